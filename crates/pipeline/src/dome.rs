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

use btfrig_calib::radiometry::{to_radiance_factor, vignetting_map, Radiometry};
use btfrig_calib::rectify::{rectify, Filter, LinearImage, Region};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::dome::DomeConfig;
use btfrig_core::frame::{BayerPattern, RawFrame};
use btfrig_mux::{DemuxReport, Demultiplexer, DemultiplexerParams, DemuxParams, SMatrix};

/// Errors of dome processing.
#[derive(Debug, thiserror::Error)]
pub enum DomeError {
    /// Demultiplexing failed (shape, ill-conditioned system).
    #[error("demultiplexing: {0}")]
    Mux(#[from] btfrig_mux::MuxError),
    /// Rectification or radiometry failed.
    #[error("rectify: {0}")]
    Rectify(#[from] btfrig_calib::rectify::RectifyError),
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
/// calibration and colour.
#[derive(Debug, Clone)]
pub struct DomeProcessing {
    /// The dome geometry.
    pub dome: DomeConfig,
    /// The lens every arc camera has.
    pub camera: CameraModel,
    /// Colour filter array.
    pub bayer: Option<BayerPattern>,
    /// Photo-electrons per DN at gain 1.
    pub electrons_per_dn: f64,
    /// Dark current, e-/s (its mean is subtracted before demultiplexing).
    pub dark_e_per_s: f64,
    /// Calibrated power factor of each LED.
    pub led_power: Vec<f64>,
    /// Calibrated camera-RGB colour factor of each LED.
    pub led_colour: Vec<[f64; 3]>,
    /// Camera-RGB rate of a white reflector facing a nominal LED at the dome radius, e-/s.
    pub nominal_irradiance: f64,
    /// White balance of the LED spectrum (nominal colour).
    pub white_balance: [f64; 3],
    /// Camera RGB to linear sRGB.
    pub matrix: [[f64; 3]; 3],
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
}

impl GroupCode {
    /// The demultiplexer for `leds` LEDs under an S-matrix of `order`, with the calibrated
    /// LED powers as intensities (always-off slots 0). Every order takes its fast path (the
    /// dome's Paley orders the pixel-vectorised Rader FFT, faster than the dense product at
    /// n = 151 and 199: `docs/benchmarks.md`, "Demultiplexing").
    pub fn multiplexed(order: usize, led_power: &[f64]) -> Result<GroupCode, DomeError> {
        let s = SMatrix::of_order(order)?;
        let mut a = led_power.to_vec();
        a.resize(order, 0.0);
        let params = DemultiplexerParams { demux: DemuxParams::default(), ..DemultiplexerParams::default() };
        Ok(GroupCode::Multiplexed(Box::new(Demultiplexer::new(s, a, params)?)))
    }

    /// Frames per group.
    pub fn frames(&self, leds: usize) -> usize {
        match self {
            GroupCode::Single => leds,
            GroupCode::Multiplexed(d) => d.s().order(),
        }
    }
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

    /// Demultiplexes a complete group (in place; single-light groups pass through).
    pub fn demultiplex(&self, stack: GroupStack, code: &GroupCode) -> Result<GroupResult, DomeError> {
        let cols = stack.width * stack.height;
        match code {
            GroupCode::Single => Ok(GroupResult { mosaics: stack.data, cols, report: None }),
            GroupCode::Multiplexed(d) => {
                let out = d.run(stack.data, cols)?;
                let (mosaics, report) = out.into_parts();
                Ok(GroupResult { mosaics, cols, report: Some(report) })
            }
        }
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
        let rgb = btfrig_render::demosaic::demosaic_bilinear_values(w, h, self.bayer, mosaic);
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
            matrix: self.matrix,
        };
        Ok(to_radiance_factor(&tex, &vig, &r)?.data)
    }
}
