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

    // A run corrects its frames with the calibration (`btfrig run --dark-flat DIR`), HDR
    // brackets merged with it too: the glazed tile near its mirror direction on the small rig.
    let plan = dir.join("run.toml");
    std::fs::write(
        &plan,
        format!(
            "name = \"dark-flat run\"\n[rig]\nconfig = {small:?}\nmaterial = \"glazed-tile\"\nseed = 4\n\
             [sampling]\nlight = {{ list = [[45, 0]] }}\nview = {{ list = [[45, 180], [30, 180], [45, 90]] }}\n\
             [texture]\nsize = 16\n[registration]\nmethod = \"nominal\"\n[exposure]\nmode = \"auto\"\nhdr = \"adaptive\"\n"
        ),
    )
    .unwrap();
    let with = |cal: bool, name: &str| {
        let mut cmd = btfrig();
        cmd.args(["run", "--plan"]).arg(&plan).arg("--out").arg(dir.join(name));
        if cal {
            cmd.arg("--dark-flat").arg(&out);
        }
        let stdout = ok(&mut cmd);
        let manifest: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join(name).join("manifest.json")).unwrap()).unwrap();
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join(name).join("report.json")).unwrap()).unwrap();
        (stdout, manifest, report)
    };
    let (stdout, manifest, report) = with(true, "with");
    let rec = &manifest["calibration"]["dark_flat"];
    assert_eq!(rec["source"], out.display().to_string(), "{rec}");
    assert_eq!(rec["defects"].as_u64(), Some(cal.dark.defects() as u64));
    assert!(stdout.contains("HDR: captures by exposures"), "{stdout}");
    let (_, plain, plain_report) = with(false, "without");
    assert!(plain["calibration"]["dark_flat"].is_null());
    let e_with = report["texture_rel_rmse"].as_f64().unwrap();
    let e_without = plain_report["texture_rel_rmse"].as_f64().unwrap();
    println!("texture rel. RMSE with the measured dark/flat {e_with:.4}, with the sensor model's {e_without:.4}");
    // The measured calibration is as good as knowing the model (it also removes PRNU).
    assert!(e_with < 1.05 * e_without, "{e_with} vs {e_without}");
    assert!(report["hdr"]["exposures_per_capture"].as_object().is_some_and(|m| m.keys().any(|k| k != "1")));

    // A calibration of another camera is refused before anything is written, naming both sizes.
    let o = btfrig()
        .args(["run", "--plan"])
        .arg(repo("rig-configs/plans/demo.toml"))
        .arg("--out")
        .arg(dir.join("other-camera"))
        .arg("--dark-flat")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("160x120") && err.contains("1600x1200"), "{err}");
    assert!(!dir.join("other-camera").exists(), "nothing is created");
}
