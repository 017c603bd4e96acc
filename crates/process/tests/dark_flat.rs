//! Dark and flat-field correction measured on the simulated rig (btfrig-calibrate) against the
//! lens model's own vignetting and against no correction, on textures vs the ground truth.

mod common;

use std::sync::Arc;

use btfrig_calibrate::dark_flat::RadiometricPlan;
use btfrig_core::config::RigConfig;
use btfrig_core::Direction;
use btfrig_imaging::dark_flat::{DarkFlat, DarkModel, FlatField};
use btfrig_imaging::{Filter, Region};
use btfrig_process::dark_flat::{demosaic_corrected, photosite_rates};
use btfrig_process::{ProcessSettings, Processor, RegistrationMethod, RegistrationPolicy};
use btfrig_render::material::MaterialSpec;
use btfrig_render::radiance::RadianceImage;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_sim_calibration::dark_flat::calibrate_simulated;
use btfrig_store::StepId;

const SMALL: &str = include_str!("../../../rig-configs/bonn-gonio-sim-small.toml");

const MATTE: &str = r#"
name = "matte"
texels = 64
seed = 2
basis = ["colorchecker:light skin", "colorchecker:foliage", "flat:0.6"]
[albedo]
pattern = { kind = "noise", scale_m = 0.08, octaves = 1 }
stops = [[0.6, 0.0, 0.4], [0.0, 0.6, 0.4]]
"#;

fn rig() -> RigConfig {
    RigConfig::from_toml(SMALL, "bonn-gonio-sim-small").unwrap()
}

/// A calibration that corrects nothing but the nominal black level.
fn no_correction(cfg: &RigConfig, like: &DarkFlat) -> DarkFlat {
    let n = like.dark.width * like.dark.height;
    let dark = DarkModel {
        bias_dn: vec![f32::from(cfg.sensor.black_level_dn); n],
        rate_e_per_s: vec![0.0; n],
        defect: vec![false; n],
        ..like.dark.clone()
    };
    let flats = like.flats.iter().map(|f| FlatField { gain: vec![1.0; n], ..f.clone() }).collect();
    DarkFlat { dark, flats }
}

fn rel_rmse(tex: &[[f32; 3]], gt: &[[f32; 3]], keep: impl Fn(usize) -> bool) -> f64 {
    let (mut se, mut st) = (0.0, 0.0);
    for (_, (a, b)) in tex.iter().zip(gt).enumerate().filter(|(i, _)| keep(*i)) {
        for c in 0..3 {
            se += (f64::from(a[c]) - f64::from(b[c])).powi(2);
            st += f64::from(b[c]).powi(2);
        }
    }
    (se / st).sqrt()
}

#[test]
fn measured_dark_and_flat_correct_textures_as_well_as_the_model_and_far_better_than_nothing() {
    let cfg = rig();
    let plan = RadiometricPlan::default_plan();
    let cal = Arc::new(calibrate_simulated(&cfg, &plan, 3, |_| {}).unwrap().cal);
    // A matte sample with a smooth albedo that fills a 0.25 m square seen frontally: the
    // texture's corners reach the image's edges, where the small rig's lens vignettes by ~15%,
    // and little of the error is resampling of sharp edges (the small rig has 2.5 mm pixels).
    let mut cfg = cfg;
    cfg.plate.side_m = 0.6;
    cfg.plate.sample_side_m = 0.4;
    cfg.plate.marker_ring_m = 0.26;
    let material = MaterialSpec::from_toml(MATTE, "matte").unwrap();
    let scene = Arc::new(RigScene::new(&cfg, &material).unwrap());
    let size = 40;
    let settings = ProcessSettings {
        size,
        region: Region::centred_square(0.25),
        filter: Filter::Bilinear,
        registration: RegistrationPolicy { method: RegistrationMethod::Nominal, ..Default::default() },
    };
    let base = common::truth_model(&cfg, &scene);
    let model = common::processor(&cfg, &scene, settings);
    let measured = common::processor_with(base.clone().with_dark_flat(Some(cal.clone())), &scene, settings);
    // A calibration of another size is refused when the processor is built.
    let mut wrong = (*cal).clone();
    wrong.dark.width += 2;
    let e = Processor::new(base.clone().with_dark_flat(Some(Arc::new(wrong))), settings).err();
    assert!(e.unwrap().to_string().contains("the calibration 162x120"));
    let none = common::processor_with(base.with_dark_flat(Some(Arc::new(no_correction(&cfg, &cal)))), &scene, settings);
    let joints = scene.gonio().ik(Direction::from_degrees(30.0, 0.0), Direction::from_degrees(0.0, 0.0)).unwrap();
    let exposure = scene.exposure_for_white(0.5, 1e-4, 30.0);
    let corner = |i: usize| {
        let (x, y) = (i % size, i / size);
        let edge = |v: usize| v < size / 5 || v >= size - size / 5;
        edge(x) && edge(y)
    };
    let step = StepId { light: 0, view: 0 };
    let gt = model.ground_truth(&joints, 1.0).unwrap();
    let (mut whole, mut corners) = ([0.0; 3], [0.0; 3]);
    let seeds = 4;
    for seed in 0..seeds {
        let (mut frame, _) = scene.capture(&joints, 1.0, exposure, 1.0, 100 + seed, &RenderOptions::default()).unwrap();
        frame.meta.f_number = Some(cfg.camera.f_number);
        for (k, p) in [&model, &measured, &none].into_iter().enumerate() {
            let tex = p.process(step, &frame, &joints, None).unwrap().texels;
            whole[k] += rel_rmse(&tex, &gt, |_| true) / seeds as f64;
            corners[k] += rel_rmse(&tex, &gt, corner) / seeds as f64;
        }
    }
    eprintln!(
        "exposure {exposure:.4} s; rel RMSE whole texture: model {:.4}, measured {:.4}, none {:.4}; \
         corner texels: model {:.4}, measured {:.4}, none {:.4}",
        whole[0], whole[1], whole[2], corners[0], corners[1], corners[2]
    );
    // Measured dark + flat: at least as good as the model's own vignetting (within 1% of it:
    // both carry the same colour-matrix and resampling error), far better than nothing.
    assert!(whole[1] <= whole[0] * 1.01 && corners[1] <= corners[0] * 1.01, "{whole:?} {corners:?}");
    assert!(corners[2] > 1.5 * corners[1] && whole[2] > whole[1], "{whole:?} {corners:?}");
}

#[test]
fn a_long_dark_frame_is_flat_zero_after_correction_hot_pixels_and_column_offsets_removed() {
    let cfg = rig();
    let plan = RadiometricPlan::default_plan();
    let cal = calibrate_simulated(&cfg, &plan, 5, |_| {}).unwrap().cal;
    let sensor = btfrig_render::sensor::SensorModel::from_config(&cfg.sensor).unwrap();
    let (w, h) = (cfg.camera.width_px, cfg.camera.height_px);
    // 1.5 s, gain 2: an exposure the plan never took (the model covers it).
    let mut frame = sensor.capture(&RadianceImage::filled(w, h, [0.0; 3]), 1.5, 2.0, 999).unwrap();
    frame.meta.f_number = Some(cfg.camera.f_number);
    let raw_max = frame.data.iter().map(|&d| f64::from(d) - f64::from(cfg.sensor.black_level_dn)).fold(0.0, f64::max);
    let img = demosaic_corrected(&frame, &cal).unwrap();
    let range = f64::from(frame.meta.white_level - frame.meta.black_level);
    let corrected: Vec<f64> = img.data.iter().map(|p| f64::from(p[1]) * range).collect();
    let max = corrected.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let rms = (corrected.iter().map(|v| v * v).sum::<f64>() / corrected.len() as f64).sqrt();
    // Read noise 3 e- at gain 2 = 2.4 DN (plus a little dark shot noise): the rest is gone.
    eprintln!("dark 1.5 s gain 2: raw max {raw_max:.0} DN above black; corrected RMS {rms:.2} DN, max {max:.1} DN");
    assert!(raw_max > 500.0, "hot photosites show in the raw frame: {raw_max}");
    assert!(rms < 3.0 && max < 6.0 * 2.6, "rms {rms}, max {max}");
    // The per-photosite rates of a frame: a uniform field of known rate comes back as that rate.
    let model = cfg.camera.to_model().unwrap();
    let rate = 20_000.0;
    let flat = btfrig_render::flat_field::flat_field_radiance(
        &btfrig_render::rig_scene::CachedCamera::new(model),
        [rate, rate, rate],
    );
    let mut f = sensor.capture(&flat, 0.05, 1.0, 4).unwrap();
    f.meta.f_number = Some(cfg.camera.f_number);
    let r = photosite_rates(&f, &cal).unwrap();
    let mean = r.iter().map(|&v| f64::from(v)).sum::<f64>() / r.len() as f64;
    // The flat is 1 at the centre, where vignetting is ~1 (cos^4 and poly at rho ~ 0).
    assert!((mean / rate - 1.0).abs() < 0.01, "mean rate {mean} vs {rate}");
}
