//! The simulator's truth of a sensor characterisation (`btfrig_calibrate::emva`): the
//! configured sensor's figures, computed over the photosites the estimates cover. For error
//! figures only.

use btfrig_calibrate::emva::{centre_box, SensorPlan};
use btfrig_core::config::RigConfig;
use btfrig_render::sensor::SensorModel;
use serde::Serialize;

/// The true EMVA 1288 figures of a simulated rig's sensor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EmvaTruth {
    /// K at the plan's gain, DN/e⁻: gain / electrons_per_dn.
    pub system_gain_dn_per_e: f64,
    /// The configured read noise, e⁻.
    pub read_noise_e: f64,
    /// Mean dark current over the photon-transfer region, hot photosites included, e⁻/s.
    pub dark_current_e_per_s: f64,
    /// Spatial standard deviation of the dark signal at the DSNU exposure (column offsets and
    /// dark current), photosites not hot, e⁻.
    pub dsnu_e: f64,
    /// Standard deviation of the PRNU gain pattern, photosites not hot, %.
    pub prnu_pct: f64,
    /// The configured full well, e⁻ (the sensor clips 4 read-noise sigmas below it, rounded
    /// down to a whole DN: [`EmvaTruth::clip_e`]).
    pub saturation_capacity_e: f64,
    /// Where the simulated sensor clips, e⁻.
    pub clip_e: f64,
    /// The simulated sensor is linear: 0 %.
    pub linearity_error_pct: f64,
}

/// The truth of `plan` on the simulated rig `cfg`.
pub fn emva_truth(cfg: &RigConfig, plan: &SensorPlan) -> Result<EmvaTruth, String> {
    let s = SensorModel::from_config(&cfg.sensor).map_err(|e| e.to_string())?;
    let (w, h) = (cfg.camera.width_px, cfg.camera.height_px);
    let k = s.dn_per_electron(plan.gain);
    let (x0, y0, x1, y1) = centre_box(w, h, plan.photon_transfer.centre_fraction);
    let mut sum = 0.0;
    for y in y0..y1 {
        for x in x0..x1 {
            sum += s.dark_current_at(x, y);
        }
    }
    let dark_current = sum / ((x1 - x0) * (y1 - y0)) as f64;
    let t = plan.dark.exposures_s.iter().copied().fold(0.0, f64::max);
    let hot = |x: usize, y: usize| s.dark_current_at(x, y) > plan.dark.hot_threshold_e_per_s;
    let e_per_dn_base = cfg.sensor.electrons_per_dn;
    let (mut n, mut m1, mut m2) = (0.0, 0.0, 0.0);
    let (mut pn, mut p1, mut p2) = (0.0, 0.0, 0.0);
    for y in 0..h {
        for x in 0..w {
            if hot(x, y) {
                continue;
            }
            // Column offsets are DN at any gain (added after the conversion): in e⁻ at the
            // plan's gain they are offset / K.
            let d = s.column_offset_dn(x) / k + s.dark_current_at(x, y) * t;
            n += 1.0;
            m1 += d;
            m2 += d * d;
            let g = s.prnu_gain(x, y);
            pn += 1.0;
            p1 += g;
            p2 += g * g;
        }
    }
    let _ = e_per_dn_base;
    let var = (m2 / n - (m1 / n).powi(2)) * n / (n - 1.0);
    let pmean = p1 / pn;
    let pvar = (p2 / pn - pmean * pmean) * pn / (pn - 1.0);
    let clip_e = f64::from(s.white_level(plan.gain) - s.black_level_dn) / k;
    Ok(EmvaTruth {
        system_gain_dn_per_e: k,
        read_noise_e: s.read_noise_e,
        dark_current_e_per_s: dark_current,
        dsnu_e: var.sqrt(),
        prnu_pct: 100.0 * pvar.sqrt() / pmean,
        saturation_capacity_e: s.full_well_e,
        clip_e,
        linearity_error_pct: 0.0,
    })
}
