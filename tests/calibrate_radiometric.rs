//! `btfrig calibrate radiometric` as a person runs it: the maps and header it writes read back
//! through `btfrig_calibrate::dark_flat::read_calibration`, its JSON names the truth errors, and a
//! bad plan is refused naming the field.

mod support;

use support::{btfrig, ok, repo, scratch};

#[test]
fn calibrate_radiometric_writes_maps_that_read_back_and_refuses_a_bad_plan() {
    let dir = scratch("calibrate-radiometric");
    let out = dir.join("cal");
    let small = repo("rig-configs/bonn-gonio-sim-small.toml");
    let stdout = ok(btfrig()
        .args(["calibrate", "radiometric", "--json", "--seed", "4", "--rig"])
        .arg(&small)
        .arg("--out")
        .arg(&out));
    let v: serde_json::Value = serde_json::from_str(&stdout).expect("JSON on stdout");
    assert_eq!(v["header"]["width"], 160);
    let t = &v["truth_error"];
    assert_eq!(t["hot_found"], t["hot_true"], "{t}");
    assert!(t["flat_rms_rel"][0].as_f64().unwrap() < 0.003, "{t}");
    let (header, cal) = btfrig_calibrate::dark_flat::read_calibration(&out).unwrap();
    assert_eq!((header.width, header.height, header.seed), (160, 120, 4));
    assert_eq!(cal.dark.defects() as u64, v["header"]["stats"]["defects"].as_u64().unwrap());
    assert!(cal.flat_for(Some(8.0)).is_ok());

    let plan = dir.join("bad.toml");
    let text = std::fs::read_to_string(repo("rig-configs/plans/calibration-radiometric.toml"))
        .unwrap()
        .replace("frames = 32", "frames = 1");
    std::fs::write(&plan, text).unwrap();
    let o = btfrig()
        .args(["calibrate", "radiometric", "--rig"])
        .arg(&small)
        .arg("--plan")
        .arg(&plan)
        .arg("--out")
        .arg(dir.join("bad"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("flat.frames = 1"), "{err}");
}
