//! The lamp factor measured on the holder plate, frame by frame, against the lamp intensity the
//! simulator rendered with: at moderate and grazing angles, on a material with strong relief
//! (whose shadows and occlusion reach the plate next to the sample).

mod common;

use std::sync::Arc;

use btfrig_core::config::RigConfig;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_core::Direction;
use btfrig_imaging::{Filter, Region};
use btfrig_process::light::{LampReference, LightCorrection};
use btfrig_process::ProcessSettings;
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::{resolve_spectrum, RigScene};
use btfrig_store::StepId;

#[test]
fn the_plate_measures_the_lamp_intensity_of_each_frame_at_moderate_and_grazing_angles() {
    let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "builtin rig").unwrap();
    let scene = Arc::new(RigScene::new(&cfg, &MaterialSpec::builtin("corduroy").unwrap()).unwrap());
    let settings = ProcessSettings {
        size: 32,
        region: Region::centred_square(0.05),
        filter: Filter::Bilinear,
        registration: Default::default(),
    };
    // The reference from the simulator's truth (the calibration's own test compares the
    // measured one with it): this test is about the per-frame measurement.
    let white = scene.colour().camera_white();
    let nominal = scene.white_signal_dn(1.0, 1.0) / scene.sensor().dn_per_electron(1.0);
    let (plate, _) = resolve_spectrum(scene.colour(), &cfg.plate.albedo).unwrap();
    let light = LightCorrection::new(LampReference {
        light: "lamp".into(),
        white_rate: std::array::from_fn(|c| nominal * white[c]),
        plate_albedo: std::array::from_fn(|c| plate[c] / white[c]),
    });
    let p = common::processor_with(common::truth_model(&cfg, &scene).with_light(Some(light)), &scene, settings);
    let exposure = scene.exposure_for_white(0.5, 1e-4, 30.0);
    let cases = [
        ((30.0, 0.0), (20.0, 180.0), 1.0),
        ((45.0, 90.0), (30.0, 0.0), 0.95),
        // Grazing light across the ridges, grazing view: shadows and occlusion near the sample.
        ((75.0, 0.0), (60.0, 200.0), 0.9),
        ((70.0, 270.0), (10.0, 0.0), 1.03),
    ];
    for (i, ((lt, lp), (vt, vp), lamp)) in cases.into_iter().enumerate() {
        let joints = scene.gonio().ik(Direction::from_degrees(lt, lp), Direction::from_degrees(vt, vp)).unwrap();
        let (frame, _) = scene.capture(&joints, lamp, exposure, 1.0, 20 + i as u64, &RenderOptions::default()).unwrap();
        let out = p.process(StepId { light: i as u32, view: 0 }, &frame, &joints, common::at(joints, lamp)).unwrap();
        let f = out.lamp_factor.expect("the plate is measurable");
        let b = out.brightness_err.unwrap();
        println!(
            "light ({lt}, {lp}) view ({vt}, {vp}) lamp {lamp}: factor {:.5} {:.5} {:.5} (sigma {:.1e}, {} points), \
             brightness vs nominal-lamp truth {:+.3} %",
            f.factor[0],
            f.factor[1],
            f.factor[2],
            f.sigma[1],
            f.points,
            100.0 * b
        );
        // Measured: within 0.03 % of the rendered lamp intensity in every case (docs/light.md).
        for c in 0..3 {
            assert!(
                (f.factor[c] / lamp - 1.0).abs() < 2e-3,
                "case {i} channel {c}: factor {} vs lamp {lamp}",
                f.factor[c]
            );
        }
        assert!(f.points > 1000, "{f:?}");
    }
}
