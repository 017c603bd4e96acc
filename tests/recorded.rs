//! The recorded camera through the `btfrig` binary (docs/recorded-camera.md): a run that keeps
//! its raw frames, `btfrig dataset export-recording`, `btfrig hw probe --recorded`, and the same
//! plan run again with `btfrig run --rig REC/rig.toml`: the same texture files. A broken
//! recording fails before anything is created.

mod support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use support::{btfrig, ok, repo, text};

/// Four captures up to theta 15 deg on the small-camera rig, 16-texel textures, raw frames kept.
fn plan(dir: &Path) -> PathBuf {
    let p = dir.join("plan.toml");
    std::fs::write(
        &p,
        format!(
            r#"name = "replay-cli"
[rig]
config = "{}"
material = "corduroy"
seed = 3
[sampling]
light = {{ preset = "bonn81", theta_max_deg = 15 }}
view = {{ preset = "bonn81", theta_max_deg = 15 }}
[texture]
size = 16
[exposure]
mode = "auto"
[skip]
max_captures = 4
[outputs]
raw_frames = true
"#,
            repo("rig-configs/bonn-gonio-sim-small.toml").display()
        ),
    )
    .unwrap();
    p
}

fn textures(dataset: &Path) -> BTreeMap<String, String> {
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

#[test]
fn a_run_exported_and_replayed_through_the_cli_gives_the_same_textures() {
    let dir = support::scratch("recorded-cli");
    let plan = plan(&dir);
    let (source, rec, replay) = (dir.join("source"), dir.join("rec"), dir.join("replay"));
    ok(btfrig().args(["run", "--plan"]).arg(&plan).arg("--out").arg(&source));
    let out = ok(btfrig()
        .args(["dataset", "export-recording"])
        .arg(&source)
        .arg("--out")
        .arg(&rec)
        .args(["--format", "tiff"]));
    assert!(out.contains("4 frames of 4 captures") && out.contains("rig.toml"), "{out}");

    let probe = ok(btfrig().args(["hw", "probe", "--recorded"]).arg(&rec));
    assert!(
        probe.contains("usable") && probe.contains("frames    4 (TIFF x4)") && probe.contains("160x120"),
        "{probe}"
    );

    let out = ok(btfrig()
        .args(["run", "--plan"])
        .arg(&plan)
        .arg("--rig")
        .arg(rec.join("rig.toml"))
        .arg("--out")
        .arg(&replay));
    assert!(out.contains("4"), "{out}");
    let original = textures(&source);
    assert_eq!(original.len(), 4);
    assert_eq!(textures(&replay), original);

    // Broken: a frame file gone. Refused before the dataset exists, naming the file and field.
    let name = std::fs::read_dir(&rec)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .find(|n| n.ends_with(".tif"))
        .unwrap();
    std::fs::remove_file(rec.join(&name)).unwrap();
    let again = dir.join("again");
    let o = btfrig()
        .args(["run", "--plan"])
        .arg(&plan)
        .arg("--rig")
        .arg(rec.join("rig.toml"))
        .arg("--out")
        .arg(&again)
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(&name) && err.contains(".file") && err.contains("missing"), "{err}");
    assert!(!again.exists(), "a refused run created its output directory");
    let o = btfrig().args(["hw", "probe", "--recorded"]).arg(&rec).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stdout).contains("NOT USABLE"), "{}", text(&o));
}
