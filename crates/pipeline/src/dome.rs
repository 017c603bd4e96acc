//! Processing a dome rig's frames (`docs/pipeline.md`, "LED dome"; a camera array's flashes
//! are its lights, processed the same way): the frames of one view
//! group (one camera, one rotation, all patterns) are collected into a pattern-major stack of
//! photosite values, demultiplexed with `btfrig_mux` (fast path, fault detection, least
//! squares around dead or stuck LEDs), and each single-LED mosaic then goes through demosaic,
//! rectification (nominal pose: the dome has no moving part between the captures of a view
//! but the turntable), and radiometry with that LED's calibrated power and colour.
//!
//! The stack holds photosites, not demosaiced RGB: demultiplexing is linear per photosite, so
//! it runs on a third of the data and demosaicing happens once per LED image. Memory: one
//! group is `patterns x width x height` f32 (Paley 199 at 160 x 120: 15.3 MB; at 1600 x 1200:
//! 1.5 GB, which is why the stack is per camera and freed after each group), and the
//! demultiplexer works on it in place in column tiles (`btfrig_mux::DemuxParams::tile`).
//! Single-light groups skip demultiplexing.
//!
//! A grouped code (`GroupCode::Grouped`: the LEDs in consecutive groups, each under its own
//! S-matrix) has one demultiplexer per group; its frames are contiguous per group, so each
//! group's chunk of the stack is demultiplexed on its own (through one chunk-sized buffer,
//! reused) and written back in place: row `j` of the stack becomes LED `j`'s mosaic.

use btfrig_calib::radiometry::{to_radiance_factor, vignetting_map, Radiometry};
use btfrig_calib::rectify::{rectify, Filter, LinearImage, Region};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::dome::DomeConfig;
use btfrig_core::frame::{BayerPattern, RawFrame};
use btfrig_mux::{Demultiplexer, DemultiplexerParams, DemuxParams, DemuxReport, SMatrix};

/// Errors of dome processing.
#[derive(Debug, thiserror::Error)]
pub enum DomeError {
    /// Demultiplexing failed (shape, ill-conditioned system).
    #[error("demultiplexing: {0}")]
    Mux(#[from] btfrig_mux::MuxError),
    /// Rectification or radiometry failed.
    #[error("rectify: {0}")]
    Rectify(#[from] btfrig_calib::rectify::RectifyError),
    /// The code does not fit the LEDs or the stack.
    #[error("code: {0}")]
    Code(String),
    /// A frame does not fit the group.
    #[error("frame {what}: {detail}")]
    Frame {
        /// Which.
        what: String,
        /// Why.
        detail: String,
    },
}

/// What the dome processor needs to know about the rig: geometry, lens, sensor, LED
/// calibration and colour, all from the rig config and the calibration files it names
/// (`docs/pipeline.md`, "LED dome"), never from the simulator.
#[derive(Debug, Clone)]
pub struct DomeProcessing {
    /// The dome geometry.
    pub dome: DomeConfig,
    /// The lens every arc camera has (the calibrated one when the rig names a calibration).
    pub camera: CameraModel,
    /// Colour filter array.
    pub bayer: Option<BayerPattern>,
    /// Photo-electrons per DN at gain 1.
    pub electrons_per_dn: f64,
    /// Dark current, e-/s (its mean is subtracted before demultiplexing).
    pub dark_e_per_s: f64,
    /// Calibrated power of each LED relative to `nominal_irradiance` (the LED calibration
    /// file's `power`; all 1 without one).
    pub led_power: Vec<f64>,
    /// Calibrated camera-RGB colour of each LED on a white reflector, green = 1 (the LED
    /// calibration file's `colour`: it white-balances; all 1 without one).
    pub led_colour: Vec<[f64; 3]>,
    /// Green camera-RGB rate of a white reflector lit along its normal by an LED of power 1 at
    /// the dome radius, e-/s (the LED calibration file's `reference_rate`; 1 without one:
    /// textures then are in relative units).
    pub nominal_irradiance: f64,
    /// White balance applied before each LED's colour (1 with an LED calibration, which
    /// white-balances per LED; a colour calibration's without one).
    pub white_balance: [f64; 3],
    /// White-balanced camera RGB to linear sRGB (a colour calibration file's model); `None`:
    /// textures stay in white-balanced camera RGB.
    pub colour: Option<crate::color::ColorCorrection>,
    /// Side of the sample square the textures tile, metres.
    pub sample_side_m: f64,
    /// Texture side, texels.
    pub size: usize,
    /// Resampling filter.
    pub filter: Filter,
}

/// The code of a view group.
pub enum GroupCode {
    /// One LED per frame: frame `j` is LED `j`.
    Single,
    /// S-matrix patterns, demultiplexed.
    Multiplexed(Box<Demultiplexer>),
    /// Consecutive groups of LEDs, each under its own S-matrix of the same order: group `g`
    /// is frames (and LEDs) `g*order .. (g+1)*order`.
    Grouped(Vec<Demultiplexer>),
}

impl GroupCode {
    /// The demultiplexer for `leds` LEDs under an S-matrix of `order`, with the calibrated
    /// LED powers as intensities (always-off slots 0). Every order takes its fast path (the
    /// dome's Paley orders the pixel-vectorised Rader FFT, faster than the dense product at
    /// n = 151 and 199: `docs/benchmarks.md`, "Demultiplexing").
    pub fn multiplexed(order: usize, led_power: &[f64]) -> Result<GroupCode, DomeError> {
        Ok(GroupCode::Multiplexed(Box::new(demultiplexer(order, led_power)?)))
    }

    /// One demultiplexer per group of `order` LEDs for `led_power.len()` LEDs in `groups`
    /// groups, each with its LEDs' calibrated powers (slots past the last LED 0, always off).
    pub fn grouped(order: usize, groups: usize, led_power: &[f64]) -> Result<GroupCode, DomeError> {
        let leds = led_power.len();
        if leds == 0 || groups != leds.div_ceil(order.max(1)) {
            return Err(DomeError::Code(format!(
                "groups {groups} x {order} does not fit {leds} LEDs: they need {} groups of {order}",
                leds.div_ceil(order.max(1))
            )));
        }
        let group = |g: usize| demultiplexer(order, &led_power[g * order..((g + 1) * order).min(leds)]);
        Ok(GroupCode::Grouped((0..groups).map(group).collect::<Result<_, _>>()?))
    }

    /// Frames per group.
    pub fn frames(&self, leds: usize) -> usize {
        match self {
            GroupCode::Single => leds,
            GroupCode::Multiplexed(d) => d.s().order(),
            GroupCode::Grouped(ds) => ds.iter().map(|d| d.s().order()).sum(),
        }
    }

    /// Demultiplexes a complete group's stack (in place; single-light groups pass through):
    /// the result's `mosaic(j)` is LED `j`'s.
    pub fn demultiplex(&self, stack: GroupStack) -> Result<GroupResult, DomeError> {
        let cols = stack.width * stack.height;
        match self {
            GroupCode::Single => Ok(GroupResult { mosaics: stack.data, cols, report: None }),
            GroupCode::Multiplexed(d) => {
                let (mosaics, report) = d.run(stack.data, cols)?.into_parts();
                Ok(GroupResult { mosaics, cols, report: Some(report) })
            }
            GroupCode::Grouped(ds) => {
                let mut mosaics = stack.data;
                let report = demultiplex_groups(ds, &mut mosaics, cols)?;
                Ok(GroupResult { mosaics, cols, report: Some(report) })
            }
        }
    }
}

/// The demultiplexer of an S-matrix of `order` over LEDs of calibrated `power` (slots past
/// them 0: always off). Every order takes its fast path (the dome's Paley orders the
/// pixel-vectorised Rader FFT).
fn demultiplexer(order: usize, power: &[f64]) -> Result<Demultiplexer, DomeError> {
    let s = SMatrix::of_order(order)?;
    let mut a = power.to_vec();
    a.resize(order, 0.0);
    let params = DemultiplexerParams { demux: DemuxParams::default(), ..DemultiplexerParams::default() };
    Ok(Demultiplexer::new(s, a, params)?)
}

/// Demultiplexes each group's contiguous chunk of `data` (`order` frames of `cols` each)
/// with its own demultiplexer and writes the images back over the frames, so row `j` is
/// source `j`. One chunk-sized buffer is reused (the demultiplexer takes its input by value):
/// the extra memory is one group, not a second stack.
fn demultiplex_groups(ds: &[Demultiplexer], data: &mut [f32], cols: usize) -> Result<DemuxReport, DomeError> {
    let needed: usize = ds.iter().map(|d| d.s().order() * cols).sum();
    if data.len() != needed {
        return Err(DomeError::Code(format!("the stack holds {} values, the groups need {needed}", data.len())));
    }
    let mut reports = Vec::with_capacity(ds.len());
    let mut buf = Vec::new();
    let mut start = 0;
    for d in ds {
        let len = d.s().order() * cols;
        let chunk = &mut data[start..start + len];
        buf.clear();
        buf.extend_from_slice(chunk);
        let (images, report) = d.run(buf, cols)?.into_parts();
        chunk.copy_from_slice(&images);
        reports.push((start / cols, report));
        buf = images;
        start += len;
    }
    Ok(merge_reports(reports))
}

/// One report for the whole code from the groups' reports, each with the index of its first
/// source: fault, excluded and noise-gain indices become LED indices.
fn merge_reports(reports: Vec<(usize, DemuxReport)>) -> DemuxReport {
    let method = reports.first().map(|(_, r)| r.method).expect("at least one group");
    let mut merged = DemuxReport {
        method,
        faults: Vec::new(),
        excluded: Vec::new(),
        re_solved: false,
        condition: None,
        noise_gain: Vec::new(),
    };
    for (offset, r) in reports {
        merged.faults.extend(r.faults.into_iter().map(|mut f| {
            f.source += offset;
            f
        }));
        merged.excluded.extend(r.excluded.into_iter().map(|j| j + offset));
        merged.re_solved |= r.re_solved;
        // The worst-conditioned group's system bounds the noise.
        merged.condition = match (merged.condition, r.condition) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        merged.noise_gain.extend(r.noise_gain);
    }
    merged
}

/// The frames of one view group being collected.
#[derive(Debug, Clone)]
pub struct GroupStack {
    /// Arc camera index.
    pub camera: usize,
    /// Rotation index.
    pub rotation: u32,
    /// Turntable angle, radians.
    pub turntable_rad: f64,
    /// Exposure of the frames, s.
    pub exposure_s: f64,
    /// Analogue gain.
    pub gain: f64,
    width: usize,
    height: usize,
    data: Vec<f32>,
    filled: Vec<bool>,
}

impl GroupStack {
    /// An empty stack of `frames` frames of `width x height`.
    pub fn new(camera: usize, rotation: u32, turntable_rad: f64, frames: usize, width: usize, height: usize) -> Self {
        GroupStack {
            camera,
            rotation,
            turntable_rad,
            exposure_s: 0.0,
            gain: 1.0,
            width,
            height,
            data: vec![0.0; frames * width * height],
            filled: vec![false; frames],
        }
    }

    /// Whether every frame has arrived.
    pub fn is_complete(&self) -> bool {
        self.filled.iter().all(|f| *f)
    }

    /// Bytes the stack holds.
    pub fn bytes(&self) -> usize {
        self.data.len() * 4
    }
}

/// Photosite values of `frame` in DN above black level and mean dark signal.
pub fn signal_dn(frame: &RawFrame, electrons_per_dn: f64, dark_e_per_s: f64) -> Vec<f32> {
    let dark = (dark_e_per_s * frame.meta.exposure_s * frame.meta.gain / electrons_per_dn) as f32;
    let black = f32::from(frame.meta.black_level);
    frame.data.iter().map(|&v| f32::from(v) - black - dark).collect()
}

/// One demultiplexed view group.
pub struct GroupResult {
    /// Per LED, its single-light mosaic (DN above black and dark, at the group's exposure).
    pub mosaics: Vec<f32>,
    /// Photosites per mosaic.
    pub cols: usize,
    /// The demultiplexer's report (`None` for a single-light group).
    pub report: Option<DemuxReport>,
}

impl GroupResult {
    /// LED `j`'s mosaic.
    pub fn mosaic(&self, j: usize) -> &[f32] {
        &self.mosaics[j * self.cols..(j + 1) * self.cols]
    }
}

impl DomeProcessing {
    /// Adds pattern `index`'s frame to `stack`.
    pub fn add(&self, stack: &mut GroupStack, index: usize, frame: &RawFrame) -> Result<(), DomeError> {
        let cols = stack.width * stack.height;
        if frame.width * frame.height != cols || index >= stack.filled.len() {
            return Err(DomeError::Frame {
                what: format!("{index} of camera {} rotation {}", stack.camera, stack.rotation),
                detail: format!(
                    "{}x{} pattern {index}, the group expects {}x{} and {} patterns",
                    frame.width,
                    frame.height,
                    stack.width,
                    stack.height,
                    stack.filled.len()
                ),
            });
        }
        stack.exposure_s = frame.meta.exposure_s;
        stack.gain = frame.meta.gain;
        let v = signal_dn(frame, self.electrons_per_dn, self.dark_e_per_s);
        stack.data[index * cols..(index + 1) * cols].copy_from_slice(&v);
        stack.filled[index] = true;
        Ok(())
    }

    /// Demultiplexes a complete group (in place; single-light groups pass through). Every
    /// result mosaic is its LED's image at the LED's own (calibrated) power, as a single-light
    /// frame is: the demultiplexer returns images per unit of the calibrated intensities it
    /// was given (`led_power` times the pattern scale), so they are multiplied back by
    /// `led_power` here and [`DomeProcessing::texture`] divides it out once for every mode.
    pub fn demultiplex(&self, stack: GroupStack, code: &GroupCode) -> Result<GroupResult, DomeError> {
        let mut result = code.demultiplex(stack)?;
        if result.report.is_some() {
            let cols = result.cols;
            for (j, &p) in self.led_power.iter().enumerate() {
                let k = p as f32;
                result.mosaics[j * cols..(j + 1) * cols].iter_mut().for_each(|v| *v *= k);
            }
        }
        Ok(result)
    }

    /// The radiance-factor texture of LED `led` from its single-light `mosaic`, seen by
    /// camera `camera` at `turntable_rad` with `exposure_s` and `gain`.
    pub fn texture(
        &self,
        mosaic: &[f32],
        camera: usize,
        turntable_rad: f64,
        led: usize,
        exposure_s: f64,
        gain: f64,
    ) -> Result<Vec<[f32; 3]>, DomeError> {
        let (w, h) = (self.camera.width, self.camera.height);
        let rgb = btfrig_imageio::demosaic::demosaic_bilinear_values(w, h, self.bayer, mosaic);
        let img = LinearImage { width: w, height: h, data: rgb.data };
        let pose = self.dome.scene_pose(camera, turntable_rad, led);
        let region = Region::centred_square(self.sample_side_m);
        let tex = rectify(&img, &self.camera, &pose, region, self.size, self.filter)?;
        let vig = vignetting_map(&self.camera, &pose, region, self.size)?;
        let c = self.led_colour[led];
        let r = Radiometry {
            dn_range: 1.0,
            // What the frame collected of the light: the exposure for an LED, the fraction of
            // the pulse for a flash (whose nominal irradiance is per flash).
            exposure_s: self.dome.light_units(exposure_s),
            dn_per_electron: gain / self.electrons_per_dn,
            dark_e_per_s: 0.0,
            nominal_irradiance: self.nominal_irradiance * self.led_power[led],
            white_balance: [self.white_balance[0] / c[0], self.white_balance[1] / c[1], self.white_balance[2] / c[2]],
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        };
        let mut out = to_radiance_factor(&tex, &vig, &r)?.data;
        if let Some(colour) = &self.colour {
            colour.apply(&mut out);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A known mosaic per LED: smooth, different for every LED, all positive.
    fn truth(leds: usize, cols: usize) -> Vec<f32> {
        (0..leds * cols)
            .map(|i| 20.0 + ((i / cols) % 13) as f32 * 3.0 + ((i % cols) as f32 * 0.37).sin() * 5.0)
            .collect()
    }

    /// The noise-free frames of the block-diagonal grouped code (frame `g*order + r` lights
    /// LED `g*order + j` at `power[..]` where row `r` has a 1 in column `j`), pattern-major.
    fn grouped_frames(order: usize, groups: usize, power: &[f64], truth: &[f32], cols: usize) -> Vec<f32> {
        let s = SMatrix::of_order(order).unwrap();
        let mut frames = vec![0.0f32; order * groups * cols];
        for g in 0..groups {
            for r in 0..order {
                let f = g * order + r;
                for j in (0..order).filter(|&j| s.get(r, j) == 1 && g * order + j < power.len()) {
                    let led = g * order + j;
                    for c in 0..cols {
                        frames[f * cols + c] += power[led] as f32 * truth[led * cols + c];
                    }
                }
            }
        }
        frames
    }

    #[test]
    fn grouped_demultiplexing_recovers_every_leds_mosaic_from_noise_free_frames() {
        // 40 LEDs in 6 groups of 7 (the last has 5 LEDs and 2 always-off slots), calibrated
        // powers 0.8..1.2, 6 x 5 photosites.
        let (leds, order, groups, (w, h)) = (40, 7, 6, (6usize, 5usize));
        let cols = w * h;
        let power: Vec<f64> = (0..leds).map(|j| 0.8 + 0.4 * (j as f64 * 0.61).fract()).collect();
        let truth = truth(leds, cols);
        let code = GroupCode::grouped(order, groups, &power).unwrap();
        assert_eq!(code.frames(leds), 42);
        let mut stack = GroupStack::new(0, 0, 0.0, 42, w, h);
        stack.data = grouped_frames(order, groups, &power, &truth, cols);
        stack.filled.fill(true);
        let out = code.demultiplex(stack).unwrap();
        for j in 0..leds {
            for (c, (a, b)) in out.mosaic(j).iter().zip(&truth[j * cols..(j + 1) * cols]).enumerate() {
                assert!((a - b).abs() < 1e-4 * b, "LED {j} photosite {c}: {a} vs {b}");
            }
        }
        let report = out.report.unwrap();
        assert!(report.faults.is_empty(), "{:?}", report.faults);
        // The always-off slots of the last group, as LED indices of the whole code.
        assert_eq!(report.excluded, vec![40, 41]);
        assert_eq!(report.noise_gain.len(), 42);
        assert!(!report.re_solved);
    }

    #[test]
    fn a_grouped_code_must_cover_the_leds_with_no_empty_group() {
        let e = GroupCode::grouped(7, 5, &[1.0; 40]).err().unwrap().to_string();
        assert_eq!(e, "code: groups 5 x 7 does not fit 40 LEDs: they need 6 groups of 7");
        assert!(GroupCode::grouped(7, 7, &[1.0; 40]).is_err());
    }

    #[test]
    fn group_faults_are_reported_with_the_led_index_of_the_whole_code() {
        // LED 17 (group 2, slot 3 of an order-15 code) is dead: its frames lack its light.
        let (leds, order, groups, (w, h)) = (45, 15, 3, (64usize, 64usize));
        let cols = w * h;
        let power = vec![1.0; leds];
        let truth = truth(leds, cols);
        let mut dead = power.clone();
        dead[17] = 0.0;
        let mut stack = GroupStack::new(0, 0, 0.0, 45, w, h);
        stack.data = grouped_frames(order, groups, &dead, &truth, cols);
        // A little noise, so the detector's z-scores are finite.
        for (i, v) in stack.data.iter_mut().enumerate() {
            *v += ((i as f32 * 12.9898).sin() * 43758.547).rem_euclid(1.0) - 0.5;
        }
        stack.filled.fill(true);
        let out = GroupCode::grouped(order, groups, &power).unwrap().demultiplex(stack).unwrap();
        let report = out.report.unwrap();
        let faults: Vec<(usize, &str)> = report.faults.iter().map(|f| (f.source, f.kind.name())).collect();
        assert_eq!(faults, vec![(17, "dead")]);
        assert!(report.re_solved && report.excluded.contains(&17));
    }
}
