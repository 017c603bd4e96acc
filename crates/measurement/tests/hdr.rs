//! HDR through a whole run on the glossy tile (`docs/hdr.md`): adaptive brackets where the
//! highlights saturate the sample and one exposure where one holds it, merged textures against
//! the ground truth, the report's exposure counts and time saved, every raw exposure kept, and
//! always-bracketing's time model checked against what the engine measured.

use std::path::{Path, PathBuf};

use btfrig_measurement::{run, RunControl, RunOutcome, RunRequest, RunSummary};
use btfrig_store::{Dataset, StepId};

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("runner-hdr-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Light 45/0; views 30/180 and 45/180 see the glaze's highlight (near the mirror direction),
/// 45/90 does not.
const VIEWS: [(f64, f64); 3] = [(30.0, 180.0), (45.0, 180.0), (45.0, 90.0)];

fn plan(exposure: &str) -> String {
    let views: Vec<String> = VIEWS.iter().map(|(t, p)| format!("[{t}, {p}]")).collect();
    format!(
        "name = \"hdr\"\n[rig]\nconfig = \"builtin:bonn-gonio-sim\"\nmaterial = \"glazed-tile\"\nseed = 3\n\
         [sampling]\nlight = {{ list = [[45, 0]] }}\nview = {{ list = [{}] }}\n\
         [texture]\nsize = 48\nregion = {{ u = [0.25, 0.75], v = [0.25, 0.75] }}\n\
         [exposure]\n{exposure}\n[outputs]\nraw_frames = true\n",
        views.join(", ")
    )
}

fn run_plan(name: &str, exposure: &str) -> (RunSummary, PathBuf) {
    let dir = scratch(name);
    let out = dir.join("dataset");
    let req = RunRequest::from_text(plan(exposure), &dir.join("plan.toml"), &out);
    let s = run(&req, &RunControl::new(), &mut |_| {}).unwrap();
    assert_eq!(s.outcome, RunOutcome::Finished, "{name}");
    assert_eq!(s.captures, VIEWS.len() as u64);
    assert!(btfrig_store::verify(&out).is_ok(), "{name}: {:?}", btfrig_store::verify(&out).problems);
    (s, out)
}

fn step(view: usize) -> StepId {
    StepId { light: 0, view: view as u32 }
}

#[test]
fn adaptive_hdr_brackets_the_highlights_only_and_the_merged_textures_match_the_truth() {
    btfrig_sim_backend::install();
    let (off, off_dir) = run_plan("off", "mode = \"auto\"");
    let (hdr, hdr_dir) = run_plan("adaptive", "mode = \"auto\"\nhdr = \"adaptive\"");
    let (off_err, hdr_err) = (off.texture_rel_rmse.unwrap(), hdr.texture_rel_rmse.unwrap());
    let figures = hdr.hdr.clone().expect("HDR figures in the summary");
    println!(
        "glazed tile, 3 views: texture rel. RMSE one exposure {off_err:.4}, adaptive HDR {hdr_err:.4}; \
         rig time {:.1} s vs {:.1} s; {figures:?}",
        off.hardware_s, hdr.hardware_s
    );
    // One exposure clips the highlights; the merged brackets hold them.
    assert!(hdr_err < 0.2 * off_err && hdr_err < 0.12, "HDR {hdr_err} vs one exposure {off_err}");
    assert!(off.hdr.is_none());

    let ds = Dataset::open_for_resume(&hdr_dir, &btfrig_store::plan_hash(&plan("mode = \"auto\"\nhdr = \"adaptive\"")))
        .unwrap()
        .0;
    for (v, view) in VIEWS.iter().enumerate() {
        let rec = ds.step_record(step(v)).unwrap();
        let h = rec.hdr.expect("an HDR record per step");
        let specular = view.1 == 180.0;
        if specular {
            assert!(h.exposures_s.len() >= 2, "view {view:?} needs a bracket: {h:?}");
            assert!(h.exposures_s.windows(2).all(|w| w[1] < w[0]), "shorter exposures for the highlight: {h:?}");
            assert!(h.bracket_s > 5.0, "{h:?}");
        } else {
            assert_eq!(h.exposures_s.len(), 1, "one exposure holds view {view:?}: {h:?}");
            assert_eq!(h.bracket_s, 0.0);
        }
        // Every exposure is kept as a raw frame with its own exposure time.
        let raws: Vec<&btfrig_store::FileRecord> = rec.files.iter().filter(|f| f.path.starts_with("raw/")).collect();
        assert_eq!(raws.len(), h.exposures_s.len(), "{:?}", rec.files);
        for (k, t) in h.exposures_s.iter().enumerate() {
            let name =
                if k == 0 { format!("raw/{}.exr", step(v).stem()) } else { format!("raw/{}_e{k}.exr", step(v).stem()) };
            let frame = btfrig_imageio::read_raw_exr(&hdr_dir.join(&name)).unwrap();
            assert_eq!(frame.meta.exposure_s, *t, "{name}");
        }
        // The plan without HDR journals no exposure record.
        let off_ds = Dataset::open_for_resume(&off_dir, &btfrig_store::plan_hash(&plan("mode = \"auto\""))).unwrap().0;
        assert!(off_ds.step_record(step(v)).unwrap().hdr.is_none());
    }
    // The report counts captures by exposures and what the policy saved.
    let n: u64 = figures.exposures_per_capture.values().sum();
    assert_eq!(n, VIEWS.len() as u64);
    assert_eq!(figures.exposures_per_capture.get(&1), Some(&1));
    assert!(figures.time_saved_s > 0.0 && figures.bracket_s > 10.0, "{figures:?}");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(hdr_dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["hdr"]["exposures_per_capture"]["1"], 1, "{}", report["hdr"]);
    assert_eq!(report["hdr"]["hdr_time_saved_s"].as_f64(), Some(figures.time_saved_s));
    // The brackets cost the rig their own time: the off-specular step kept its overlap.
    let added = hdr.hardware_s - off.hardware_s;
    assert!((added - figures.bracket_s).abs() < 0.5, "added {added} s, brackets {} s", figures.bracket_s);
}

#[test]
fn always_bracketing_costs_what_the_report_s_time_model_says() {
    btfrig_sim_backend::install();
    let (s, _) = run_plan("always", "mode = \"bracket\"\nstops = [1.0, 0.125]");
    let h = s.hdr.expect("HDR figures");
    assert_eq!(h.exposures_per_capture.get(&2), Some(&(VIEWS.len() as u64)), "{h:?}");
    // Always bracketing saves nothing against itself: the engine's measured bracket time
    // equals the per-exposure overhead model (command, latency, read-out, transfer) to rounding.
    assert!(h.time_saved_s.abs() < 1e-6 * h.bracket_s, "{h:?}");
    assert!(h.bracket_s > 3.0 * 5.0, "{h:?}");
}
