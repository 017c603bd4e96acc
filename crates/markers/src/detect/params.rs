//! Detector settings, their check, and the errors of detection.

use btfrig_core::camera::CameraModel;

use super::GrayImage;

/// Why detection cannot run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DetectError {
    /// The image buffer does not match its size.
    #[error("image of {width} x {height} pixels needs {} values, got {len}", width * height)]
    BadImage {
        /// Width.
        width: usize,
        /// Height.
        height: usize,
        /// Values given.
        len: usize,
    },
    /// A parameter is out of range.
    #[error("detector parameter {name} = {value} is invalid: {allowed}")]
    BadParameter {
        /// Parameter name.
        name: &'static str,
        /// Value given.
        value: f64,
        /// Allowed range.
        allowed: &'static str,
    },
    /// The camera model is for another image size.
    #[error("camera model is {cam_w} x {cam_h} pixels but the image is {width} x {height}")]
    CameraSize {
        /// Camera width.
        cam_w: usize,
        /// Camera height.
        cam_h: usize,
        /// Image width.
        width: usize,
        /// Image height.
        height: usize,
    },
}

/// Detector settings. [`DetectParams::default`] suits the simulated rig (markers of 20 px or
/// more per side, modules of 3 px or more).
#[derive(Debug, Clone)]
pub struct DetectParams {
    /// Side of the square window of the adaptive threshold's local mean, pixels (odd, >= 3).
    pub threshold_window_px: usize,
    /// A pixel is dark when it is below `(1 - threshold_rel) * local mean` (0..1).
    pub threshold_rel: f64,
    /// Smallest marker side, pixels (regions with a smaller bounding box are skipped).
    pub min_side_px: f64,
    /// Largest marker side as a fraction of the smaller image dimension (0..1].
    pub max_side_frac: f64,
    /// Regions with a pixel closer than this to the image border are rejected (pixels).
    pub border_margin_px: usize,
    /// Most data bits the decoder may correct (OpenCV's default for 4x4_50 is 1).
    pub max_hamming: u32,
    /// Border modules allowed to read white.
    pub max_border_errors: u32,
    /// Smallest `(white - black) / white` of the marker edges.
    pub min_relative_contrast: f64,
    /// A marker whose edge-fit RMS residual exceeds this on some edge is rejected as partly
    /// hidden or not a clean square (pixels).
    pub max_edge_rms_px: f64,
    /// Systematic floor added (in quadrature, per axis) to each corner's standard deviation:
    /// what the edge-fit residuals cannot see (rendering, model error). 0.02 px: set to the
    /// simulated rig's frontal error when the renderer's regular edge grid quantised it
    /// (0.027 px); with multi-jittered edge samples it is 0.013 px at the renderer's default,
    /// still under the floor (`docs/markers.md`; the scanline-only fit, `edge_model: false`,
    /// wants 0.03).
    pub corner_sigma_floor_px: f64,
    /// When set, edge points are undistorted with this camera before the line fits (lens
    /// distortion bends the edges), and the corners distorted back. Must match the image size.
    pub camera: Option<CameraModel>,
    /// Which pixels the final, model-based edge fit samples (see [`GreenSites`]).
    pub green_sites: GreenSites,
    /// Refine each edge by fitting a model of the pixel values around it (a straight step seen
    /// through the pixel footprint and a fitted blur, with dark and light levels and a shading
    /// gradient) after the scanline passes. `false` keeps the scanline (profile-area) edges
    /// only (the method before; 4 to 20 times worse at 75-80 degrees, `docs/markers.md`).
    pub edge_model: bool,
    /// Search for dark regions (threshold and flood fill) on `region_bin` x `region_bin`
    /// means of the image: 1 searches every pixel; 2 a quarter of them, for frames whose
    /// markers have modules of at least 3 px per bin (large markers on 12 MP frames, where
    /// the search is a large part of the detector's time). The corner fits and the decoding
    /// read the full image either way; the region only gives them their starting quad. 1 to 4.
    pub region_bin: usize,
    /// Markers whose modules are narrower than this across some side (pixels) get their
    /// corners from a fit of the whole module grid (every boundary between a dark and a
    /// light module, from the decoded bits) after the edge model: the border alone gives
    /// the edge model only one or two rows of dark samples there (grazing views). Needs
    /// `edge_model`; markers whose code needed a correction keep the edge model's corners.
    /// 0 turns it off.
    pub module_grid_below_px: f64,
}

/// Which pixels of the grey image are genuine samples for the model-based edge fit. In the
/// green channel of a bilinear demosaic, half the pixels are the mosaic's green photosites
/// and the other half means of their four neighbours; the interpolated half adds a ripple
/// along edges that does not average out on short (foreshortened) edges.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GreenSites {
    /// Every pixel.
    All,
    /// Pixels with `x + y` even only (green photosites of a GRBG or GBRG mosaic).
    Even,
    /// Pixels with `x + y` odd only (green photosites of an RGGB or BGGR mosaic).
    Odd,
    /// Recognise a bilinear-demosaiced green channel (every pixel of one parity equal to the
    /// mean of its four neighbours) and use the other parity; otherwise every pixel.
    #[default]
    Auto,
}

impl Default for DetectParams {
    fn default() -> Self {
        DetectParams {
            threshold_window_px: 51,
            threshold_rel: 0.25,
            min_side_px: 16.0,
            max_side_frac: 0.5,
            border_margin_px: 2,
            max_hamming: 1,
            max_border_errors: 0,
            min_relative_contrast: 0.3,
            max_edge_rms_px: 0.35,
            corner_sigma_floor_px: 0.02,
            camera: None,
            green_sites: GreenSites::Auto,
            edge_model: true,
            region_bin: 1,
            module_grid_below_px: 4.0,
        }
    }
}

impl DetectParams {
    pub(super) fn validate(&self, img: &GrayImage) -> Result<(), DetectError> {
        // The fields are public: check the buffer here too, not only in `GrayImage::new`.
        if img.width == 0 || img.height == 0 || img.data.len() != img.width * img.height {
            return Err(DetectError::BadImage { width: img.width, height: img.height, len: img.data.len() });
        }
        let bad = |name, value: f64, allowed| Err(DetectError::BadParameter { name, value, allowed });
        let w = self.threshold_window_px;
        if w < 3 || w % 2 == 0 {
            return bad("threshold_window_px", w as f64, "odd, at least 3");
        }
        if !(self.threshold_rel > 0.0 && self.threshold_rel < 1.0) {
            return bad("threshold_rel", self.threshold_rel, "between 0 and 1 (exclusive)");
        }
        if !(1..=4).contains(&self.region_bin) {
            return bad("region_bin", self.region_bin as f64, "1, 2, 3 or 4");
        }
        if !(self.min_side_px >= 8.0 && self.min_side_px.is_finite()) {
            return bad("min_side_px", self.min_side_px, "at least 8");
        }
        if !(self.max_side_frac > 0.0 && self.max_side_frac <= 1.0) {
            return bad("max_side_frac", self.max_side_frac, "in (0, 1]");
        }
        if !(self.min_relative_contrast >= 0.0 && self.min_relative_contrast < 1.0) {
            return bad("min_relative_contrast", self.min_relative_contrast, "in [0, 1)");
        }
        if !(self.max_edge_rms_px > 0.0 && self.max_edge_rms_px.is_finite()) {
            return bad("max_edge_rms_px", self.max_edge_rms_px, "positive");
        }
        if !(self.module_grid_below_px >= 0.0 && self.module_grid_below_px.is_finite()) {
            return bad("module_grid_below_px", self.module_grid_below_px, "finite, at least 0");
        }
        if !(self.corner_sigma_floor_px >= 0.0 && self.corner_sigma_floor_px.is_finite()) {
            return bad("corner_sigma_floor_px", self.corner_sigma_floor_px, "finite, at least 0");
        }
        if let Some(c) = &self.camera {
            if c.width != img.width || c.height != img.height {
                return Err(DetectError::CameraSize {
                    cam_w: c.width,
                    cam_h: c.height,
                    width: img.width,
                    height: img.height,
                });
            }
        }
        Ok(())
    }
}
