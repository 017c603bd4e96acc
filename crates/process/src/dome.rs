//! Processing a dome rig's frames (`docs/pipeline.md`, "LED dome"; a camera array's flashes
//! are its lights, processed the same way): the frames of one view
//! group (one camera, one rotation, all patterns) are collected into a pattern-major stack of
//! photosite values (dark-subtracted and flat-fielded per photosite with the model's dark/flat
//! calibration: linear per photosite, so it commutes with demultiplexing; each pattern frame
//! has its own dark), demultiplexed with `btfrig_mux` (fast path, fault detection, least
//! squares around dead or stuck LEDs), and each single-LED mosaic then goes through demosaic,
//! rectification and radiometry with that LED's calibrated power and colour.
//!
//! Registration: every LED image of a view group shares one pose (one camera, one turntable
//! stop), so the group is registered once ([`DomeProcessing::register`]) from the SUM of its
//! pattern frames: it is the plate under every light at once (no shadowed or dark marker
//! whatever the LED), with the summed exposure of all patterns (the highest SNR the group
//! has), and it is there before demultiplexing, so registration does not wait for it. Its
//! markers give the sample's pose (`btfrig_registration::PlateRegistrar`, the camera fixed, as on
//! the gonio); each LED's pose is that pose with the LED's position. When the markers do not
//! give a pose the group falls back to the nominal pose, which the [`GroupPose`] says.
//!
//! The stack holds photosites, not demosaiced RGB: demultiplexing is linear per photosite, so
//! it runs on a third of the data and demosaicing happens once per LED image. Memory: one
//! group is `patterns x width x height` f32 (Paley 199 at 320 x 240: 61.1 MB; at 1600 x 1200:
//! 1.5 GB, which is why the stack is per camera and freed after each group), and the
//! demultiplexer works on it in place in column tiles (`btfrig_mux::DemuxParams::tile`).
//! Single-light groups skip demultiplexing.
//!
//! A grouped code (`GroupCode::Grouped`: the LEDs in consecutive groups, each under its own
//! S-matrix) has one demultiplexer per group; its frames are contiguous per group, so each
//! group's chunk of the stack is demultiplexed on its own (through one chunk-sized buffer,
//! reused) and written back in place: row `j` of the stack becomes LED `j`'s mosaic.

use btfrig_core::config::dome::DomeConfig;
use btfrig_core::frame::{BayerPattern, RawFrame};
use btfrig_core::pose::ScenePose;
use btfrig_imaging::radiometry::{to_radiance_factor, vignetting_map, Radiometry};
use btfrig_imaging::rectify::{rectify, Filter, LinearImage, Region};
use btfrig_markers::GrayImage;
use btfrig_mux::{Demultiplexer, DemultiplexerParams, DemuxParams, DemuxReport, SMatrix};
use btfrig_registration::{PlateRegistrar, RegisterOptions};

use crate::{PoseSource, ProcessingModel};

/// Errors of dome processing.
#[derive(Debug, thiserror::Error)]
pub enum DomeError {
    /// Demultiplexing failed (shape, ill-conditioned system).
    #[error("demultiplexing: {0}")]
    Mux(#[from] btfrig_mux::MuxError),
    /// Rectification or radiometry failed.
    #[error("rectify: {0}")]
    Rectify(#[from] btfrig_imaging::rectify::RectifyError),
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
    /// The dark/flat calibration does not fit a frame (size, f-number).
    #[error("dark/flat: {0}")]
    DarkFlat(#[from] btfrig_imaging::dark_flat::DarkFlatError),
    /// The marker registrar cannot be built from the model (camera, plate layout).
    #[error("registration setup: {0}")]
    Registrar(#[from] btfrig_registration::FrameError),
}

/// A dome's light calibration: the per-LED (per-flash) power and colour from the rig's
/// `[dome] led_calibration` file.
#[derive(Debug, Clone, PartialEq)]
pub struct LedLight {
    /// Calibrated power of each LED relative to `nominal_irradiance` (all 1 without a file).
    pub power: Vec<f64>,
    /// Calibrated camera-RGB colour of each LED on a white reflector, green = 1 (it
    /// white-balances; all 1 without a file).
    pub colour: Vec<[f64; 3]>,
    /// Green camera-RGB rate of a white reflector lit along its normal by an LED of power 1 at
    /// the dome radius, e-/s (the file's `reference_rate`; 1 without one: relative units).
    pub nominal_irradiance: f64,
}

/// What the dome processor works with: the rig's [`ProcessingModel`] (lens, sensor,
/// dark/flat, colour, plate), the dome geometry and the per-LED light calibration, all from
/// the rig config and the calibration files it names (`docs/pipeline.md`, "LED dome"), never
/// from the simulator.
#[derive(Debug, Clone)]
pub struct DomeProcessing {
    /// The model every rig's pipeline shares (its `light`, the gonio lamp's, is unused).
    pub model: ProcessingModel,
    /// The dome geometry.
    pub dome: DomeConfig,
    /// Colour filter array.
    pub bayer: Option<BayerPattern>,
    /// The per-LED light calibration.
    pub leds: LedLight,
    /// White balance applied before dividing by each LED's colour: with an LED calibration
    /// and a colour model, the colour model's white balance times the LEDs' mean colour (so
    /// each light is balanced as the colour model expects, its tint taken out); 1 with an LED
    /// calibration only (each light balanced to a flat white); the colour model's without
    /// an LED calibration.
    pub white_balance: [f64; 3],
    /// Texture side, texels.
    pub size: usize,
    /// Resampling filter.
    pub filter: Filter,
    /// The plate's marker registrar (with the model's camera).
    registrar: PlateRegistrar,
}

/// The pose a view group's textures are rectified with (see the module documentation).
#[derive(Debug, Clone)]
pub struct GroupPose {
    /// The sample's pose (the lamp position is set per LED by [`DomeProcessing::texture`]).
    pub pose: ScenePose,
    /// The nominal pose of the group (turntable as commanded).
    pub nominal: ScenePose,
    /// `Markers`, or `NominalFallback` when the markers gave no pose.
    pub source: PoseSource,
    /// Markers used (inliers).
    pub markers: usize,
    /// RMS reprojection error of the markers, pixels.
    pub rms_px: Option<f64>,
    /// Why the markers gave no pose.
    pub reason: Option<String>,
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
    /// Time stamp of the group's first pattern frame, s.
    pub timestamp_s: f64,
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
            timestamp_s: f64::NAN,
            width,
            height,
            data: vec![0.0; frames * width * height],
            filled: vec![false; frames],
        }
    }

    /// Pattern frames the group has (arrived or not).
    pub fn frames(&self) -> usize {
        self.filled.len()
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
    /// The processor of `model`, `dome` and the LED calibration `leds` (`None`: every light
    /// counted equal, relative units) writing `size`-texel textures; refused: a model whose
    /// camera and plate give no marker registrar, a dark/flat calibration of another sensor
    /// size.
    pub fn new(
        model: ProcessingModel,
        dome: DomeConfig,
        bayer: Option<BayerPattern>,
        leds: Option<LedLight>,
        size: usize,
        filter: Filter,
    ) -> Result<DomeProcessing, DomeError> {
        let camera = model.camera.clone();
        if let Some(cal) = &model.dark_flat {
            if (cal.dark.width, cal.dark.height) != (camera.width, camera.height) {
                return Err(DomeError::DarkFlat(btfrig_imaging::dark_flat::DarkFlatError::SizeMismatch {
                    got_w: camera.width,
                    got_h: camera.height,
                    cal_w: cal.dark.width,
                    cal_h: cal.dark.height,
                }));
            }
        }
        let mut registrar = PlateRegistrar::new(camera.clone(), &model.plate, RegisterOptions::default())?;
        registrar.detect = btfrig_markers::DetectParams { camera: Some(camera), ..registrar.detect.clone() };
        let white_balance = match (&leds, &model.color) {
            // The colour model was fitted to camera RGB balanced with the chart's white under
            // the calibration light, which is not a flat white (the gonio's chart white and
            // white tile differ by 2.5 % in blue): keep that balance, and take out of each
            // light only its tint relative to the lights' mean colour, the light the colour
            // calibration stands for (docs/color.md). Balancing each light to a flat white
            // instead fed the model inputs it was not fitted to: grey came out 2 % too red
            // and 4 % too blue-poor, saturated browns 4-7 % too bright.
            (Some(l), Some(c)) => {
                let n = l.colour.len().max(1) as f64;
                std::array::from_fn(|k| c.white_balance[k] * l.colour.iter().map(|v| v[k]).sum::<f64>() / n)
            }
            (None, Some(c)) => c.white_balance,
            // Without a colour model, each light is balanced to a flat white (with an LED
            // calibration; without one, camera RGB as it comes).
            (_, None) => [1.0; 3],
        };
        let n = dome.led_count();
        let leds = leds.unwrap_or(LedLight { power: vec![1.0; n], colour: vec![[1.0; 3]; n], nominal_irradiance: 1.0 });
        Ok(DomeProcessing { model, dome, bayer, leds, white_balance, size, filter, registrar })
    }

    /// Photosite values of `frame` in DN above the dark signal: `(DN - dark(x, y, t, g)) /
    /// flat(x, y)` with the model's dark/flat calibration (defective photosites replaced by
    /// their neighbours), else `DN - black - mean dark current` (no flat: the lens model's
    /// vignetting is divided out later).
    pub fn signal(&self, frame: &RawFrame) -> Result<Vec<f32>, DomeError> {
        if let Some(cal) = &self.model.dark_flat {
            return Ok(cal.corrected_dn(frame)?);
        }
        let s = &self.model.sensor;
        let dark = (s.dark_current_e_per_s * frame.meta.exposure_s * frame.meta.gain / s.electrons_per_dn) as f32;
        let black = f32::from(frame.meta.black_level);
        Ok(frame.data.iter().map(|&v| f32::from(v) - black - dark).collect())
    }

    /// The nominal pose of camera `camera` with the sample at `turntable_rad` (lamp: LED 0).
    pub fn nominal_pose(&self, camera: usize, turntable_rad: f64) -> ScenePose {
        self.dome.scene_pose(camera, turntable_rad, 0)
    }

    /// Registers a complete group from the sum of its pattern frames (module documentation),
    /// falling back to the nominal pose when the markers give none.
    pub fn register(&self, stack: &GroupStack) -> GroupPose {
        let nominal = self.nominal_pose(stack.camera, stack.turntable_rad);
        let cols = stack.width * stack.height;
        let mut sum = vec![0.0f32; cols];
        for frame in stack.data.chunks_exact(cols.max(1)) {
            sum.iter_mut().zip(frame).for_each(|(s, v)| *s += v);
        }
        let (w, h) = (stack.width, stack.height);
        let rgb = btfrig_imaging::demosaic::demosaic_bilinear_values(w, h, self.bayer, &sum);
        let green: Vec<f32> = rgb.data.iter().map(|p| p[1]).collect();
        let found = GrayImage::new(w, h, &green)
            .map_err(|e| e.to_string())
            .and_then(|g| self.registrar.register_image(&g, &nominal).map_err(|e| e.to_string()));
        match found {
            Ok(r) => {
                let r = r.registration;
                GroupPose {
                    pose: r.pose,
                    nominal,
                    source: PoseSource::Markers,
                    markers: r.inlier_markers.len(),
                    rms_px: Some(r.rms_px),
                    reason: None,
                }
            }
            Err(reason) => GroupPose {
                pose: nominal,
                nominal,
                source: PoseSource::NominalFallback,
                markers: 0,
                rms_px: None,
                reason: Some(reason),
            },
        }
    }

    /// The texture region on the sample plane.
    pub fn region(&self) -> Region {
        Region::centred_square(self.model.plate.sample_side_m)
    }

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
        if index == 0 {
            stack.timestamp_s = frame.meta.timestamp_s;
        }
        let v = self.signal(frame)?;
        stack.data[index * cols..(index + 1) * cols].copy_from_slice(&v);
        stack.filled[index] = true;
        Ok(())
    }

    /// Demultiplexes a complete group (in place; single-light groups pass through). Every
    /// result mosaic is its LED's image at the LED's own (calibrated) power, as a single-light
    /// frame is: the demultiplexer returns images per unit of the calibrated intensities it
    /// was given (the LED powers times the pattern scale), so they are multiplied back by the
    /// LED powers here and [`DomeProcessing::texture`] divides them out once for every mode.
    pub fn demultiplex(&self, stack: GroupStack, code: &GroupCode) -> Result<GroupResult, DomeError> {
        let mut result = code.demultiplex(stack)?;
        if result.report.is_some() {
            let cols = result.cols;
            for (j, &p) in self.leds.power.iter().enumerate() {
                let k = p as f32;
                result.mosaics[j * cols..(j + 1) * cols].iter_mut().for_each(|v| *v *= k);
            }
        }
        Ok(result)
    }

    /// The radiance-factor texture of LED `led` from its single-light `mosaic`, seen from the
    /// group's sample pose `pose` (its lamp replaced by the LED) with `exposure_s` and `gain`.
    pub fn texture(
        &self,
        mosaic: &[f32],
        pose: &ScenePose,
        led: usize,
        exposure_s: f64,
        gain: f64,
    ) -> Result<Vec<[f32; 3]>, DomeError> {
        let camera = &self.model.camera;
        let (w, h) = (camera.width, camera.height);
        let rgb = btfrig_imaging::demosaic::demosaic_bilinear_values(w, h, self.bayer, mosaic);
        let img = LinearImage { width: w, height: h, data: rgb.data };
        let pose = ScenePose { lamp_position: self.dome.led_position(led), ..*pose };
        let region = self.region();
        let tex = rectify(&img, camera, &pose, region, self.size, self.filter)?;
        let mut vig = vignetting_map(camera, &pose, region, self.size)?;
        if self.model.dark_flat.is_some() {
            // The flat divided the lens's vignetting out already.
            vig = crate::dark_flat::unit_vignetting(vig);
        }
        let c = self.leds.colour[led];
        let r = Radiometry {
            dn_range: 1.0,
            // What the frame collected of the light: the exposure for an LED, the fraction of
            // the pulse for a flash (whose nominal irradiance is per flash).
            exposure_s: self.dome.light_units(exposure_s),
            dn_per_electron: self.model.sensor.dn_per_electron(gain),
            dark_e_per_s: 0.0,
            nominal_irradiance: self.leds.nominal_irradiance * self.leds.power[led],
            white_balance: [self.white_balance[0] / c[0], self.white_balance[1] / c[1], self.white_balance[2] / c[2]],
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        };
        let mut out = to_radiance_factor(&tex, &vig, &r)?.data;
        if let Some(colour) = &self.model.color {
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
