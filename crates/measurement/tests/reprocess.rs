//! `btfrig reprocess` as a library call: a small seeded run on the small-camera simulated rig
//! that keeps its raw frames, processed again without the rig: with the same calibrations
//! every texture is the same file; with a light calibration whose white rates are 1.1 times
//! larger every texture is 1.1 times darker; and the inputs it must refuse.

use std::path::{Path, PathBuf};

use btfrig_measurement::reprocess::{reprocess, ReprocessRequest};
use btfrig_measurement::{run, RunControl, RunOutcome, RunRequest};

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("reprocess-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

/// Six captures up to theta 15 deg on the small-camera rig, 16-texel textures, raw frames kept
/// (`RAW` replaced by true or false). The rig names `builtin:bonn-gonio-sim-light` and
/// `builtin:bonn-gonio-sim-color`.
fn plan(raw: bool) -> String {
    format!(
        r#"
name = "reprocess"
[rig]
config = "{}"
material = "lacquered-wood"
seed = 7
[sampling]
light = {{ preset = "bonn81", theta_max_deg = 15 }}
view = {{ preset = "bonn81", theta_max_deg = 15 }}
[texture]
size = 16
[registration]
method = "nominal"
[exposure]
mode = "auto"
[skip]
max_captures = 6
[outputs]
raw_frames = {raw}
[run]
fault_scenario = "none"
"#,
        repo("rig-configs/bonn-gonio-sim-small.toml").display()
    )
}

fn measure(dir: &Path, raw: bool) -> PathBuf {
    let out = dir.join("dataset");
    let req = RunRequest::from_text(plan(raw), &dir.join("plan.toml"), &out);
    let s = run(&req, &RunControl::new(), &mut |_| {}).unwrap();
    assert_eq!(s.outcome, RunOutcome::Finished, "{s:?}");
    assert_eq!(s.captures, 6);
    out
}

fn request(dataset: &Path, out: &Path, calibration: Option<&Path>) -> ReprocessRequest {
    ReprocessRequest { dataset: dataset.into(), out: out.into(), calibration: calibration.map(Path::to_path_buf) }
}

/// `textures/*.exr` by name, with their content hashes.
fn textures(dataset: &Path) -> std::collections::BTreeMap<String, String> {
    std::fs::read_dir(dataset.join("textures"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "exr"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                btfrig_store::content_hash(&std::fs::read(&p).unwrap()),
            )
        })
        .collect()
}

/// Sum of every texel's channels of `textures/<name>`.
fn texel_sum(dataset: &Path, name: &str) -> f64 {
    let (_, _, texels) = btfrig_imageio::read_rgb_exr(&dataset.join("textures").join(name)).unwrap();
    texels.iter().flat_map(|t| t.iter()).map(|&v| f64::from(v)).sum()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let target = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &target);
        } else {
            std::fs::copy(&p, &target).unwrap();
        }
    }
}

/// The shipped light calibration with every white rate multiplied by `factor`.
fn scaled_light_calibration(factor: f64) -> String {
    let text = std::fs::read_to_string(repo("calibration/bonn-gonio-sim-light.toml")).unwrap();
    let mut v: toml::Value = toml::from_str(&text).unwrap();
    let rates = v["lights"]["lamp"]["white_rate_e_per_s"].as_array_mut().unwrap();
    for r in rates.iter_mut() {
        *r = toml::Value::Float(r.as_float().unwrap() * factor);
    }
    toml::to_string(&v).unwrap()
}

#[test]
fn same_calibrations_give_the_same_textures_and_a_brighter_light_calibration_darker_ones() {
    btfrig_sim_backend::install();
    let dir = scratch("same-and-light");
    let source = measure(&dir, true);
    let original = textures(&source);
    assert_eq!(original.len(), 6);

    // The dataset's own calibrations: every texture file is the original's, byte for byte.
    let same = dir.join("same");
    let s = reprocess(&request(&source, &same, None)).unwrap();
    assert_eq!(s.steps, 6);
    assert_eq!(textures(&same), original);
    assert!(btfrig_store::verify(&same).is_ok(), "{:?}", btfrig_store::verify(&same).problems);
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(same.join("manifest.json")).unwrap()).unwrap();
    let from = &manifest["calibration"]["reprocessed_from"];
    assert_eq!(from["dataset"], source.display().to_string(), "{manifest}");
    assert_eq!(manifest["raw_frames"], false);
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(same.join("report.json")).unwrap()).unwrap();
    // No rig, no simulator: no truth figures.
    assert!(report.get("texture_rel_rmse").is_none(), "{report}");
    assert_eq!(report["captures"], 6);

    // A calibration directory with the light calibration the rig config names, white rates x 1.1:
    // the lamp is taken to be 1.1 times brighter, so every texture is 1.1 times darker.
    let cal = dir.join("cal");
    std::fs::create_dir_all(&cal).unwrap();
    std::fs::write(cal.join("bonn-gonio-sim-light.toml"), scaled_light_calibration(1.1)).unwrap();
    let brighter = dir.join("brighter");
    let s = reprocess(&request(&source, &brighter, Some(&cal))).unwrap();
    assert_eq!(s.steps, 6);
    for name in original.keys() {
        let ratio = texel_sum(&brighter, name) / texel_sum(&source, name);
        // Half-float textures: about 5e-4 per texel, much less over 768 values.
        assert!((ratio - 1.0 / 1.1).abs() < 1e-3, "{name}: ratio {ratio}, expected {}", 1.0 / 1.1);
    }
    let light_source = s.processing.sources.iter().find(|(p, _)| p == "light").unwrap();
    assert!(light_source.1.ends_with("cal/bonn-gonio-sim-light.toml"), "{:?}", s.processing);
    let files = &manifest_of(&brighter)["calibration"]["reprocessed_from"]["calibration_files"];
    assert_eq!(files[0]["part"], "[lamp] calibration", "{files}");
}

fn manifest_of(dataset: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dataset.join("manifest.json")).unwrap()).unwrap()
}

fn refusal(req: &ReprocessRequest) -> String {
    reprocess(req).expect_err("must be refused").to_string()
}

#[test]
fn refuses_what_it_cannot_reprocess_naming_the_cause() {
    btfrig_sim_backend::install();
    let dir = scratch("refusals");
    let source = measure(&dir, true);
    let new = dir.join("new");

    // A file in --out: refused, the file kept.
    let busy = dir.join("busy");
    std::fs::create_dir_all(&busy).unwrap();
    std::fs::write(busy.join("keep"), b"mine").unwrap();
    let e = refusal(&request(&source, &busy, None));
    assert!(e.contains("not empty") && e.contains("busy") && e.contains("overwrites nothing"), "{e}");
    assert_eq!(std::fs::read(busy.join("keep")).unwrap(), b"mine");
    // Into itself (a dataset of the same plan, which a run would resume): refused, untouched.
    let before = textures(&source);
    let e = refusal(&request(&source, &source, None));
    assert!(e.contains("not empty") && e.contains("overwrites nothing"), "{e}");
    assert_eq!(textures(&source), before);
    assert!(btfrig_store::verify(&source).is_ok());

    // A calibration file that does not parse: named, with the field.
    let cal = dir.join("cal");
    std::fs::create_dir_all(&cal).unwrap();
    let bad = scaled_light_calibration(1.0).replace("white_rate_e_per_s = [", "white_rate_e_per_s = [\"bright\", ");
    std::fs::write(cal.join("bonn-gonio-sim-light.toml"), bad).unwrap();
    let e = refusal(&request(&source, &new, Some(&cal)));
    assert!(e.contains("cal/bonn-gonio-sim-light.toml") && e.contains("white_rate_e_per_s"), "{e}");
    assert!(!new.exists(), "{e}");

    // A missing raw frame, then a damaged one: named.
    let broken = dir.join("broken");
    copy_dir(&source, &broken);
    let raw = std::fs::read_dir(broken.join("raw")).unwrap().map(|e| e.unwrap().path()).min().unwrap();
    let bytes = std::fs::read(&raw).unwrap();
    std::fs::remove_file(&raw).unwrap();
    let e = refusal(&request(&broken, &new, None));
    assert!(e.contains(&raw.display().to_string()) && e.contains("missing"), "{e}");
    let mut damaged = bytes.clone();
    let mid = damaged.len() / 2;
    damaged[mid] ^= 0x40;
    std::fs::write(&raw, &damaged).unwrap();
    let e = refusal(&request(&broken, &new, None));
    assert!(e.contains(&raw.display().to_string()) && e.contains("damaged"), "{e}");
    assert!(!new.exists(), "{e}");

    // A dome dataset without kept pattern frames (its manifest has no raw_groups): names the
    // setting to turn on.
    let dome = dir.join("dome");
    copy_dir(&source, &dome);
    let mut m = manifest_of(&dome);
    let dome_rig = btfrig_core::plan::BUILTIN_RIGS.iter().find(|(n, _)| *n == "builtin:bonn-dome-sim").unwrap().1;
    m["rig"]["config_toml"] = serde_json::Value::String(dome_rig.to_string());
    std::fs::write(dome.join("manifest.json"), serde_json::to_vec_pretty(&m).unwrap()).unwrap();
    let e = refusal(&request(&dome, &new, None));
    assert!(e.contains("led_dome run") && e.contains("outputs.raw_frames = true"), "{e}");

    // A dataset without raw frames: names the setting to turn on.
    let plain = scratch("refusals-plain");
    let without = measure(&plain, false);
    let e = refusal(&request(&without, &new, None));
    assert!(e.contains("raw_frames = true") && e.contains("[outputs]"), "{e}");
    assert!(!new.exists(), "{e}");
}
