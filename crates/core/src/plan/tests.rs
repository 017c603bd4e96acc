use super::*;
use crate::kinematics::Gonio;
use crate::sampling::Sampling;
use crate::Direction;

fn repo_dir(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

fn ctx() -> PlanContext {
    PlanContext::with_builtin_names()
}

fn validate(text: &str) -> Result<ValidatedPlan, PlanErrors> {
    Plan::load_and_validate(text, "<test>", &ctx())
}

/// STYLE habit 8: every shipped plan parses and validates against the embedded rig.
#[test]
fn every_shipped_plan_validates() {
    let mut count = 0;
    for entry in std::fs::read_dir(repo_dir("rig-configs/plans")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        // Calibration plans are another format, parsed by btfrig-calibrate (its tests load them).
        if path.file_name().is_some_and(|n| n.to_string_lossy().starts_with("calibration-")) {
            continue;
        }
        // Dome plans (`dome-*` for the LED dome, `camera-array-*` for the camera array) are the
        // dome format, validated against the embedded rig they name.
        let stem = path.file_name().unwrap().to_string_lossy().into_owned();
        if stem.starts_with("dome-") || stem.starts_with("camera-array-") {
            let text = std::fs::read_to_string(&path).unwrap();
            let plan = crate::plan::dome::DomePlan::from_toml(&text, &path.display().to_string()).unwrap();
            let rig_text =
                BUILTIN_RIGS.iter().find(|(n, _)| *n == plan.rig.config).unwrap_or_else(|| panic!("{stem}")).1;
            let rig = crate::config::RigConfig::from_toml(rig_text, "dome").unwrap();
            let want = if stem.starts_with("dome-") { "led_dome" } else { "camera_array" };
            assert_eq!(rig.rig.kind.as_str(), want, "{stem}");
            let v = plan.validate(&rig).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(!v.cameras.is_empty() && !v.rotations.is_empty());
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let v = Plan::load_and_validate(&text, &path.display().to_string(), &ctx()).unwrap_or_else(|e| panic!("{e}"));
        let captures = v.capture_list().captures;
        assert!(!captures.is_empty(), "{}", path.display());
        count += 1;
    }
    assert!(count >= 3, "expected bonn-full, demo and grazing");
}

#[test]
fn the_builtin_fault_scenarios_match_the_files() {
    let mut stems: Vec<String> = std::fs::read_dir(repo_dir("sim/faults"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    stems.sort();
    let mut builtin: Vec<String> = BUILTIN_FAULT_SCENARIOS.iter().map(|s| s.to_string()).collect();
    builtin.sort();
    assert_eq!(stems, builtin);
    let mut mats: Vec<String> = std::fs::read_dir(repo_dir("sim/materials"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    mats.sort();
    let mut builtin: Vec<String> = BUILTIN_MATERIAL_NAMES.iter().map(|s| s.to_string()).collect();
    builtin.sort();
    assert_eq!(mats, builtin);
}

#[test]
fn bonn_full_requests_all_6561_pairs_and_reports_the_same_unreachable_count_as_kinematics() {
    let text = std::fs::read_to_string(repo_dir("rig-configs/plans/bonn-full.toml")).unwrap();
    let v = validate(&text).unwrap();
    assert_eq!(v.pairs.len(), 6561);
    assert_eq!(v.texture.size, 256);
    // Cross-check against the kinematics' own report over the same samplings.
    let gonio = Gonio::new(v.rig.geometry.clone()).unwrap();
    let report = gonio.report(&Sampling::bonn81(), &Sampling::bonn81());
    assert_eq!(v.unreachable.len(), report.total - report.reachable);
    let CaptureList { captures, skipped } = v.capture_list();
    assert_eq!(captures.len(), report.reachable);
    assert_eq!(captures.len() + skipped.len(), 6561);
    // Light-major order: the full cross product in nested order.
    assert_eq!(v.pairs[0], (0, 0));
    assert_eq!(v.pairs[1], (0, 1));
    assert_eq!(v.pairs[81], (1, 0));
    // The whole sample square.
    let a = v.rig.plate.sample_side_m;
    assert_eq!(v.texture.region, Region { x_min_m: -a / 2.0, x_max_m: a / 2.0, y_min_m: -a / 2.0, y_max_m: a / 2.0 });
}

#[test]
fn demo_filters_and_caps() {
    let text = std::fs::read_to_string(repo_dir("rig-configs/plans/demo.toml")).unwrap();
    let v = validate(&text).unwrap();
    // Bonn rings at theta 0, 15, 30: 1 + 6 + 12.
    assert_eq!(v.light.len(), 19);
    assert_eq!(v.view.len(), 19);
    assert_eq!(v.light_source_indices, (0..19).collect::<Vec<_>>());
    assert_eq!(v.rig.rig.seed, 7, "the seed override is applied");
    let CaptureList { captures, skipped } = v.capture_list();
    assert_eq!(captures.len(), 60);
    assert!(skipped.iter().any(|(_, r)| *r == SkipReason::MaxCaptures));
    // Central half: region side = sample side / 2, centred.
    let a = v.rig.plate.sample_side_m;
    let r = v.texture.region;
    assert!((r.side_m() - a / 2.0).abs() < 1e-12);
    assert!((r.x_min_m + a / 4.0).abs() < 1e-12 && (r.y_max_m - a / 4.0).abs() < 1e-12);
}

#[test]
fn grazing_views_are_at_60_and_75_degrees() {
    let text = std::fs::read_to_string(repo_dir("rig-configs/plans/grazing.toml")).unwrap();
    let v = validate(&text).unwrap();
    assert_eq!(v.view.len(), 44);
    for d in v.view.directions() {
        let t = d.theta.to_degrees();
        assert!((t - 60.0).abs() < 1e-9 || (t - 75.0).abs() < 1e-9, "{t}");
    }
    assert_eq!(v.outputs.format, OutputFormat::ExrFloat);
    assert_eq!(v.exposure, ExposurePolicy::Fixed { exposure_s: 0.2, gain: 1.0 });
}

#[test]
fn region_fractions_follow_the_texture_axes() {
    // u along +x from the left edge, v along -y from the top edge: the top-left quarter.
    let v = validate(
        "[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n[texture]\nsize = 8\nregion = { u = [0.0, 0.5], v = [0.0, 0.5] }\n",
    )
    .unwrap();
    let a = v.rig.plate.sample_side_m;
    let r = v.texture.region;
    assert_eq!((r.x_min_m, r.x_max_m), (-a / 2.0, 0.0));
    assert_eq!((r.y_min_m, r.y_max_m), (0.0, a / 2.0));
    // Texel (0, 0) centre sits half a texel in from the top-left corner.
    let (x, y) = r.texel_centre(0, 0, 8);
    assert!((x - (-a / 2.0 + a / 32.0)).abs() < 1e-15 && (y - (a / 2.0 - a / 32.0)).abs() < 1e-15);
}

#[test]
fn content_hash_ignores_comments_order_defaults_and_run_settings_but_not_content() {
    let a = Plan::from_toml("[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n", "a").unwrap();
    let b = Plan::from_toml(
        "# a comment\n[texture]\nsize = 256\n[sampling]\nview = \"bonn81\"\nlight = \"bonn81\"\npairs = \"all\"\n[run]\nmax_retries = 9\n",
        "b",
    )
    .unwrap();
    assert_eq!(a.content_hash(), b.content_hash());
    let c = Plan::from_toml("[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n[texture]\nsize = 512\n", "c").unwrap();
    assert_ne!(a.content_hash(), c.content_hash());
    // Pinned: the hash is a file-format fact (datasets record it), so it must not drift.
    assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
    assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
}

#[test]
fn existing_dataset_of_the_same_plan_resumes_and_of_another_is_refused() {
    let text = "[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n";
    let plan = Plan::from_toml(text, "p").unwrap();
    let mut c = ctx();
    c.existing_dataset = Some(ExistingDataset { plan_hash: plan.content_hash(), path: "out".into() });
    assert!(plan.validate(&c).unwrap().resume);
    c.existing_dataset = Some(ExistingDataset { plan_hash: plan.content_hash() ^ 1, path: "out".into() });
    let e = plan.validate(&c).unwrap_err();
    assert!(e.has_field("output"), "{e}");
    assert!(e.to_string().contains("already holds a dataset of another plan"), "{e}");
}

#[test]
fn reciprocal_pairs_are_skipped_once_captured() {
    let v = validate(
        "[sampling]\nlight = { list = [[30, 0], [30, 90]] }\nview = { list = [[30, 90], [30, 0]] }\n[skip]\nreciprocal = true\n",
    )
    .unwrap();
    // Pairs in order: (L0=30/0, V0=30/90), (L0, V1=30/0), (L1=30/90, V0=30/90), (L1, V1=30/0).
    // (L1, V1) is the reciprocal of (L0, V0); same-direction pairs are unreachable.
    let CaptureList { captures, skipped } = v.capture_list();
    assert_eq!(captures, vec![(0, 0)]);
    assert!(skipped.contains(&((1, 1), SkipReason::Reciprocal)), "{skipped:?}");
}

#[test]
fn rig_and_material_paths_resolve_against_the_plan_file() {
    let plan = Plan::from_toml(
        "[rig]\nconfig = \"../my-rig.toml\"\nmaterial = \"mats/wood.toml\"\n[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n",
        "p",
    )
    .unwrap();
    let p = Path::new("/x/plans/p.toml");
    assert_eq!(plan.rig_config_path(p), Some(PathBuf::from("/x/plans/../my-rig.toml")));
    assert_eq!(plan.material_path(p), Some(PathBuf::from("/x/plans/mats/wood.toml")));
    // Not loaded by the caller: a clear error, not a silent default.
    let e = plan.validate(&ctx()).unwrap_err();
    assert!(e.has_field("rig.config"), "{e}");
    // Loaded: fine.
    let mut c = ctx();
    c.rig = Some(crate::config::RigConfig::from_toml(BUILTIN_RIGS[0].1, "rig").unwrap());
    let v = plan.validate(&c).unwrap();
    assert_eq!(v.material, Some(MaterialRef::File("mats/wood.toml".into())));
}

#[test]
fn dome_preset_with_theta_and_every_filters_keeps_the_expected_directions() {
    let v = validate(
        "[sampling]\nlight = { preset = \"dome1-151\", theta_min_deg = 45, every = 2 }\nview = \"dome1-151\"\n",
    )
    .unwrap();
    // Dome-1 rings from theta 45 on: 18 + 18 + 24 + 24 + 24 = 108 directions, every 2nd: 54.
    assert_eq!(v.light.len(), 54);
    assert_eq!(v.view.len(), 151);
    // Source indices: the first ring at 45 deg starts after 1+6+12+12+12 = 43 directions.
    assert_eq!(&v.light_source_indices[..3], &[43, 45, 47]);
    let full = Sampling::bonn_dome1();
    for (k, &i) in v.light_source_indices.iter().enumerate() {
        assert!(v.light.get(k).angle_to(full.get(i)) < 1e-12);
    }
}

const MINIMAL: &str = "[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n";

#[test]
fn every_filter_of_calib_is_selectable_with_its_parameter_and_bad_ones_name_the_field() {
    let filter = |t: &str| validate(&format!("{MINIMAL}[texture]\nfilter = {t}\n")).map(|v| v.texture.filter);
    assert_eq!(validate(MINIMAL).unwrap().texture.filter, ResampleFilter::Footprint { max: 4 });
    assert_eq!(filter("\"bilinear\"").unwrap(), ResampleFilter::Bilinear);
    assert_eq!(filter("\"ewa\"").unwrap(), ResampleFilter::Ewa);
    assert_eq!(filter("\"supersample\"").unwrap(), ResampleFilter::Supersample { n: 4 });
    assert_eq!(filter("{ name = \"supersample\", n = 3 }").unwrap(), ResampleFilter::Supersample { n: 3 });
    assert_eq!(filter("\"footprint\"").unwrap(), ResampleFilter::Footprint { max: 4 });
    assert_eq!(filter("{ name = \"footprint\", max = 12 }").unwrap(), ResampleFilter::Footprint { max: 12 });
    let e = filter("{ name = \"supersample\", n = 17 }").unwrap_err();
    assert!(e.has_field("texture.filter.n") && e.to_string().contains("1..=16"), "{e}");
    let e = filter("{ name = \"ewa\", max = 4 }").unwrap_err();
    assert!(e.has_field("texture.filter.max") && e.to_string().contains("only with name = \"footprint\""), "{e}");
    let e = filter("{ name = \"lanczos\" }").unwrap_err();
    assert!(e.has_field("texture.filter.name") && e.to_string().contains("\"footprint\", \"ewa\""), "{e}");
    // Schema errors inside the table keep serde's message naming the key.
    let e =
        Plan::from_toml(&format!("{MINIMAL}[texture]\nfilter = {{ name = \"ewa\", sigma = 1 }}\n"), "x").unwrap_err();
    assert!(e.to_string().contains("unknown field `sigma`"), "{e}");
}

#[test]
fn registration_defaults_to_markers_with_a_nominal_fallback_and_bad_values_name_the_field() {
    let reg = |t: &str| validate(&format!("{MINIMAL}[registration]\n{t}\n")).map(|v| v.registration);
    assert_eq!(validate(MINIMAL).unwrap().registration, RegistrationPolicy::default());
    assert_eq!(
        RegistrationPolicy::default(),
        RegistrationPolicy { method: RegistrationMethod::Markers, on_failure: OnRegistrationFailure::Nominal }
    );
    let r = reg("method = \"nominal\"\non_failure = \"fail\"").unwrap();
    assert_eq!(r.method, RegistrationMethod::Nominal);
    assert_eq!(r.on_failure, OnRegistrationFailure::Fail);
    let e = reg("method = \"sift\"\non_failure = \"retry\"").unwrap_err();
    assert!(e.has_field("registration.method") && e.has_field("registration.on_failure"), "{e}");
    assert!(
        e.to_string().contains("\"markers\", \"nominal\"") && e.to_string().contains("\"nominal\", \"fail\""),
        "{e}"
    );
}

#[test]
fn the_registration_method_is_content_but_the_failure_policy_and_spelled_out_defaults_are_not() {
    let hash = |t: &str| Plan::from_toml(&format!("{MINIMAL}{t}"), "h").unwrap().content_hash();
    let base = hash("");
    assert_eq!(hash("[registration]\nmethod = \"markers\"\n"), base);
    assert_eq!(hash("[registration]\non_failure = \"fail\"\n"), base);
    assert_ne!(hash("[registration]\nmethod = \"nominal\"\n"), base);
    // The default filter spelled out keeps the hash; another filter changes the texels.
    assert_eq!(hash("[texture]\nfilter = \"footprint\"\n"), base);
    assert_ne!(hash("[texture]\nfilter = \"bilinear\"\n"), base);
    assert_ne!(hash("[texture]\nfilter = \"ewa\"\n"), base);
}

#[test]
fn hdr_settings_default_off_keep_the_hash_and_name_bad_values() {
    let hash = |t: &str| Plan::from_toml(&format!("{MINIMAL}{t}"), "h").unwrap().content_hash();
    // The defaults spelled out keep the hash of a plan written before they existed.
    let spelled = "[exposure]\nmode = \"auto\"\nhdr = \"off\"\nmax_exposures = 3\nstop_ratio = 0.125\n\
                   saturated_max_fraction = 0.0001\ndark_max_fraction = 0.02\n";
    assert_eq!(hash(spelled), hash(""));
    assert_ne!(hash("[exposure]\nmode = \"auto\"\nmax_exposures = 4\n"), hash(""));
    assert!(validate(&format!("{MINIMAL}{spelled}")).is_ok());
    // Every bad value is named.
    let e = validate(&format!(
        "{MINIMAL}[exposure]\nmode = \"auto\"\nhdr = \"adaptive\"\nmax_exposures = 9\nstop_ratio = 0.9\n\
         saturated_max_fraction = -1\ndark_max_fraction = 2\n"
    ))
    .unwrap_err()
    .to_string();
    for field in [
        "exposure.max_exposures = 9",
        "exposure.stop_ratio = 0.9",
        "exposure.saturated_max_fraction = -1",
        "exposure.dark_max_fraction = 2",
    ] {
        assert!(e.contains(field), "{field} missing in {e}");
    }
    // Valid HDR settings resolve to what the runner executes.
    let v =
        validate(&format!("{MINIMAL}[exposure]\nmode = \"auto\"\nhdr = \"adaptive\"\nmax_exposures = 4\n")).unwrap();
    let ExposurePolicy::Auto { white_fraction, hdr } = v.exposure else { panic!("{:?}", v.exposure) };
    assert_eq!((white_fraction, hdr.mode, hdr.max_exposures), (0.6, HdrMode::Adaptive, 4));
    let v = validate(&format!("{MINIMAL}[exposure]\nmode = \"bracket\"\nstops = [1.0, 0.125]\n")).unwrap();
    let ExposurePolicy::Auto { hdr, .. } = v.exposure else { panic!("{:?}", v.exposure) };
    assert_eq!(hdr.mode, HdrMode::Always(vec![1.0, 0.125]));
    let e = validate(&format!("{MINIMAL}[exposure]\nmode = \"auto\"\nhdr = \"sometimes\"\n")).unwrap_err().to_string();
    assert!(e.contains("exposure.hdr = \"sometimes\" is unknown"), "{e}");
    let e = validate(&format!("{MINIMAL}[exposure]\nmode = \"bracket\"\nstops = [1.0, 0.0, 100.0]\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("exposure.stops[1] = 0") && e.contains("exposure.stops[2] = 100"), "{e}");
    let e = validate(&format!("{MINIMAL}[exposure]\nmode = \"bracket\"\n")).unwrap_err().to_string();
    assert!(e.contains("exposure.stops = [] is invalid"), "{e}");
}

#[test]
fn a_sparse_subset_captures_only_its_pairs_and_changes_the_hash() {
    let base = "[sampling]\nlight = { preset = \"bonn81\", theta_max_deg = 30 }\nview = { preset = \"bonn81\", theta_max_deg = 30 }\n";
    let sparse = format!("{base}[sparse]\npairs = [[0, 3], [7, 2], [12, 18]]\n");
    let ctx = PlanContext::with_builtin_names();
    let full = Plan::from_toml(base, "full").unwrap();
    let plan = Plan::from_toml(&sparse, "sparse").unwrap();
    assert_ne!(full.content_hash(), plan.content_hash(), "the subset is part of the hash");
    let v = plan.validate(&ctx).unwrap();
    let list = v.capture_list();
    let mut got = list.captures.clone();
    got.sort_unstable();
    assert_eq!(got, vec![(0, 3), (7, 2), (12, 18)]);
    let sparse_skips = list.skipped.iter().filter(|(_, r)| *r == SkipReason::Sparse).count();
    let unreachable = list.skipped.iter().filter(|(_, r)| matches!(r, SkipReason::Unreachable(_))).count();
    assert_eq!(sparse_skips + unreachable + 3, 19 * 19);
    assert_eq!(SkipReason::Sparse.label(), "sparse");
}

#[test]
fn compressed_model_names_a_model_and_is_not_content() {
    let model = |t: &str| {
        validate(&format!("{MINIMAL}[outputs]\ncompressed_model = {t}\n")).map(|v| v.outputs.compressed_model)
    };
    assert_eq!(validate(MINIMAL).unwrap().outputs.compressed_model, None);
    assert_eq!(model("false").unwrap(), None);
    assert_eq!(model("\"none\"").unwrap(), None);
    assert_eq!(model("true").unwrap(), Some(CompressedModel::Fmf));
    assert_eq!(model("\"fmf\"").unwrap(), Some(CompressedModel::Fmf));
    assert_eq!(model("\"pvmf\"").unwrap(), Some(CompressedModel::Pvmf));
    assert_eq!(model("\"pcmf\"").unwrap(), Some(CompressedModel::Pcmf));
    assert_eq!(model("\"pcmf-shared\"").unwrap(), Some(CompressedModel::PcmfShared));
    for m in [CompressedModel::Fmf, CompressedModel::Pvmf, CompressedModel::Pcmf, CompressedModel::PcmfShared] {
        assert_eq!(CompressedModel::from_name(m.name()), Some(m));
    }
    let e = model("\"PCMF\"").unwrap_err().to_string();
    assert!(e.contains("outputs.compressed_model") && e.contains("\"fmf\", \"pvmf\", \"pcmf\""), "{e}");
    // A wrong type names what is allowed too.
    let e = model("3").unwrap_err().to_string();
    assert!(e.contains("line 5") && e.contains("expected false, true, or one of \"fmf\", \"pvmf\", \"pcmf\""), "{e}");
    // The model is built from the textures.
    let e = validate(&format!("{MINIMAL}[outputs]\ncompressed_model = \"fmf\"\ntextures = false\nraw_frames = true\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("outputs.compressed_model") && e.contains("textures = true"), "{e}");
    // A shared basis of 32 terms needs 32 captures: refused before the run, naming both counts.
    let e = validate(&format!("{MINIMAL}[outputs]\ncompressed_model = \"pcmf-shared\"\n[skip]\nmax_captures = 20\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("outputs.compressed_model") && e.contains("32 terms") && e.contains("captures 20 pairs"), "{e}");
    assert!(validate(&format!("{MINIMAL}[outputs]\ncompressed_model = \"pcmf-shared\"\n[skip]\nmax_captures = 32\n"))
        .is_ok());
    // A derived output: the dataset's content (and so resume) does not depend on it.
    let hash = |t: &str| Plan::from_toml(&format!("{MINIMAL}{t}"), "h").unwrap().content_hash();
    assert_eq!(hash("[outputs]\ncompressed_model = \"pcmf\"\n"), hash(""));
    assert_eq!(hash("[outputs]\ncompressed_model = false\n"), hash(""));
}

/// Issue 24's runaway plan: `rings` rings of `count` directions for light and view.
fn runaway_plan(rings: usize, count: usize, extra: &str) -> String {
    let ring_list: Vec<String> =
        (0..rings).map(|r| format!("{{ theta_deg = {}, count = {count} }}", 5.0 + 4.0 * r as f64)).collect();
    let rings = ring_list.join(", ");
    format!("[sampling]\nlight = {{ rings = [{rings}] }}\nview = {{ rings = [{rings}] }}\n{extra}")
}

#[test]
fn r24_the_runaway_plan_is_refused_from_its_pair_count_naming_the_limit_and_how_to_raise_it() {
    let text = runaway_plan(10, 360, "");
    assert!(text.len() < 1500, "the plan as found was 1.3 KB; this one is {} bytes", text.len());
    let e = validate(&text).unwrap_err();
    assert_eq!(e.errors.len(), 1, "{e}");
    assert!(e.has_field("sampling.pairs"), "{e}");
    let msg = e.to_string();
    // The value is the count from the ring counts (3600 x 3600), not from an expanded list.
    for want in [
        "12960000 pairs (3600 light x 3600 view directions)",
        "100000",
        "limits.max_captures",
        "[limits] max_captures = N",
        "1000000",
    ] {
        assert!(msg.contains(want), "{want:?} missing: {msg}");
    }
    // `skip.max_captures` does not make it acceptable: the pairs are what gets expanded.
    let e = validate(&runaway_plan(10, 360, "[skip]\nmax_captures = 60\n")).unwrap_err();
    assert!(e.has_field("sampling.pairs"), "{e}");
    // Raised within the ceiling, a plan of that size passes the limit (here: 60 x 60 pairs
    // against a limit of 3000 refused, of 4000 accepted).
    let small = |limit: usize| runaway_plan(2, 30, &format!("[limits]\nmax_captures = {limit}\n"));
    assert!(validate(&small(3000)).unwrap_err().has_field("sampling.pairs"));
    let v = validate(&small(4000)).unwrap();
    assert_eq!(v.pairs.len(), 3600);
    // The ceiling is a limit too, named.
    let e = validate(&small(2_000_000)).unwrap_err();
    assert!(e.has_field("limits.max_captures") && e.to_string().contains("1..=1000000"), "{e}");
    // The limits are a run policy: the content hash does not change with them.
    let a = Plan::from_toml(&small(4000), "a").unwrap().content_hash();
    let b = Plan::from_toml(&runaway_plan(2, 30, ""), "b").unwrap().content_hash();
    assert_eq!(a, b);
}

#[test]
fn r24_more_directions_than_the_limit_are_refused_before_expansion() {
    // 20 rings of 360: 7200 directions > 4096, counted from the rings.
    let e = validate(&runaway_plan(20, 360, "")).unwrap_err();
    assert!(e.has_field("sampling.light.rings") && e.has_field("sampling.view.rings"), "{e}");
    assert!(e.to_string().contains("7200 directions") && e.to_string().contains("4096"), "{e}");
}

#[test]
fn r24_a_50_mb_plan_is_refused_by_its_size_before_parsing() {
    // A 4.2 M-entry pairs list, as found: about 50 MB of TOML.
    let mut text = String::from("[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\npairs = [");
    for k in 0..4_200_000u32 {
        text.push_str(&format!("[ {}, {} ], ", k % 81, k % 79));
    }
    text.push_str("]\n");
    assert!(text.len() > 48_000_000, "{}", text.len());
    // Broken at the end: were it parsed, the error would be a syntax error.
    text.push_str("[[[");
    let e = Plan::from_toml(&text, "big.toml").unwrap_err();
    assert_eq!(e.errors.len(), 1);
    assert!(matches!(e.errors[0], PlanError::TooLarge { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains(&format!("{} bytes", text.len())) && msg.contains("1048576 bytes"), "{msg}");
    // A dome plan is refused the same way.
    let e = crate::plan::dome::DomePlan::from_toml(&text, "big.toml").unwrap_err().to_string();
    assert!(e.contains("1048576 bytes"), "{e}");
}

#[test]
fn r24_reciprocal_skips_are_the_quadratic_definitions() {
    // The set-based reciprocal check equals the definition (an earlier capture with light and
    // view swapped), on a plan whose light and view samplings differ and overlap.
    let text = "[sampling]\nlight = { preset = \"bonn81\", theta_max_deg = 45 }\nview = { preset = \"bonn81\", theta_min_deg = 15 }\n[skip]\nreciprocal = true\n";
    let v = validate(text).unwrap();
    let list = v.capture_list();
    let mut captured: Vec<(usize, usize)> = Vec::new();
    let mut want_skipped = 0;
    for &p in &v.pairs {
        if v.unreachable.iter().any(|u| (u.light, u.view) == p) {
            continue;
        }
        let (l, w) = (v.light.get(p.0), v.view.get(p.1));
        let same = |a: Direction, b: Direction| a.angle_to(b) < 1e-6;
        if !same(l, w) && captured.iter().any(|&(cl, cv)| same(v.light.get(cl), w) && same(v.view.get(cv), l)) {
            want_skipped += 1;
            continue;
        }
        captured.push(p);
    }
    assert!(want_skipped > 100, "{want_skipped}");
    assert_eq!(list.captures, captured);
    assert_eq!(list.skipped.iter().filter(|(_, r)| *r == SkipReason::Reciprocal).count(), want_skipped);
}
