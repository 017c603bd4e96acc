//! The measurement behind `btfrig bench pipeline`: one frame from raw photosites to texture,
//! stage by stage, as btfrig's pipeline runs it (the mosaic read in place, marker registration
//! in predicted windows, rectification with the vignetting map, radiometry), and as it ran
//! before (whole-frame demosaic, separate vignetting map: [`run_whole_frame`]), against one plain read-and-write pass
//! over the frame (the memory-bandwidth floor), and the 2-frame HDR merge before and after
//! its rewrite ([`btfrig_imaging::hdr::merge_bracket_reference`] against
//! [`btfrig_imaging::hdr::merge_bracket`]) on a rendered bracket. The OpenCV peer of the same
//! frames is [`crate::opencv::run_opencv`] with `pipeline` set. Frames and truths come from
//! [`crate::registration::Bench`].

use std::time::Instant;

use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_imaging::demosaic::demosaic_bilinear;
use btfrig_imaging::hdr::{
    merge_bracket, merge_bracket_into, merge_bracket_reference, MergeOptions, NoiseModel, NominalCalibration,
};
use btfrig_imaging::{rectify, rectify_vignetted, to_radiance_factor, vignetting_map, Filter, LinearImage, Mosaic};
use btfrig_markers::GrayImage;
use btfrig_registration::{texel_position_error, GreyFrame, SearchRecord};
use nalgebra::Point2;

pub use btfrig_registration::BIN_MIN_MODULE_PX;

use crate::registration::{sq_sums, Bench, Frame};

/// Milliseconds per frame of each stage.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stages {
    /// Raw photosites to camera RGB.
    pub demosaic_ms: f64,
    /// Marker detection.
    pub detect_ms: f64,
    /// Pose (or homography) from the corners.
    pub register_ms: f64,
    /// Resampling into the texture.
    pub rectify_ms: f64,
    /// Vignetting and radiometric conversion of the texture.
    pub radiometry_ms: f64,
}

impl Stages {
    /// Their sum.
    pub fn total_ms(&self) -> f64 {
        self.demosaic_ms + self.detect_ms + self.register_ms + self.rectify_ms + self.radiometry_ms
    }
}

/// btfrig's pipeline on one frame.
#[derive(Debug, Clone)]
pub struct OursFrame {
    /// Stage times (median of the repeats; detection and registration from the registrar's
    /// own record of the last repeat's search).
    pub stages: Stages,
    /// Texel position error of the registered pose (mean, max), texels.
    pub texel: (f64, f64),
    /// Texture squared error and squared truth against the area-averaged ground truth.
    pub texture: (f64, f64),
    /// RMS distance of the detected plate corners from the projected true ones, pixels.
    pub corner_rms_px: Option<f64>,
    /// Plate markers detected.
    pub markers: usize,
    /// The radiance-factor texture.
    pub texture_data: Vec<[f32; 3]>,
    /// How the markers were searched.
    pub search: SearchRecord,
    /// The region search's binning for this frame ([`btfrig_registration::PlateRegistrar::region_bin_for`]).
    pub region_bin: usize,
    /// With `region_bin` above 1: the same detection with the regions searched at full
    /// resolution, to compare.
    pub full_resolution_regions: Option<FullResolutionRegions>,
}

/// The detection of a frame whose regions were searched on binned pixels, repeated at full
/// resolution in the same run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FullResolutionRegions {
    /// Marker detection, ms (median of the repeats).
    pub detect_ms: f64,
    /// Largest distance between a corner found both ways, pixels.
    pub max_corner_shift_px: f64,
    /// Whether both found the same markers.
    pub same_markers: bool,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Times `f` `repeat` times (median, ms) and returns its last result.
fn timed<T>(repeat: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut times = Vec::new();
    let mut out = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        out = Some(f());
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    (median(times), out.expect("at least one repeat"))
}

/// btfrig's stages on `frame` (its raw photosites), as a run's processing does them
/// (`btfrig_process`'s `process_bracket`), with the bench's registrar (its learned windows
/// carry over from frame to frame, as in a run): the mosaic read in place (no whole-frame
/// demosaic: `demosaic_ms` is only wrapping it), the demosaiced green filled in and searched
/// in the predicted windows, bilinear rectification (the filter OpenCV's
/// `warpPerspective(INTER_LINEAR)` matches) with the vignetting map from the same
/// projections, and the radiometric conversion.
pub fn run_ours(b: &Bench, frame: &Frame, repeat: usize) -> anyhow::Result<OursFrame> {
    let filter = Filter::Bilinear;
    let cam = b.camera();
    let nominal = b.scene.pose(&frame.commanded);
    let (demosaic_ms, mosaic) = timed(repeat, || Mosaic::of_raw(&frame.raw));
    let mosaic = mosaic?;
    let mut detect = Vec::new();
    let mut register = Vec::new();
    let mut last = None;
    let tolerance = b.registrar.learned_tolerance();
    for _ in 0..repeat.max(1) {
        let r = b.registrar.register_grey_within(GreyFrame::Mosaic(mosaic), &nominal, Some(tolerance))?;
        detect.push(r.detect_s * 1e3);
        register.push(r.register_s * 1e3);
        last = Some(r);
    }
    let reg = last.expect("at least one repeat");
    let region_bin = b.registrar.region_bin_for(&nominal);
    let full_resolution_regions = if region_bin > 1 {
        let mut full = b.registrar.clone();
        full.bin_large_markers = false;
        let mut times = Vec::new();
        let mut last = None;
        for _ in 0..repeat.max(1) {
            let r = full.register_grey_within(GreyFrame::Mosaic(mosaic), &nominal, Some(tolerance))?;
            times.push(r.detect_s * 1e3);
            last = Some(r);
        }
        let r = last.expect("at least one repeat");
        let mut shift = 0.0f64;
        for d in &reg.detections {
            if let Some(e) = r.detections.iter().find(|e| e.id == d.id) {
                for k in 0..4 {
                    shift = shift.max((d.corners[k] - e.corners[k]).norm());
                }
            }
        }
        let ids = |v: &[btfrig_markers::Detection]| v.iter().map(|d| d.id).collect::<Vec<_>>();
        Some(FullResolutionRegions {
            detect_ms: median(times),
            max_corner_shift_px: shift,
            same_markers: ids(&reg.detections) == ids(&r.detections),
        })
    } else {
        None
    };
    b.registrar.remember(&reg.registration, &nominal);
    let pose = reg.registration.pose;
    let (rectify_ms, tex) = timed(repeat, || rectify_vignetted(&mosaic, cam, &pose, b.region, b.size, filter));
    let (tex, vig) = tex?;
    let (radiometry_ms, out) = timed(repeat, || to_radiance_factor(&tex, &vig, &frame.radiometry));
    let out = out?;
    let ids: Vec<(u32, [Point2<f64>; 4])> =
        reg.detections.iter().filter(|d| reg.detected.contains(&d.id)).map(|d| (d.id, d.corners)).collect();
    Ok(OursFrame {
        stages: Stages {
            demosaic_ms,
            detect_ms: median(detect),
            register_ms: median(register),
            rectify_ms,
            radiometry_ms,
        },
        texel: texel_position_error(&b.scene.pose(&frame.truth), &pose, cam, b.region, b.size),
        texture: sq_sums(&out.data, &frame.gt_box),
        corner_rms_px: b.corner_error(frame, &ids).map(|c| c.0),
        markers: reg.detected.len(),
        search: reg.search,
        texture_data: out.data,
        region_bin,
        full_resolution_regions,
    })
}

/// Today's path before the in-place mosaic, kept to compare: the whole frame demosaiced
/// ([`demosaic_bilinear`]), its green channel copied out and searched, [`rectify`] of the
/// demosaiced image and a separate [`vignetting_map`]. Returns the stages' times and the
/// radiance-factor texture (which [`run_ours`]'s equals bit for bit).
pub fn run_whole_frame(b: &Bench, frame: &Frame, repeat: usize) -> anyhow::Result<(Stages, Vec<[f32; 3]>)> {
    let filter = Filter::Bilinear;
    let cam = b.camera();
    let nominal = b.scene.pose(&frame.commanded);
    let (demosaic_ms, dm) = timed(repeat, || demosaic_bilinear(&frame.raw));
    let rgb = LinearImage { width: dm.width, height: dm.height, data: dm.data };
    let tolerance = b.registrar.learned_tolerance();
    let (mut detect, mut register, mut last) = (Vec::new(), Vec::new(), None);
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let green: Vec<f32> = rgb.data.iter().map(|p| p[1]).collect();
        let image = GrayImage::new(rgb.width, rgb.height, &green)?;
        let green_s = t.elapsed().as_secs_f64();
        let r = b.registrar.register_within(&image, &nominal, Some(tolerance))?;
        detect.push((green_s + r.detect_s) * 1e3);
        register.push(r.register_s * 1e3);
        last = Some(r);
    }
    let pose = last.expect("at least one repeat").registration.pose;
    let (rectify_ms, tex) = timed(repeat, || rectify(&rgb, cam, &pose, b.region, b.size, filter));
    let tex = tex?;
    let (radiometry_ms, out) = timed(repeat, || {
        vignetting_map(cam, &pose, b.region, b.size).and_then(|v| to_radiance_factor(&tex, &v, &frame.radiometry))
    });
    let stages =
        Stages { demosaic_ms, detect_ms: median(detect), register_ms: median(register), rectify_ms, radiometry_ms };
    Ok((stages, out?.data))
}

/// One plain pass over the frame (the memory-bandwidth floor): every raw photosite read and
/// written as an `f32`, ms (median of `repeat`; the output is allocated once, outside).
pub fn memory_pass(raw: &RawFrame, repeat: usize) -> f64 {
    let mut out = vec![0.0f32; raw.data.len()];
    let scale = 1.0 / f32::from(raw.meta.white_level.max(1));
    let (ms, ()) = timed(repeat, || {
        // Opaque to the optimiser on both sides, so the pass is really made every time.
        let input = std::hint::black_box(&raw.data[..]);
        for (o, &v) in out.iter_mut().zip(input) {
            *o = f32::from(v) * scale;
        }
        std::hint::black_box(&mut out[..]);
    });
    ms
}

/// The HDR merge of a 2-frame bracket before and after.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HdrResult {
    /// The reference (per-photosite, as before), ms (median).
    pub reference_ms: f64,
    /// The merge the pipeline runs now, ms (median).
    pub fast_ms: f64,
    /// Largest |fast - reference| over the reference's magnitude, over rates and variances.
    pub max_rel_diff: f64,
    /// Whether every photosite used the same exposures.
    pub same_used: bool,
    /// Photosites saturated in both exposures.
    pub saturated_everywhere: usize,
}

/// Renders the bracket of `frame` (its exposure and `ratio` times it, the same true state)
/// and merges it both ways, alternating, `repeat` times each.
pub fn hdr(b: &Bench, cfg: &RigConfig, frame: &Frame, ratio: f64, repeat: usize) -> anyhow::Result<HdrResult> {
    let long_exposure = frame.raw.meta.exposure_s * ratio;
    let (long, _) = b.scene.capture(&frame.truth, 1.0, long_exposure, 1.0, 7_000_001, &b.render)?;
    let frames = [&frame.raw, &long];
    let s = &cfg.sensor;
    let cal = NominalCalibration { dark_current_e_per_s: s.dark_current_e_per_s, electrons_per_dn: s.electrons_per_dn };
    let noise = NoiseModel { electrons_per_dn: s.electrons_per_dn, read_noise_e: s.read_noise_e };
    let opts = MergeOptions::default();
    let (mut slow_t, mut fast_t) = (Vec::new(), Vec::new());
    let mut slow = None;
    // The pipeline merges into planes it keeps from frame to frame (`merge_bracket_into`):
    // one merge first, untimed, as the run's first frame would be; the reference allocates
    // fresh planes every time, as the merge did before.
    let mut fast = merge_bracket(&frames, &cal, &noise, &opts)?;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        slow = Some(merge_bracket_reference(&frames, &cal, &noise, &opts)?);
        slow_t.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        merge_bracket_into(&frames, &cal, &noise, &opts, &mut fast)?;
        fast_t.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let slow = slow.expect("repeat");
    let rel = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (f64::from(*x) - f64::from(*y)).abs() / f64::from(y.abs()).max(1e-30))
            .fold(0.0, f64::max)
    };
    Ok(HdrResult {
        reference_ms: median(slow_t),
        fast_ms: median(fast_t),
        max_rel_diff: rel(&fast.rate, &slow.rate).max(rel(&fast.variance, &slow.variance)),
        same_used: fast.used == slow.used,
        saturated_everywhere: fast.saturated_everywhere(),
    })
}

/// Seconds per capture the rig's camera cannot go below: trigger latency, exposure, read-out
/// and the transfer of one frame (motion overlaps the transfer; `docs/timing.md`).
pub fn capture_floor_s(cfg: &RigConfig, exposure_s: f64, width: usize, height: usize) -> f64 {
    let c = &cfg.timing.camera;
    let bytes = c.frame_bytes.map_or(2.0 * (width * height) as f64, |b| b as f64);
    c.trigger_latency_s + exposure_s + c.read_out_s + bytes / c.transfer_bytes_per_s
}
