//! Exposure control: metering a frame on the sample's footprint and deciding, capture by
//! capture, how many exposures a bracket needs.
//!
//! * [`sample_footprint`]: the photosites that see the sample region, from the nominal pose
//!   and the camera model (its boundary projected through the lens, then filled).
//! * [`meter`] / [`meter_merged`]: on those photosites, the fraction saturated (at or above
//!   `saturation_fraction` of full scale), the fraction underexposed (below
//!   `dark_fraction` of full scale), and the distribution of signal rates (e-/s).
//! * [`HdrPolicy`]: the base exposure from a metering (the rate quantile that may saturate
//!   put at a target level), and the next exposure of a bracket from the meterings of the
//!   exposures taken so far: shorter by `stop_ratio` while too much of the footprint is
//!   saturated even in the shortest one, longer while too much is underexposed even in the
//!   longest (and the previous longer exposure halved that fraction at least), at most
//!   `max_exposures` in all. A scene one exposure holds gets one.
//!
//! Numerics only; the policy, its defaults and the measured figures are in `docs/hdr.md`.

use btfrig_core::camera::CameraModel;
use btfrig_core::frame::RawFrame;
use btfrig_core::pose::ScenePose;
use nalgebra::Point3;
use rayon::prelude::*;

use crate::hdr::{HdrError, MergedFrame, NoiseModel, PhotositeCalibration};
use crate::rectify::{sample_to_camera, Region};

/// A set of photosites of a `width x height` frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Footprint {
    /// Frame width.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// Row-major membership.
    pub mask: Vec<bool>,
}

impl Footprint {
    /// Every photosite of the frame.
    pub fn whole(width: usize, height: usize) -> Footprint {
        Footprint { width, height, mask: vec![true; width * height] }
    }
    /// Number of photosites in the set.
    pub fn count(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }
}

/// The photosites whose centres see `region` of the sample plane for `pose` (nominal), with
/// the lens's distortion: the region's boundary (64 points per edge) is projected and the
/// polygon filled by the even-odd rule. Parts behind the camera are left out.
pub fn sample_footprint(camera: &CameraModel, pose: &ScenePose, region: Region) -> Footprint {
    const PER_EDGE: usize = 64;
    let to_cam = sample_to_camera(pose);
    let corners = [
        (region.x_min, region.y_min),
        (region.x_max, region.y_min),
        (region.x_max, region.y_max),
        (region.x_min, region.y_max),
    ];
    let mut poly: Vec<(f64, f64)> = Vec::with_capacity(4 * PER_EDGE);
    for e in 0..4 {
        let (a, b) = (corners[e], corners[(e + 1) % 4]);
        for i in 0..PER_EDGE {
            let s = i as f64 / PER_EDGE as f64;
            let p = to_cam * Point3::new(a.0 + s * (b.0 - a.0), a.1 + s * (b.1 - a.1), 0.0);
            if let Some(q) = camera.project(&p) {
                poly.push((q.x, q.y));
            }
        }
    }
    let (w, h) = (camera.width, camera.height);
    let mut mask = vec![false; w * h];
    if poly.len() < 3 {
        return Footprint { width: w, height: h, mask };
    }
    let y_lo = poly.iter().map(|p| p.1).fold(f64::INFINITY, f64::min).floor().max(0.0) as usize;
    let y_hi = (poly.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max).ceil().max(0.0) as usize).min(h);
    mask.par_chunks_mut(w.max(1)).enumerate().filter(|(y, _)| (y_lo..y_hi).contains(y)).for_each(|(y, row)| {
        // Crossings of the scanline through the pixel centres with the polygon's edges.
        let yc = y as f64;
        let mut xs: Vec<f64> = Vec::new();
        for i in 0..poly.len() {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            if (a.1 <= yc) != (b.1 <= yc) {
                xs.push(a.0 + (yc - a.1) / (b.1 - a.1) * (b.0 - a.0));
            }
        }
        xs.sort_by(f64::total_cmp);
        for pair in xs.chunks_exact(2) {
            let x0 = pair[0].ceil().max(0.0) as usize;
            let x1 = (pair[1].floor() + 1.0).max(0.0) as usize;
            for m in row.iter_mut().take(x1.min(w)).skip(x0) {
                *m = true;
            }
        }
    });
    Footprint { width: w, height: h, mask }
}

/// Levels of the metering, fractions of a frame's full scale `white - black`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeterLevels {
    /// At or above this a photosite counts as saturated (default 0.95, the merge's limit).
    pub saturation_fraction: f64,
    /// Below this a photosite counts as underexposed (default 0.01: about 400 e- on the
    /// default sensor, a shot-noise SNR of 20).
    pub dark_fraction: f64,
}

impl Default for MeterLevels {
    fn default() -> Self {
        MeterLevels { saturation_fraction: 0.95, dark_fraction: 0.01 }
    }
}

/// Statistics of one frame (or merged bracket) on a footprint.
#[derive(Debug, Clone, PartialEq)]
pub struct Metering {
    /// Photosites measured.
    pub photosites: usize,
    /// Of those, saturated.
    pub saturated: usize,
    /// Of those, underexposed.
    pub dark: usize,
    /// Signal rates (e-/s, flat removed) of the measured photosites, ascending; a saturated
    /// photosite holds its clipped value (a lower bound).
    pub rates: Vec<f64>,
    /// The saturation threshold as a rate (e-/s) for this frame's exposure: rates at or
    /// above it are lower bounds.
    pub saturation_rate: f64,
    /// Full scale in electrons (`(white - black) / k`).
    pub full_scale_e: f64,
}

impl Metering {
    /// Fraction of the footprint saturated (0 for an empty footprint).
    pub fn saturated_fraction(&self) -> f64 {
        self.saturated as f64 / self.photosites.max(1) as f64
    }
    /// Fraction of the footprint underexposed.
    pub fn dark_fraction(&self) -> f64 {
        self.dark as f64 / self.photosites.max(1) as f64
    }
    /// The `q`-quantile of the rates (`q` in `[0, 1]`, nearest rank), and whether it is a
    /// lower bound (saturated). `None` for an empty footprint.
    pub fn rate_quantile(&self, q: f64) -> Option<(f64, bool)> {
        let n = self.rates.len();
        if n == 0 {
            return None;
        }
        let i = ((q.clamp(0.0, 1.0) * n as f64).ceil() as usize).clamp(1, n) - 1;
        let r = self.rates[i];
        Some((r, r >= self.saturation_rate))
    }
}

/// Meters a raw frame on `footprint`: counts and rates per photosite, with the dark level and
/// flat of `calibration`.
pub fn meter(
    frame: &RawFrame,
    footprint: &Footprint,
    calibration: &impl PhotositeCalibration,
    noise: &NoiseModel,
    levels: &MeterLevels,
) -> Result<Metering, HdrError> {
    check_sizes(frame.width, frame.height, footprint)?;
    let m = &frame.meta;
    if !(m.exposure_s > 0.0 && m.gain > 0.0 && m.white_level > m.black_level) {
        return Err(HdrError::OutOfRange {
            what: "frame exposure_s, gain or white_level".into(),
            value: m.exposure_s,
            allowed: "exposure and gain > 0, white level above black",
        });
    }
    let full = f64::from(m.white_level) - f64::from(m.black_level);
    let k = m.gain / noise.electrons_per_dn;
    let (sat_dn, dark_dn) = (levels.saturation_fraction * full, levels.dark_fraction * full);
    let w = frame.width;
    let per_row: Vec<(usize, usize, Vec<f64>)> = (0..frame.height)
        .into_par_iter()
        .map(|y| {
            let (mut sat, mut dark, mut rates) = (0, 0, Vec::new());
            for x in 0..w {
                if !footprint.mask[y * w + x] {
                    continue;
                }
                let dn = f64::from(frame.data[y * w + x]);
                let above = dn - f64::from(m.black_level);
                if above >= sat_dn || frame.data[y * w + x] >= m.white_level {
                    sat += 1;
                } else if above < dark_dn {
                    dark += 1;
                }
                let flat = calibration.flat(x, y);
                rates.push((dn - calibration.dark_dn(x, y, m)) / (k * m.exposure_s * flat));
            }
            (sat, dark, rates)
        })
        .collect();
    let mut out = Metering {
        photosites: 0,
        saturated: 0,
        dark: 0,
        rates: Vec::new(),
        saturation_rate: sat_dn / (k * m.exposure_s),
        full_scale_e: full / k,
    };
    for (s, d, r) in per_row {
        out.saturated += s;
        out.dark += d;
        out.rates.extend(r);
    }
    out.photosites = out.rates.len();
    out.rates.sort_by(f64::total_cmp);
    Ok(out)
}

/// Meters a merged bracket on `footprint`: saturated = saturated in every exposure; dark =
/// a rate whose signal in the longest exposure `longest_s` is below `dark_fraction` of
/// `full_scale_e`.
pub fn meter_merged(
    merged: &MergedFrame,
    footprint: &Footprint,
    longest_s: f64,
    full_scale_e: f64,
    levels: &MeterLevels,
) -> Result<Metering, HdrError> {
    check_sizes(merged.width, merged.height, footprint)?;
    let dark_rate = levels.dark_fraction * full_scale_e / longest_s;
    let mut out = Metering {
        photosites: 0,
        saturated: 0,
        dark: 0,
        rates: Vec::new(),
        saturation_rate: f64::INFINITY,
        full_scale_e,
    };
    let mut min_saturated = f64::INFINITY;
    for (i, _) in footprint.mask.iter().enumerate().filter(|(_, &m)| m) {
        let r = f64::from(merged.rate[i]);
        if merged.used[i] == 0 {
            out.saturated += 1;
            min_saturated = min_saturated.min(r);
        } else if r < dark_rate {
            out.dark += 1;
        }
        out.rates.push(r);
    }
    out.saturation_rate = min_saturated;
    out.photosites = out.rates.len();
    out.rates.sort_by(f64::total_cmp);
    Ok(out)
}

fn check_sizes(width: usize, height: usize, footprint: &Footprint) -> Result<(), HdrError> {
    if (footprint.width, footprint.height) != (width, height) || footprint.mask.len() != width * height {
        return Err(HdrError::SizeMismatch {
            index: 0,
            width: footprint.width,
            height: footprint.height,
            expect_width: width,
            expect_height: height,
        });
    }
    Ok(())
}

/// How a capture's exposures are chosen.
#[derive(Debug, Clone, PartialEq)]
pub enum BracketMode {
    /// One exposure, always.
    Off,
    /// One exposure, more while the range needs them (see the module documentation).
    Adaptive,
    /// Always the base exposure times each of these multipliers.
    Always(Vec<f64>),
}

/// The exposure policy of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct HdrPolicy {
    /// Bracketing mode.
    pub mode: BracketMode,
    /// Most exposures per capture (adaptive mode), `1..=8`.
    pub max_exposures: usize,
    /// Ratio between neighbouring exposures of an adaptive bracket, `(0, 1)` (e.g. 1/8).
    pub stop_ratio: f64,
    /// Largest tolerated saturated fraction of the footprint.
    pub saturated_max_fraction: f64,
    /// Largest tolerated underexposed fraction of the footprint.
    pub dark_max_fraction: f64,
    /// Quantile of the footprint's rates the base exposure meters on (e.g. 0.99: the bulk of
    /// the sample, not its highlights, sets the base).
    pub meter_quantile: f64,
    /// Level the base exposure puts that quantile at (fraction of full scale).
    pub target_fraction: f64,
    /// Shortest and longest exposure the camera allows, seconds.
    pub exposure_range_s: (f64, f64),
    /// Metering levels.
    pub levels: MeterLevels,
}

impl HdrPolicy {
    /// Base exposure from a metering taken at `metered_exposure_s`: the rate at the
    /// `meter_quantile` of the footprint lands at `target_fraction` of full scale. If that
    /// quantile was saturated (its rate is only a lower bound), the exposure is cut by
    /// `stop_ratio` instead, and the next metering refines it.
    pub fn base_exposure(&self, metering: &Metering, metered_exposure_s: f64) -> f64 {
        let (lo, hi) = self.exposure_range_s;
        let t = match metering.rate_quantile(self.meter_quantile) {
            None => metered_exposure_s,
            Some((_, true)) => metered_exposure_s * self.stop_ratio,
            Some((r, false)) if r > 0.0 => self.target_fraction * metering.full_scale_e / r,
            // Nothing above the dark level: as long as the camera allows.
            Some(_) => hi,
        };
        t.clamp(lo, hi)
    }

    /// The next exposure of the bracket after the exposures taken so far (`(exposure_s,
    /// metering)` each, base first), or `None` when the bracket is complete.
    pub fn next_exposure(&self, taken: &[(f64, Metering)]) -> Option<f64> {
        let (base, _) = taken.first()?;
        let (lo, hi) = self.exposure_range_s;
        match &self.mode {
            BracketMode::Off => None,
            BracketMode::Always(stops) => stops.get(taken.len()).map(|s| (base * s).clamp(lo, hi)),
            BracketMode::Adaptive => {
                if taken.len() >= self.max_exposures {
                    return None;
                }
                let shortest = taken.iter().min_by(|a, b| a.0.total_cmp(&b.0))?;
                let longest = taken.iter().max_by(|a, b| a.0.total_cmp(&b.0))?;
                if shortest.1.saturated_fraction() > self.saturated_max_fraction && shortest.0 > lo {
                    return Some((shortest.0 * self.stop_ratio).max(lo));
                }
                // A longer exposure only while the last one helped: photosites that stay dark
                // (shadowed grout, a black marker) would otherwise fill the bracket.
                let mut by_time: Vec<&(f64, Metering)> = taken.iter().collect();
                by_time.sort_by(|a, b| a.0.total_cmp(&b.0));
                let helped = match by_time.as_slice() {
                    [.., prev, last] if std::ptr::eq(*last, &taken[taken.len() - 1]) && last.0 > base * 1.0001 => {
                        last.1.dark_fraction() < 0.5 * prev.1.dark_fraction()
                    }
                    _ => true,
                };
                if helped && longest.1.dark_fraction() > self.dark_max_fraction && longest.0 < hi {
                    return Some((longest.0 / self.stop_ratio).min(hi));
                }
                None
            }
        }
    }
}

/// Time of a capture of `exposures` (seconds each) when every exposure costs its time plus
/// `per_exposure_overhead_s` (read-out and the decision on it).
pub fn bracket_time_s(exposures: &[f64], per_exposure_overhead_s: f64) -> f64 {
    exposures.iter().map(|t| t + per_exposure_overhead_s).sum()
}

/// What one exposure costs beyond its own time on a camera of this timing model: the exposure
/// command, the trigger latency, the read-out and the transfer of `frame_bytes`.
pub fn per_exposure_overhead_s(camera: &btfrig_core::config::timing::CameraTiming, frame_bytes: u64) -> f64 {
    camera.command_s + camera.trigger_latency_s + camera.read_out_s + frame_bytes as f64 / camera.transfer_bytes_per_s
}

/// The run report's HDR figures: captures counted by number of exposures, and the time the
/// policy saved against always taking the full bracket.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HdrTally {
    /// Captures by number of exposures (`exposures_per_capture`).
    pub exposures_per_capture: std::collections::BTreeMap<usize, usize>,
    /// Sum over captures of the always-bracket's time minus the time taken, seconds
    /// (`hdr_time_saved_s`).
    pub time_saved_s: f64,
}

impl HdrTally {
    /// Records a capture that took `taken` where always bracketing would have taken `always`
    /// (exposure times, seconds), each exposure costing `overhead_s` more.
    pub fn record(&mut self, taken: &[f64], always: &[f64], overhead_s: f64) {
        *self.exposures_per_capture.entry(taken.len()).or_default() += 1;
        self.time_saved_s += bracket_time_s(always, overhead_s) - bracket_time_s(taken, overhead_s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hdr::NominalCalibration;
    use btfrig_core::camera::{Distortion, Vignetting};
    use btfrig_core::frame::FrameMeta;
    use btfrig_core::Direction;

    const NOISE: NoiseModel = NoiseModel { electrons_per_dn: 2.5, read_noise_e: 3.0 };
    const NOMINAL: NominalCalibration = NominalCalibration { dark_current_e_per_s: 0.0, electrons_per_dn: 2.5 };

    #[test]
    fn frontal_footprint_is_the_projected_square() {
        // Pinhole, f = 1000 px, 0.5 m away: a 0.05 m square spans 100 px, centred.
        let cam =
            CameraModel::new(400, 300, 1000.0, 1000.0, 199.5, 149.5, Distortion::default(), Vignetting::default())
                .unwrap();
        let pose =
            ScenePose::looking_at(Direction::from_degrees(30.0, 0.0), Direction::from_degrees(0.0, 0.0), 0.5, 1.0);
        let fp = sample_footprint(&cam, &pose, Region::centred_square(0.05));
        assert!((fp.count() as f64 - 100.0 * 100.0).abs() < 2.0 * 2.0 * 100.0, "{}", fp.count());
        assert!(fp.mask[150 * 400 + 200] && !fp.mask[150 * 400 + 260] && !fp.mask[90 * 400 + 200]);
        // Oblique at 60 degrees: foreshortened to half along one axis.
        let pose =
            ScenePose::looking_at(Direction::from_degrees(30.0, 0.0), Direction::from_degrees(60.0, 0.0), 0.5, 1.0);
        let n = sample_footprint(&cam, &pose, Region::centred_square(0.05)).count() as f64;
        assert!((n / 5000.0 - 1.0).abs() < 0.05, "{n}");
    }

    fn frame(dn: Vec<u16>, exposure_s: f64) -> RawFrame {
        RawFrame {
            width: dn.len(),
            height: 1,
            data: dn,
            meta: FrameMeta {
                sequence: 0,
                exposure_s,
                gain: 1.0,
                f_number: None,
                black_level: 256,
                white_level: 16251,
                bit_depth: 14,
                bayer: None,
                timestamp_s: 0.0,
                temperature_c: None,
            },
        }
    }

    #[test]
    fn metering_counts_saturated_and_dark_photosites_on_the_footprint_only() {
        // Full scale 15995 DN: saturated from 15195.25 DN above black, dark below 159.95.
        let f = frame(vec![16251, 15500, 8256, 300, 16251, 256], 0.01);
        let mut fp = Footprint::whole(6, 1);
        fp.mask[4] = false;
        fp.mask[5] = false;
        let m = meter(&f, &fp, &NOMINAL, &NOISE, &MeterLevels::default()).unwrap();
        assert_eq!((m.photosites, m.saturated, m.dark), (4, 2, 1));
        // Rates: 44 DN -> 11 000 e-/s; 8000 DN -> 2e6 e-/s.
        assert!((m.rates[0] - 11_000.0).abs() < 1e-6 && (m.rates[1] - 2e6).abs() < 1e-3);
        assert_eq!(m.rate_quantile(0.5), Some((2e6, false)));
        assert!(m.rate_quantile(1.0).unwrap().1, "the top is saturated, a lower bound");
        let bad = Footprint::whole(5, 1);
        assert!(meter(&f, &bad, &NOMINAL, &NOISE, &MeterLevels::default()).is_err());
    }

    fn metering(saturated: f64, dark: f64, rates: Vec<f64>, saturation_rate: f64) -> Metering {
        Metering {
            photosites: 10_000,
            saturated: (saturated * 10_000.0) as usize,
            dark: (dark * 10_000.0) as usize,
            rates,
            saturation_rate,
            full_scale_e: 40_000.0,
        }
    }

    fn policy(mode: BracketMode) -> HdrPolicy {
        HdrPolicy {
            mode,
            max_exposures: 3,
            stop_ratio: 0.125,
            saturated_max_fraction: 1e-3,
            dark_max_fraction: 0.02,
            meter_quantile: 0.99,
            target_fraction: 0.6,
            exposure_range_s: (1e-4, 30.0),
            levels: MeterLevels::default(),
        }
    }

    #[test]
    fn base_exposure_puts_the_metered_quantile_at_the_target() {
        let p = policy(BracketMode::Adaptive);
        let rates: Vec<f64> = (1..=100).map(|i| f64::from(i) * 1e4).collect();
        // The 99 % quantile is 9.9e5 e-/s: 0.6 * 40 000 / 9.9e5 s.
        let t = p.base_exposure(&metering(0.0, 0.0, rates.clone(), 1e9), 0.01);
        assert!((t - 24_000.0 / 9.9e5).abs() < 1e-12, "{t}");
        // A saturated quantile says only "shorter": cut by the stop ratio.
        assert_eq!(p.base_exposure(&metering(0.5, 0.0, rates.clone(), 5e5), 0.01), 0.01 * 0.125);
        // Clamped to the camera's range.
        let dim: Vec<f64> = vec![1e-3; 100];
        assert_eq!(p.base_exposure(&metering(0.0, 1.0, dim, 1e9), 0.01), 30.0);
    }

    #[test]
    fn adaptive_brackets_only_while_the_range_needs_it() {
        let p = policy(BracketMode::Adaptive);
        let ok = || metering(0.0, 0.0, vec![1.0], 1e9);
        // One exposure holds the scene: done after one.
        assert_eq!(p.next_exposure(&[(0.01, ok())]), None);
        // Too many saturated: shorter by the ratio; then the short one holds the highlights.
        let sat = || metering(0.01, 0.0, vec![1.0], 1e9);
        assert_eq!(p.next_exposure(&[(0.01, sat())]), Some(0.00125));
        assert_eq!(p.next_exposure(&[(0.01, sat()), (0.00125, metering(0.0, 0.3, vec![1.0], 1e9))]), None);
        // Still saturated in the shortest: shorter again, but never beyond max_exposures.
        let taken = [(0.01, sat()), (0.00125, sat())];
        assert_eq!(p.next_exposure(&taken), Some(0.00125 * 0.125));
        let taken = [(0.01, sat()), (0.00125, sat()), (0.00125 * 0.125, sat())];
        assert_eq!(p.next_exposure(&taken), None);
        // Too dark: longer; stop when the longer one did not halve the dark fraction.
        let dark = |f| metering(0.0, f, vec![1.0], 1e9);
        assert_eq!(p.next_exposure(&[(0.01, dark(0.1))]), Some(0.08));
        assert_eq!(p.next_exposure(&[(0.01, dark(0.1)), (0.08, dark(0.03))]), Some(0.64));
        assert_eq!(p.next_exposure(&[(0.01, dark(0.1)), (0.08, dark(0.08))]), None);
        // Off never brackets; Always follows the stops.
        assert_eq!(policy(BracketMode::Off).next_exposure(&[(0.01, sat())]), None);
        let always = policy(BracketMode::Always(vec![1.0, 0.25, 4.0]));
        assert_eq!(always.next_exposure(&[(0.01, ok())]), Some(0.0025));
        assert_eq!(always.next_exposure(&[(0.01, ok()), (0.0025, ok())]), Some(0.04));
        assert_eq!(always.next_exposure(&[(0.01, ok()), (0.0025, ok()), (0.04, ok())]), None);
        assert!((bracket_time_s(&[0.01, 0.00125], 0.5) - 1.01125).abs() < 1e-12);
    }

    #[test]
    fn tally_counts_captures_and_the_time_saved_on_the_bonn_camera() {
        let cfg = btfrig_core::config::RigConfig::from_toml(btfrig_core::plan::BUILTIN_RIGS[0].1, "rig").unwrap();
        let overhead = per_exposure_overhead_s(&cfg.timing.camera, cfg.timing.camera.frame_bytes.unwrap());
        // 0.05 command + 0.1 latency + 0.6 read-out + 12 MB at 2.4 MB/s.
        assert!((overhead - 5.75).abs() < 1e-12, "{overhead}");
        let always = [0.01, 0.00125, 0.00015625];
        let mut tally = HdrTally::default();
        tally.record(&[0.01], &always, overhead);
        tally.record(&[0.01], &always, overhead);
        tally.record(&[0.01, 0.00125], &always, overhead);
        assert_eq!(tally.exposures_per_capture.into_iter().collect::<Vec<_>>(), vec![(1, 2), (2, 1)]);
        let expect = 2.0 * (2.0 * 5.75 + 0.00125 + 0.00015625) + (5.75 + 0.00015625);
        assert!((tally.time_saved_s - expect).abs() < 1e-9, "{}", tally.time_saved_s);
    }
}
