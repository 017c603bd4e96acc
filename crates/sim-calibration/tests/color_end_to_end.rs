//! End to end: a material's texture, processed by the pipeline, against the simulator's
//! ground truth (linear sRGB radiance factor), with the colour calibration made on the same
//! simulated rig against without it (white-balanced camera RGB only). The calibration must
//! cut the texels' mean CIEDE2000 and the texture's relative RMSE; the figures are in
//! docs/color.md.

use btfrig_hw::truth::ExposureTruth;
use btfrig_sim::truth::SceneTruth;
use btfrig_sim::RenderedFrameSource;
use std::sync::Arc;

use btfrig_calibrate::color::ColorPlan;
use btfrig_calibrate::processing_camera;
use btfrig_color::{delta_e_2000, space::linear_srgb_to_lab};
use btfrig_core::config::RigConfig;
use btfrig_core::Direction;
use btfrig_imaging::{Filter, Region};
use btfrig_process::color::ColorCorrection;
use btfrig_process::{ProcessSettings, Processor};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim_calibration::color::calibrate_color_simulated;
use btfrig_store::StepId;

fn rig() -> RigConfig {
    RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "bonn-gonio-sim.toml").unwrap()
}

/// Mean CIEDE2000 over texels (Lab relative to the output space's white (1, 1, 1)), over
/// texels whose truth is not black (the texture's few shadowed texels carry no colour).
fn mean_de00(tex: &[[f32; 3]], gt: &[[f32; 3]]) -> f64 {
    let lab = |p: &[f32; 3]| linear_srgb_to_lab(p.map(f64::from));
    let v: Vec<f64> = tex
        .iter()
        .zip(gt)
        .filter(|(_, g)| g.iter().cloned().fold(0.0f32, f32::max) > 0.01)
        .map(|(t, g)| delta_e_2000(lab(t), lab(g)))
        .collect();
    assert!(v.iter().all(|x| x.is_finite()));
    v.iter().sum::<f64>() / v.len() as f64
}

/// Mean CIEDE2000 of `k x k`-texel block means (a `n x n` texture): the texture's colour with
/// the per-texel sensor noise averaged out (noise alone gives dark texels several dE00).
fn block_de00(tex: &[[f32; 3]], gt: &[[f32; 3]], n: usize, k: usize) -> f64 {
    let mean = |img: &[[f32; 3]], bx: usize, by: usize| {
        let mut m = [0.0f64; 3];
        for y in by * k..(by + 1) * k {
            for x in bx * k..(bx + 1) * k {
                for c in 0..3 {
                    m[c] += f64::from(img[y * n + x][c]) / (k * k) as f64;
                }
            }
        }
        m
    };
    let mut v = Vec::new();
    for by in 0..n / k {
        for bx in 0..n / k {
            let (t, g) = (mean(tex, bx, by), mean(gt, bx, by));
            v.push(delta_e_2000(linear_srgb_to_lab(t), linear_srgb_to_lab(g)));
        }
    }
    assert!(v.iter().all(|x| x.is_finite()));
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn colour_calibration_cuts_a_materials_colour_error() {
    let cfg = rig();
    let cam = processing_camera(&cfg, None).unwrap();
    let cal = calibrate_color_simulated(&cfg, &cam, &ColorPlan::default_plan(), 3, |_| {}).unwrap();
    let chosen = cal.chosen();
    let calibrated =
        ColorCorrection { name: "test".into(), white_balance: cal.white_balance, model: chosen.model.clone().unwrap() };
    let plain = ColorCorrection::white_balance_only(cal.white_balance);
    let settings = ProcessSettings {
        size: 128,
        region: Region::centred_square(0.05),
        filter: Filter::Supersample { n: 2 },
        registration: Default::default(),
    };
    let mut report = Vec::new();
    for material in ["lacquered-wood", "leather", "glazed-tile"] {
        let scene = Arc::new(RigScene::new(&cfg, &MaterialSpec::builtin(material).unwrap()).unwrap());
        let joints =
            scene.gonio().ik(Direction::from_degrees(40.0, 180.0), Direction::from_degrees(20.0, 30.0)).unwrap();
        let exposure = scene.exposure_for_white(0.5, 1e-4, 30.0);
        let (frame, _) = scene.capture(&joints, 1.0, exposure, 1.0, 21, &RenderOptions::default()).unwrap();
        let step = StepId { light: 0, view: 0 };
        let run = |c: Option<ColorCorrection>| {
            // The simulator's own constants, the calibrated camera, and the colour under test
            // (`None`: the simulator's manufacturer-style matrix).
            let mut model = btfrig_sim_calibration::perfect::truth_model(&cfg, &scene);
            model.camera = cam.clone();
            if c.is_some() {
                model = model.with_color(c);
            }
            let probe = SceneTruth::new(
                scene.clone(),
                Arc::new(RenderedFrameSource::new(scene.clone(), RenderOptions::default())),
            );
            let p = Processor::new(model, settings).unwrap().with_truth(Some(Arc::new(probe)));
            let truth = ExposureTruth { joints, lamp_intensity: 1.0 };
            let out = p.process(step, &frame, &joints, Some(truth)).unwrap();
            let gt = p.ground_truth(&joints, 1.0).unwrap();
            (
                mean_de00(&out.texels, &gt),
                block_de00(&out.texels, &gt, 128, 8),
                btfrig_imaging::rel_rmse(&out.texels, &gt).unwrap(),
            )
        };
        let (tde_cal, de_cal, rmse_cal) = run(Some(calibrated.clone()));
        let (tde_plain, de_plain, rmse_plain) = run(Some(plain.clone()));
        let (tde_model, de_model, rmse_model) = run(None);
        eprintln!(
            "{material}: dE00 of 8x8-texel means: white balance only {de_plain:.2}, calibrated ({}) {de_cal:.2}, \
             rig-model matrix {de_model:.2}; per texel {tde_plain:.2} / {tde_cal:.2} / {tde_model:.2}; rel RMSE \
             {rmse_plain:.4} / {rmse_cal:.4} / {rmse_model:.4}",
            chosen.kind.name()
        );
        report.push((material, de_plain, de_cal, de_model, rmse_plain, rmse_cal));
    }
    for (material, de_plain, de_cal, de_model, rmse_plain, rmse_cal) in report {
        // Measured: see docs/color.md ("End to end"). The colour error of the texture falls by
        // more than half; the relative RMSE (noise and gloss dominate it) must not get worse.
        assert!(de_cal < 0.5 * de_plain, "{material}: dE00 {de_cal} vs {de_plain} without calibration");
        assert!(rmse_cal < 1.02 * rmse_plain, "{material}: rel RMSE {rmse_cal} vs {rmse_plain}");
        // And about as good as the matrix fitted on the simulator's true spectra, which a real
        // rig does not have.
        assert!(de_cal < de_model + 0.5, "{material}: dE00 {de_cal} vs {de_model} with the rig model's matrix");
    }
}
