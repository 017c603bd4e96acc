//! A dome plan that keeps its raw frames (`[outputs] raw_frames = true`) and `btfrig
//! reprocess` of its dataset: with the run's calibrations the textures are the run's, file for
//! file; with an LED calibration whose powers are 1.1 times larger they are 1.1 times darker;
//! a crash between a group's frames and its textures resumes into a dataset whose frames
//! still give its textures; a dataset without kept frames is refused naming the setting.

use std::path::{Path, PathBuf};

use btfrig_measurement::dome::{run, DomeRunRequest, DomeRunSummary};
use btfrig_measurement::reprocess::{reprocess, ReprocessRequest};

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("dome-reprocess-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

/// Two cameras at one rotation under the full S-matrix (199 patterns), two single-LED
/// reference frames (measured, not kept), every pattern frame kept.
const PLAN: &str = "name = \"dome-reprocess\"\ntexture_size = 16\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\n\
                    material = \"leather\"\n[dome]\ncameras = [3, 4]\nrotations = [1]\nmultiplex = \"on\"\n\
                    reference_leds = 2\n[outputs]\nraw_frames = true\n";

fn go(out: &Path) -> DomeRunSummary {
    go_with(out, None)
}

/// [`go`] with the fault scenario replaced (not part of the plan hash: a resume may change it).
fn go_with(out: &Path, faults: Option<String>) -> DomeRunSummary {
    let req = DomeRunRequest {
        plan_text: PLAN.into(),
        plan_path: PathBuf::from("<test>"),
        out: out.to_path_buf(),
        faults,
        preview: false,
        compressed_model: None,
    };
    run(&req, &mut |line| eprintln!("{line}")).unwrap_or_else(|e| panic!("{e}"))
}

fn request(dataset: &Path, out: &Path, calibration: Option<&Path>) -> ReprocessRequest {
    ReprocessRequest { dataset: dataset.into(), out: out.into(), calibration: calibration.map(Path::to_path_buf) }
}

/// `textures/*.exr` by name, with their content hashes.
fn textures(dataset: &Path) -> std::collections::BTreeMap<String, String> {
    std::fs::read_dir(dataset.join("textures"))
        .unwrap()
        .map(|e| e.unwrap().path())
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

fn json_of(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// The shipped LED calibration with every LED's power multiplied by `factor`.
fn scaled_led_calibration(factor: f64) -> String {
    let text = std::fs::read_to_string(repo("calibration/bonn-dome-sim-leds.toml")).unwrap();
    let mut v: toml::Value = toml::from_str(&text).unwrap();
    for led in v["leds"].as_array_mut().unwrap() {
        let p = led["power"].as_float().unwrap();
        led["power"] = toml::Value::Float(p * factor);
    }
    toml::to_string(&v).unwrap()
}

#[test]
fn kept_pattern_frames_reprocess_into_the_same_textures_and_a_new_led_calibration_changes_them() {
    btfrig_sim_backend::install();
    let dir = scratch("same");
    let source = dir.join("dataset");
    let s = go(&source);
    assert_eq!((s.textures, s.frames, s.mode.as_str()), (396, 201, "s-matrix 199"), "{:?}", s.warnings);
    let r = btfrig_store::verify(&source);
    assert!(r.is_ok(), "{r}");
    // Every pattern frame of both cameras' groups, nothing of the reference frames.
    let raw: Vec<String> = std::fs::read_dir(source.join("raw"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(raw.len(), 2 * 199, "{raw:?}");
    assert!(raw.contains(&"v014_p198.exr".to_string()) && raw.contains(&"v015_p000.exr".to_string()), "{raw:?}");
    let manifest = json_of(&source.join("manifest.json"));
    let groups = &manifest["raw_groups"];
    assert_eq!(groups["mode"], serde_json::json!({"kind": "multiplexed", "order": 199}), "{groups}");
    assert_eq!((groups["frames_per_group"].as_u64(), groups["leds"].as_u64()), (Some(199), Some(198)));
    let original = textures(&source);
    assert_eq!(original.len(), 396);

    // The dataset's own calibrations: every texture file is the run's, byte for byte.
    let same = dir.join("reprocessed");
    let r = reprocess(&request(&source, &same, None)).unwrap();
    assert_eq!((r.steps, r.registered, r.fallbacks), (396, 2, 0), "{r:?}");
    assert_eq!(textures(&same), original, "reprocessed textures differ from the run's");
    let v = btfrig_store::verify(&same);
    assert!(v.is_ok(), "{v}");
    let m = json_of(&same.join("manifest.json"));
    assert_eq!(m["calibration"]["reprocessed_from"]["dataset"], source.display().to_string(), "{m}");
    assert!(m.get("raw_groups").is_none(), "{m}");
    let report = json_of(&same.join("report.json"));
    assert!(report.get("texture_rel_rmse").is_none(), "no truth figures without the rig: {report}");
    assert_eq!(report["calibration"]["leds"], "builtin:bonn-dome-sim-leds", "{report}");

    // The LED calibration the rig config names, every power x 1.1: the demultiplexer and the
    // radiometry take each LED to be 1.1 times brighter, so every texture is 1.1 times darker.
    let cal = dir.join("cal");
    std::fs::create_dir_all(&cal).unwrap();
    std::fs::write(cal.join("bonn-dome-sim-leds.toml"), scaled_led_calibration(1.1)).unwrap();
    let brighter = dir.join("brighter");
    let r = reprocess(&request(&source, &brighter, Some(&cal))).unwrap();
    assert_eq!(r.steps, 396);
    let light = r.processing.sources.iter().find(|(p, _)| p == "light").unwrap();
    assert!(light.1.ends_with("cal/bonn-dome-sim-leds.toml"), "{:?}", r.processing);
    let (mut worst, mut differ) = (0.0f64, 0);
    for name in original.keys() {
        let ratio = texel_sum(&brighter, name) / texel_sum(&source, name);
        worst = worst.max((ratio * 1.1 - 1.0).abs());
        differ += usize::from(textures(&brighter)[name] != original[name]);
    }
    eprintln!("LED powers x 1.1: texture sums x 1/1.1 within {worst:.2e}; {differ} of 396 files differ");
    assert_eq!(differ, 396);
    assert!(worst < 1e-4, "texture sums off 1/1.1 by up to {worst}");
    let files = &json_of(&brighter.join("manifest.json"))["calibration"]["reprocessed_from"]["calibration_files"];
    assert_eq!(files[0]["part"], "[dome] led_calibration", "{files}");

    // Without kept frames (the manifest of a plan without [outputs] raw_frames): refused,
    // naming the setting.
    let plain = dir.join("plain");
    std::fs::create_dir_all(&plain).unwrap();
    let mut m = json_of(&source.join("manifest.json"));
    m.as_object_mut().unwrap().remove("raw_groups");
    std::fs::write(plain.join("manifest.json"), serde_json::to_vec_pretty(&m).unwrap()).unwrap();
    let journal = btfrig_store::JOURNAL_FILE;
    std::fs::copy(source.join(journal), plain.join(journal)).unwrap();
    let e = reprocess(&request(&plain, &dir.join("new"), None)).unwrap_err().to_string();
    assert!(e.contains("outputs.raw_frames = true") && e.contains("no raw frames"), "{e}");
    assert!(!dir.join("new").exists());
    // A damaged frame: named, nothing written.
    let frame = source.join("raw/v015_p100.exr");
    let mut bytes = std::fs::read(&frame).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x40;
    std::fs::write(&frame, &bytes).unwrap();
    let e = reprocess(&request(&source, &dir.join("new"), None)).unwrap_err().to_string();
    assert!(e.contains("v015_p100.exr") && e.contains("damaged"), "{e}");
    assert!(!dir.join("new").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Cuts the journal after the `frames` record of `view`: the crash right after a view group's
/// frames were journaled, before any of its textures.
fn crash_after_frames(dataset: &Path, view: u32) {
    let path = dataset.join(btfrig_store::JOURNAL_FILE);
    let text = std::fs::read_to_string(&path).unwrap();
    let mut kept = String::new();
    for line in text.split_inclusive('\n') {
        kept.push_str(line);
        let json: serde_json::Value = serde_json::from_str(line.splitn(3, ' ').nth(2).unwrap()).unwrap();
        if json["type"] == "frames" && json["view"] == view {
            break;
        }
    }
    assert!(kept.len() < text.len(), "the journal has records after view {view}'s frames");
    std::fs::write(&path, kept).unwrap();
}

#[test]
fn a_crash_between_a_groups_frames_and_its_textures_takes_the_group_again() {
    btfrig_sim_backend::install();
    let dir = scratch("crash");
    let source = dir.join("dataset");
    go(&source);
    // Camera 4's group (view 15) is committed after camera 3's (view 14).
    crash_after_frames(&source, 15);
    let r = btfrig_store::verify(&source);
    assert!(!r.is_ok(), "textures of view 15 are no longer journaled: {r}");
    // The rig changed meanwhile (LED 40 now stuck on), so the frames captured again differ
    // from those of the first session: a group kept with the first session's frames and the
    // second's textures would not reprocess into its textures.
    let faults = dir.join("stuck.toml");
    std::fs::write(&faults, "description = \"LED 40 stuck on\"\n[[stuck_leds]]\nindex = 40\nstate = \"on\"\n").unwrap();
    let again = go_with(&source, Some(faults.display().to_string()));
    // View 14 was whole and is kept; view 15 is captured and processed again, frames first.
    assert_eq!(again.textures, 198, "{:?}", again.warnings);
    assert!(again.faults.contains(&"camera 4 rotation 1: LED 40 stuck".to_string()), "{:?}", again.warnings);
    let r = btfrig_store::verify(&source);
    assert!(r.is_ok(), "{r}");
    // The kept frames are the ones the textures were made from.
    let same = dir.join("reprocessed");
    reprocess(&request(&source, &same, None)).unwrap();
    assert_eq!(textures(&same), textures(&source));
    let _ = std::fs::remove_dir_all(&dir);
}
