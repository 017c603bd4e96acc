//! The dark and flat calibration on the simulated rig: frames from the rig's sensor model,
//! dark frames with zero light, flats from [`btfrig_render::flat_field`] (a uniform field
//! through the true lens); the procedure is `btfrig_calibrate::dark_flat::calibrate`.
//! [`compare_with_truth`] measures a calibration against the simulated sensor's true dark
//! signal and relative gain.

use btfrig_calibrate::dark_flat::{
    calibrate, DarkFlatCalError, DarkFlatCamera, DarkFlatResult, DarkFlatShot, RadiometricPlan,
};
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_imaging::dark_flat::DarkFlat;
use btfrig_render::flat_field::{flat_field_radiance, white_flat_level};
use btfrig_render::radiance::RadianceImage;
use btfrig_render::rig_scene::CachedCamera;
use btfrig_render::sensor::SensorModel;
use serde::Serialize;

/// The seed of frame `k` of capture group `group`: distinct, well-mixed streams.
fn frame_seed(seed: u64, group: u64, k: u64) -> u64 {
    let mut z = seed ^ (group << 32) ^ k ^ 0x5eed_da4c_f1a7_0000;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The simulated camera of a radiometric plan: its sensor model in the dark and in front of
/// a uniform field (the plan's flat level), frame noise seeded from the seed, the capture
/// group and the frame.
pub struct SimDarkFlatCamera {
    sensor: SensorModel,
    camera: CachedCamera,
    dark: RadianceImage,
    /// The flat field's level, and its image made when the first flat is asked for (as
    /// before the split: not held while the darks are taken).
    flat_level: [f64; 3],
    flat: Option<RadianceImage>,
    seed: u64,
}

impl SimDarkFlatCamera {
    /// The camera of rig `cfg` for `plan`.
    pub fn new(cfg: &RigConfig, plan: &RadiometricPlan, seed: u64) -> Result<SimDarkFlatCamera, DarkFlatCalError> {
        let rig = |e: &dyn std::fmt::Display| DarkFlatCalError::Rig(e.to_string());
        cfg.validate().map_err(|e| rig(&e))?;
        let sensor = SensorModel::from_config(&cfg.sensor).map_err(|e| rig(&e))?;
        let camera = CachedCamera::new(cfg.camera.to_model().map_err(|e| rig(&e))?);
        let colour = btfrig_render::colour::ColourSystem::from_config(&cfg.lamp, &cfg.sensor).map_err(|e| rig(&e))?;
        let (w, h) = (cfg.camera.width_px, cfg.camera.height_px);
        let full_scale_e = f64::from(sensor.white_level(plan.flat.gain) - sensor.black_level_dn)
            / sensor.dn_per_electron(plan.flat.gain);
        let level = white_flat_level(colour.camera_white(), plan.flat.level, full_scale_e, plan.flat.exposure_s);
        Ok(SimDarkFlatCamera {
            sensor,
            camera,
            dark: RadianceImage::filled(w, h, [0.0; 3]),
            flat_level: level,
            flat: None,
            seed,
        })
    }
}

impl DarkFlatCamera for SimDarkFlatCamera {
    fn capture(&mut self, shot: &DarkFlatShot) -> Result<RawFrame, String> {
        let img = if shot.flat {
            let (camera, level) = (&self.camera, self.flat_level);
            &*self.flat.get_or_insert_with(|| flat_field_radiance(camera, level))
        } else {
            &self.dark
        };
        let s = frame_seed(self.seed, shot.group, shot.frame);
        let mut f = self.sensor.capture(img, shot.exposure_s, shot.gain, s).map_err(|e| e.to_string())?;
        f.meta.f_number = Some(shot.f_number);
        Ok(f)
    }
}

/// Runs the plan on the simulated rig `cfg` (noise from `seed`) and fits the calibration;
/// `progress` gets one line per capture group.
pub fn calibrate_simulated(
    cfg: &RigConfig,
    plan: &RadiometricPlan,
    seed: u64,
    progress: impl FnMut(&str),
) -> Result<DarkFlatResult, DarkFlatCalError> {
    let mut rig = SimDarkFlatCamera::new(cfg, plan, seed)?;
    calibrate(cfg, plan, &mut rig, progress)
}

/// Errors of a calibration against the simulator's truth.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DarkFlatTruthError {
    /// RMS of (measured - true) bias over non-defect photosites, DN.
    pub bias_rms_dn: f64,
    /// RMS of (measured - true) / standard error of the bias (about 1 when the errors are right).
    pub bias_z_rms: f64,
    /// RMS of (measured - true) dark current over non-defect photosites, e-/s.
    pub rate_rms_e_per_s: f64,
    /// RMS of (measured - true) / standard error of the dark current.
    pub rate_z_rms: f64,
    /// True hot photosites (dark current above the threshold).
    pub hot_true: usize,
    /// True hot photosites flagged.
    pub hot_found: usize,
    /// Photosites flagged that are not truly hot.
    pub false_defects: usize,
    /// Per flat: RMS of (measured - true) relative gain, relative to the true one, over
    /// non-defect photosites (true: vignetting x PRNU normalised like the flat).
    pub flat_rms_rel: Vec<f64>,
    /// Per flat: the same over the corner regions (outer 10% of each side).
    pub flat_corner_rms_rel: Vec<f64>,
}

/// Compares `cal` with the simulated rig's true dark signal (black level + column offset,
/// per-photosite dark current) and true relative gain (vignetting x PRNU).
pub fn compare_with_truth(
    cfg: &RigConfig,
    cal: &DarkFlat,
    centre_fraction: f64,
) -> Result<DarkFlatTruthError, DarkFlatCalError> {
    let rig = |e: &dyn std::fmt::Display| DarkFlatCalError::Rig(e.to_string());
    let sensor = SensorModel::from_config(&cfg.sensor).map_err(|e| rig(&e))?;
    let model = cfg.camera.to_model().map_err(|e| rig(&e))?;
    let d = &cal.dark;
    let (w, h) = (d.width, d.height);
    let (mut sb, mut zb, mut sr, mut zr, mut n) = (0.0, 0.0, 0.0, 0.0, 0usize);
    let (mut hot_true, mut hot_found, mut false_defects) = (0, 0, 0);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let true_rate = sensor.dark_current_at(x, y);
            let hot = true_rate > d.hot_threshold_e_per_s;
            hot_true += usize::from(hot);
            hot_found += usize::from(hot && d.defect[i]);
            false_defects += usize::from(!hot && d.defect[i]);
            if d.defect[i] {
                continue;
            }
            let eb = f64::from(d.bias_dn[i]) - f64::from(sensor.black_level_dn) - sensor.column_offset_dn(x);
            let er = f64::from(d.rate_e_per_s[i]) - true_rate;
            sb += eb * eb;
            zb += (eb / f64::from(d.bias_sigma_dn[i])).powi(2);
            sr += er * er;
            zr += (er / f64::from(d.rate_sigma_e_per_s[i])).powi(2);
            n += 1;
        }
    }
    let nn = n.max(1) as f64;
    let mut flat_rms_rel = Vec::new();
    let mut flat_corner_rms_rel = Vec::new();
    for f in &cal.flats {
        let truth: Vec<f64> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                model.vignetting(nalgebra::Point2::new(x as f64, y as f64)) * sensor.prnu_gain(x, y)
            })
            .collect();
        // Normalise the truth like the flat: per channel over the same centre box.
        let (bw, bh) = (((w as f64 * centre_fraction) as usize).max(2), ((h as f64 * centre_fraction) as usize).max(2));
        let (x0, y0) = ((w - bw.min(w)) / 2, (h - bh.min(h)) / 2);
        let (mut sum, mut cnt) = ([0.0; 3], [0usize; 3]);
        for y in y0..(y0 + bh).min(h) {
            for x in x0..(x0 + bw).min(w) {
                if !d.defect[y * w + x] {
                    sum[sensor.channel_at(x, y)] += truth[y * w + x];
                    cnt[sensor.channel_at(x, y)] += 1;
                }
            }
        }
        let norm: [f64; 3] = std::array::from_fn(|c| if cnt[c] > 0 { sum[c] / cnt[c] as f64 } else { 1.0 });
        let norm = if sensor.bayer.is_none() { [norm[1]; 3] } else { norm };
        let (mut s, mut k, mut sc, mut kc) = (0.0, 0usize, 0.0, 0usize);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if d.defect[i] {
                    continue;
                }
                let t = truth[i] / norm[sensor.channel_at(x, y)];
                let e = (f64::from(f.gain[i]) - t) / t;
                s += e * e;
                k += 1;
                let edge = |v: usize, n: usize| v < n / 10 || v >= n - n / 10;
                if edge(x, w) && edge(y, h) {
                    sc += e * e;
                    kc += 1;
                }
            }
        }
        flat_rms_rel.push((s / k.max(1) as f64).sqrt());
        flat_corner_rms_rel.push((sc / kc.max(1) as f64).sqrt());
    }
    Ok(DarkFlatTruthError {
        bias_rms_dn: (sb / nn).sqrt(),
        bias_z_rms: (zb / nn).sqrt(),
        rate_rms_e_per_s: (sr / nn).sqrt(),
        rate_z_rms: (zr / nn).sqrt(),
        hot_true,
        hot_found,
        false_defects,
        flat_rms_rel,
        flat_corner_rms_rel,
    })
}
