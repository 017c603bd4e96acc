//! Geometric calibration from frames on disk, as a real camera's would arrive: board frames
//! are rendered on the simulated rig by the test (btfrig-render is only a dev-dependency; the
//! library renders nothing), written as raw EXR files with their metadata, read back and
//! calibrated with `plan_captures` and `calibrate_captures`. The result is compared with the
//! lens the renderer imaged with (the rig config's own `[camera]` fields).

use btfrig_calibrate::{calibrate_captures, plan_captures, BoardCaptures, CalibrationPlan, RigCalibError, Ring};
use btfrig_core::config::RigConfig;
use btfrig_imageio::{read_raw_exr, write_raw_exr};
use btfrig_intrinsics::mapping_difference_up_to_rotation;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;

#[test]
fn a_calibration_from_frames_read_back_from_disk_recovers_the_rendering_lens() {
    let cfg =
        RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "bonn-gonio-sim.toml").unwrap();
    // Twelve views and coarse edge supersampling keep the render short; one detection pass;
    // the tangential terms (tiny here, and correlated with the principal point) held at 0.
    let plan = CalibrationPlan {
        marker_supersampling: 2,
        passes: 1,
        estimate_tangential: false,
        rings: vec![
            Ring { theta_deg: 0.0, count: 4, phi_offset_deg: 10.0 },
            Ring { theta_deg: 20.0, count: 4, phi_offset_deg: 10.0 },
            Ring { theta_deg: 35.0, count: 4, phi_offset_deg: 55.0 },
        ],
        ..CalibrationPlan::default_plan()
    };
    let captures = plan_captures(&cfg, &plan).unwrap();
    assert_eq!(captures.len(), 12);
    assert!(captures.iter().all(|c| c.skipped.is_none()), "every view reachable");

    // The "camera": rendered frames, each written to disk with a seeded noise stream.
    let dir = std::env::temp_dir().join(format!("btfrig-geometry-from-files-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = RigScene::with_target(&cfg, &plan.target).unwrap();
    let exposure = scene.exposure_for_white(plan.exposure_fraction, 1e-4, 30.0);
    let opts = RenderOptions { marker_supersampling: plan.marker_supersampling, ..RenderOptions::default() };
    let files: Vec<_> = captures
        .iter()
        .enumerate()
        .map(|(i, cap)| {
            let (raw, _) = scene.capture(&cap.joints, 1.0, exposure, 1.0, 1000 + i as u64, &opts).unwrap();
            let path = dir.join(format!("view-{i:02}.exr"));
            write_raw_exr(&path, &raw).unwrap();
            path
        })
        .collect();
    drop(scene);

    // The procedure sees only files, the rig config and the plan.
    let frames = files.iter().map(|p| Some(read_raw_exr(p).unwrap())).collect();
    std::fs::remove_dir_all(&dir).ok();
    let shots = BoardCaptures { frames, captures: captures.clone(), render_s: 0.0 };
    let r = calibrate_captures(&cfg, &plan, &shots, |l| eprintln!("{l}")).unwrap();
    let (e, t) = (&r.calibration.camera, cfg.camera.to_model().unwrap());
    let (fx_rel, fy_rel) = (e.fx / t.fx - 1.0, e.fy / t.fy - 1.0);
    let (dcx, dcy) = (e.cx - t.cx, e.cy - t.cy);
    let (rot_px, _) = mapping_difference_up_to_rotation(&t, e, 81);
    eprintln!(
        "{} views, {} corners: fx {:+.4}% fy {:+.4}%, cx {dcx:+.3} cy {dcy:+.3} px, k1 {:.5} (true {:.5}), rms {:.4} px, \
         mapping up to rotation {rot_px:.4} px",
        r.views_used(),
        r.calibration.points_used,
        fx_rel * 100.0,
        fy_rel * 100.0,
        e.distortion.k1,
        t.distortion.k1,
        r.calibration.rms_px
    );
    assert_eq!(r.views_used(), 12, "every view calibrated");
    assert!(r.calibration.points_used > 2000, "{}", r.calibration.points_used);
    // Twelve views at supersampling 2 instead of the default plan's 34 at 8: bounds a few times
    // looser than the default plan's (docs/camera-calibration.md), far below what a wrong
    // pairing or pose costs (percents, tens of pixels).
    assert!(fx_rel.abs() < 0.002 && fy_rel.abs() < 0.002, "focal length {fx_rel} {fy_rel}");
    assert!(dcx.abs() < 2.0 && dcy.abs() < 2.0, "principal point ({dcx}, {dcy}) px");
    assert!((e.distortion.k1 - t.distortion.k1).abs() < 0.005, "k1 {} vs {}", e.distortion.k1, t.distortion.k1);
    assert!(rot_px < 0.5, "mapping up to rotation {rot_px} px");
    assert!(r.calibration.rms_px < 0.1, "rms {}", r.calibration.rms_px);

    // Frames that do not match the plan's captures are refused, naming both counts.
    let short = BoardCaptures { frames: vec![None; 3], captures, render_s: 0.0 };
    let e = calibrate_captures(&cfg, &plan, &short, |_| {}).unwrap_err();
    assert!(matches!(e, RigCalibError::Rig(_)) && e.to_string().contains("3 frames for 12 planned captures"), "{e}");
}
