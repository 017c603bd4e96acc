//! The detector: threshold, regions, quads, sub-pixel edges, decoding.

use btfrig_core::camera::CameraModel;
use nalgebra::{Matrix3, Point2, Point3, SMatrix, SVector, Vector2};

use crate::dictionary::Dictionary;

/// A grey image borrowed as `f32` values, row-major, any linear scale (dark = low).
#[derive(Debug, Clone, Copy)]
pub struct GrayImage<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height` values, row-major.
    pub data: &'a [f32],
}

impl<'a> GrayImage<'a> {
    /// Wraps `data`; fails unless it holds `width * height` values and both are positive.
    pub fn new(width: usize, height: usize, data: &'a [f32]) -> Result<Self, DetectError> {
        if width == 0 || height == 0 || data.len() != width * height {
            return Err(DetectError::BadImage { width, height, len: data.len() });
        }
        Ok(GrayImage { width, height, data })
    }

    fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Bilinear value at `(x, y)` (integer = pixel centre), clamped at the image edge.
    fn bilinear(&self, x: f64, y: f64) -> f64 {
        let xm = (self.width - 1) as f64;
        let ym = (self.height - 1) as f64;
        let x = x.clamp(0.0, xm);
        let y = y.clamp(0.0, ym);
        let x0 = (x.floor() as usize).min(self.width.saturating_sub(2));
        let y0 = (y.floor() as usize).min(self.height.saturating_sub(2));
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let a = f64::from(self.at(x0, y0)) * (1.0 - fx) + f64::from(self.at(x1, y0)) * fx;
        let b = f64::from(self.at(x0, y1)) * (1.0 - fx) + f64::from(self.at(x1, y1)) * fx;
        a * (1.0 - fy) + b * fy
    }
}

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
    /// what the edge-fit residuals cannot see (rendering, model error). 0.02 px: the simulated
    /// rig's frontal error, where the rendered image's own edge quantisation dominates
    /// (`docs/markers.md`; the scanline-only fit, `edge_model: false`, wants 0.03).
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
        }
    }
}

impl DetectParams {
    fn validate(&self, img: &GrayImage) -> Result<(), DetectError> {
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

/// How good a detection is.
#[derive(Debug, Clone, PartialEq)]
pub struct Quality {
    /// RMS residual of each edge's line fit (pixels), edge `k` from corner `k` to `k + 1`.
    pub edge_rms_px: [f64; 4],
    /// `(white - black) / white` at the marker's edges.
    pub contrast: f64,
    /// Mean module size along the marker's sides (pixels).
    pub module_px: f64,
    /// Or of the `Quality::*` flag constants.
    pub flags: u32,
}

impl Quality {
    /// The decoder corrected at least one bit.
    pub const CORRECTED: u32 = 1;
    /// Modules smaller than 4 px: bit sampling and edge windows are tight.
    pub const SMALL_MODULES: u32 = 2;
    /// Some edge fit has an RMS residual above half of [`DetectParams::max_edge_rms_px`].
    pub const ROUGH_EDGE: u32 = 4;
}

/// One decoded marker.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Marker id in the dictionary.
    pub id: u32,
    /// Outer corners of the black border, pixels, in the dictionary's canonical order
    /// (top-left, top-right, bottom-right, bottom-left of the marker image).
    pub corners: [Point2<f64>; 4],
    /// Standard deviation of each corner (pixels, per axis: `sqrt(trace(cov) / 2)`), from
    /// the residuals of the two edge fits that meet there plus
    /// [`DetectParams::corner_sigma_floor_px`].
    pub corner_sigma_px: [f64; 4],
    /// Covariance of each corner, `[[xx, xy], [xy, yy]]`, pixels squared.
    pub corner_cov_px2: [[[f64; 2]; 2]; 4],
    /// Bits the decoder corrected.
    pub hamming: u32,
    /// Fit and decoding quality.
    pub quality: Quality,
}

/// Finds the markers of `dict` in `image`. Markers touching the border (within
/// [`DetectParams::border_margin_px`]), regions that are not clean quads, and quads whose
/// border is not black or whose code is farther than [`DetectParams::max_hamming`] from
/// every code are rejected. Each id is reported at most once (the best fit wins).
pub fn detect(image: &GrayImage, dict: &Dictionary, params: &DetectParams) -> Result<Vec<Detection>, DetectError> {
    params.validate(image)?;
    let dark = threshold(image, params);
    let parity = match params.green_sites {
        GreenSites::All => None,
        GreenSites::Even => Some(0),
        GreenSites::Odd => Some(1),
        GreenSites::Auto => demosaic_green_parity(image),
    };
    let (w, h) = (image.width, image.height);
    let max_side = params.max_side_frac * w.min(h) as f64;
    let mut seen = vec![false; w * h];
    let mut stack = Vec::new();
    let mut pixels: Vec<(u32, u32)> = Vec::new();
    let mut out: Vec<Detection> = Vec::new();
    for start in 0..w * h {
        if !dark[start] || seen[start] {
            continue;
        }
        // Flood fill (8-connected) of one dark region.
        pixels.clear();
        stack.push(start);
        seen[start] = true;
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            pixels.push((x as u32, y as u32));
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        continue;
                    }
                    let j = ny as usize * w + nx as usize;
                    if dark[j] && !seen[j] {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
        }
        let (bw, bh) = ((x1 - x0 + 1) as f64, (y1 - y0 + 1) as f64);
        if bw.max(bh) < params.min_side_px || bw.max(bh) > max_side * 1.5 || bw.min(bh) < 3.0 {
            continue;
        }
        let m = params.border_margin_px;
        if x0 < m || y0 < m || x1 + m >= w || y1 + m >= h {
            continue;
        }
        if let Some(d) = candidate(image, dict, params, parity, &pixels) {
            match out.iter_mut().find(|o| o.id == d.id) {
                Some(o) => {
                    if score(&d) < score(o) {
                        *o = d;
                    }
                }
                None => out.push(d),
            }
        }
    }
    out.sort_by_key(|d| d.id);
    Ok(out)
}

/// Finds the markers in a raw frame: the edges are fitted on its green photosites (on every
/// photosite of a frame without mosaic), the rest runs on the green channel interpolated as
/// a bilinear demosaic does (the mean of the 3 x 3 neighbourhood's green sites), values
/// `(dn - black) / (white - black)`. Same results as [`detect`] on the green channel of
/// `btfrig_render`'s bilinear demosaic with `green_sites` set by the pattern; it does not
/// rely on recognising the demosaic. `params.green_sites` is ignored.
pub fn detect_raw(
    raw: &btfrig_core::frame::RawFrame,
    dict: &Dictionary,
    params: &DetectParams,
) -> Result<Vec<Detection>, DetectError> {
    let (w, h) = (raw.width, raw.height);
    if w == 0 || h == 0 || raw.data.len() != w * h {
        return Err(DetectError::BadImage { width: w, height: h, len: raw.data.len() });
    }
    let black = f32::from(raw.meta.black_level);
    let range = (f32::from(raw.meta.white_level) - black).max(1.0);
    let norm = |v: u16| (f32::from(v) - black) / range;
    let mut p = params.clone();
    let green: Vec<f32> = match raw.meta.bayer {
        None => {
            p.green_sites = GreenSites::All;
            raw.data.iter().map(|&v| norm(v)).collect()
        }
        Some(bayer) => {
            let is_green = |x: usize, y: usize| bayer.channel_at(x, y) == 1;
            // Green sites have x + y of one parity in every Bayer layout.
            p.green_sites = if is_green(0, 0) { GreenSites::Even } else { GreenSites::Odd };
            let mut g = vec![0.0f32; w * h];
            for y in 0..h {
                for x in 0..w {
                    g[y * w + x] = if is_green(x, y) {
                        norm(raw.data[y * w + x])
                    } else {
                        let (mut sum, mut n) = (0.0f32, 0u32);
                        for yy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                            for xx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                                if is_green(xx, yy) {
                                    sum += norm(raw.data[yy * w + xx]);
                                    n += 1;
                                }
                            }
                        }
                        if n > 0 {
                            sum / n as f32
                        } else {
                            0.0
                        }
                    };
                }
            }
            g
        }
    };
    detect(&GrayImage::new(w, h, &green)?, dict, &p)
}

fn score(d: &Detection) -> f64 {
    d.hamming as f64 + d.quality.edge_rms_px.iter().sum::<f64>()
}

/// Dark mask: `v < (1 - rel) * local mean`, the mean over a square window (integral image).
fn threshold(img: &GrayImage, p: &DetectParams) -> Vec<bool> {
    let (w, h) = (img.width, img.height);
    let mut integ = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            row += f64::from(img.at(x, y));
            integ[(y + 1) * (w + 1) + x + 1] = integ[y * (w + 1) + x + 1] + row;
        }
    }
    let r = p.threshold_window_px / 2;
    let k = 1.0 - p.threshold_rel;
    let mut dark = vec![false; w * h];
    for y in 0..h {
        let (ya, yb) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (xa, xb) = (x.saturating_sub(r), (x + r + 1).min(w));
            let s = integ[yb * (w + 1) + xb] - integ[ya * (w + 1) + xb] - integ[yb * (w + 1) + xa]
                + integ[ya * (w + 1) + xa];
            let mean = s / ((yb - ya) * (xb - xa)) as f64;
            // A positive mean only: on black velvet (mean ~ 0) nothing counts as dark.
            dark[y * w + x] = mean > 0.0 && f64::from(img.at(x, y)) < k * mean;
        }
    }
    dark
}

fn cross(a: Vector2<f64>, b: Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Quad from a region's extreme pixels, in clockwise order on screen (y down).
fn initial_quad(pixels: &[(u32, u32)]) -> Option<[Point2<f64>; 4]> {
    let n = pixels.len() as f64;
    let (sx, sy) = pixels.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0 as f64, a.1 + p.1 as f64));
    let c = Point2::new(sx / n, sy / n);
    let pt = |p: &(u32, u32)| Point2::new(p.0 as f64, p.1 as f64);
    let far = |from: Point2<f64>| {
        pixels.iter().map(pt).max_by(|a, b| (a - from).norm_squared().total_cmp(&(b - from).norm_squared()))
    };
    let p0 = far(c)?;
    let p2 = far(p0)?;
    let d = p2 - p0;
    let side = |p: &Point2<f64>| cross(d, p - p0);
    let p1 = pixels.iter().map(pt).max_by(|a, b| side(a).total_cmp(&side(b)))?;
    let p3 = pixels.iter().map(pt).min_by(|a, b| side(a).total_cmp(&side(b)))?;
    let mut q = [p0, p1, p2, p3];
    let area: f64 = (0..4).map(|i| cross(q[i].coords, q[(i + 1) % 4].coords)).sum();
    if area < 0.0 {
        q.swap(1, 3);
    }
    // Convex and not degenerate: every turn to the same side.
    for i in 0..4 {
        let (a, b, c) = (q[i], q[(i + 1) % 4], q[(i + 2) % 4]);
        if cross(b - a, c - b) <= 0.0 {
            return None;
        }
    }
    // Pixel centres of the dark region lie about half a pixel inside its edges.
    let centre = Point2::from((q[0].coords + q[1].coords + q[2].coords + q[3].coords) / 4.0);
    for p in &mut q {
        let v = *p - centre;
        *p += v.normalize() * 0.7;
    }
    Some(q)
}

/// One edge's sub-pixel line in the (possibly undistorted) fitting frame.
struct EdgeFit {
    /// Unit normal `n` and offset `c` of the line `n . p = c`.
    n: Vector2<f64>,
    c: f64,
    /// Centroid of the points and unit direction.
    mid: Point2<f64>,
    dir: Vector2<f64>,
    /// RMS residual of the edge points (scanline fits; 0 for model fits).
    rms: f64,
    dark: f64,
    light: f64,
    /// Variance of the line's offset at `mid` and of its slope (px^2, rad^2).
    off_var: f64,
    slope_var: f64,
    /// Model fits only: the fitted blur width and its variance (infinite when it was fixed).
    blur: f64,
    blur_var: f64,
}

fn to_fit(cam: Option<&CameraModel>, p: Point2<f64>) -> Option<Point2<f64>> {
    match cam {
        None => Some(p),
        Some(c) => {
            let r = c.try_pixel_ray(p)?;
            Some(Point2::new(c.fx * r.x / r.z + c.cx, c.fy * r.y / r.z + c.cy))
        }
    }
}

fn from_fit(cam: Option<&CameraModel>, p: Point2<f64>) -> Option<Point2<f64>> {
    match cam {
        None => Some(p),
        Some(c) => c.project(&Point3::new((p.x - c.cx) / c.fx, (p.y - c.cy) / c.fy, 1.0)),
    }
}

/// Fits edge `a -> b` (marker dark on the right-hand side of the direction in screen
/// coordinates, i.e. the outward normal is `(dy, -dx)`). Each scanline's profile runs from
/// `ad` pixels inside (dark) to `bl` pixels outside (light).
fn fit_edge(
    img: &GrayImage,
    cam: Option<&CameraModel>,
    a: Point2<f64>,
    b: Point2<f64>,
    ad: f64,
    bl: f64,
) -> Option<EdgeFit> {
    let len = (b - a).norm();
    let dir = (b - a) / len;
    let nrm = Vector2::new(dir.y, -dir.x);
    let step = 0.25;
    let nd = (ad / step).round() as usize;
    let ad = nd as f64 * step;
    let nl = (bl / step).round() as usize;
    let bl = nl as f64 * step;
    let ns = nd + nl + 1;
    // Away from the corners, where the other edge's transition would enter the window; on
    // short (foreshortened) edges at most a fifth of the edge at each end.
    let margin = (ad.max(2.0) + 1.0).min(0.2 * len);
    if len < 2.0 * margin + 4.0 {
        return None;
    }
    let nlines = (len - 2.0 * margin).floor() as usize;
    // Profiles first: the dark and light levels (outer quarters of the profiles) are averaged
    // over the whole edge, so the per-scanline offsets carry only the integral's noise.
    let mut profiles = Vec::with_capacity(nlines);
    let (mut dsum, mut lsum, mut dn, mut ln) = (0.0, 0.0, 0.0, 0.0);
    for k in 0..=nlines {
        let t = margin + k as f64 * (len - 2.0 * margin) / nlines as f64;
        let base = a + dir * t;
        let prof: Vec<f64> = (0..ns)
            .map(|i| {
                let s = -ad + i as f64 * step;
                let p = base + nrm * s;
                img.bilinear(p.x, p.y)
            })
            .collect();
        let q = (ns / 4).max(1);
        dsum += prof[..q].iter().sum::<f64>();
        dn += q as f64;
        lsum += prof[ns - q..].iter().sum::<f64>();
        ln += q as f64;
        profiles.push((base, prof));
    }
    let (dark, light) = (dsum / dn, lsum / ln);
    if !(light - dark > 0.0) {
        return None;
    }
    let mut pts = Vec::with_capacity(profiles.len());
    for (base, prof) in &profiles {
        // Trapezoid integral of the profile over [-hw, hw].
        let integ = step * (prof.iter().sum::<f64>() - 0.5 * (prof[0] + prof[ns - 1]));
        // A step from `dark` to `light` at `e` has this integral over [-ad, bl].
        let e = (dark * ad + light * bl - integ) / (light - dark);
        if e < -ad || e > bl {
            continue;
        }
        if let Some(p) = to_fit(cam, base + nrm * e) {
            pts.push(p);
        }
    }
    let mut fit = line_fit(&pts)?;
    // One pass without outliers (3.5 robust sigmas), then the final fit.
    let mut res: Vec<f64> = pts.iter().map(|p| (fit.n.dot(&p.coords) - fit.c).abs()).collect();
    res.sort_by(f64::total_cmp);
    let mad = res[res.len() / 2] * 1.4826;
    let lim = (3.5 * mad).max(0.05);
    let kept: Vec<Point2<f64>> = pts.iter().copied().filter(|p| (fit.n.dot(&p.coords) - fit.c).abs() <= lim).collect();
    if kept.len() * 10 >= pts.len() * 8 {
        fit = line_fit(&kept)?;
    } else {
        fit = line_fit(&pts)?;
    }
    // Keep the normal pointing outward (to the light side) as in the input.
    let nfit = to_fit(cam, a + nrm).zip(to_fit(cam, a)).map(|(p, q)| p - q).unwrap_or(nrm);
    if fit.n.dot(&nfit) < 0.0 {
        fit.n = -fit.n;
        fit.c = -fit.c;
        fit.dir = -fit.dir;
    }
    fit.dark = dark;
    fit.light = light;
    Some(fit)
}

fn line_fit(pts: &[Point2<f64>]) -> Option<EdgeFit> {
    if pts.len() < 5 {
        return None;
    }
    let n = pts.len() as f64;
    let mid = Point2::from(pts.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / n);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in pts {
        let d = p - mid;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    // Direction: principal axis of the scatter (total least squares).
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let dir = Vector2::new(theta.cos(), theta.sin());
    let nv = Vector2::new(-dir.y, dir.x);
    let c = nv.dot(&mid.coords);
    let ss: f64 = pts.iter().map(|p| (nv.dot(&p.coords) - c).powi(2)).sum();
    let spread2: f64 = pts.iter().map(|p| dir.dot(&(p - mid)).powi(2)).sum();
    let var = ss / (n - 2.0);
    Some(EdgeFit {
        n: nv,
        c,
        mid,
        dir,
        rms: (ss / n).sqrt(),
        dark: 0.0,
        light: 0.0,
        off_var: var / n,
        slope_var: var / spread2.max(1e-9),
        blur: 0.0,
        blur_var: f64::INFINITY,
    })
}

/// Intersection of two fitted lines and its covariance (in the fitting frame).
fn intersect(l1: &EdgeFit, l2: &EdgeFit) -> Option<(Point2<f64>, [[f64; 2]; 2])> {
    let m = nalgebra::Matrix2::new(l1.n.x, l1.n.y, l2.n.x, l2.n.y);
    let inv = m.try_inverse()?;
    let p = inv * Vector2::new(l1.c, l2.c);
    let p = Point2::from(p);
    // Variance of each line's offset at the corner, from its fit (1/N + t^2 / sum t_i^2).
    let off_var = |l: &EdgeFit| {
        let t = l.dir.dot(&(p - l.mid));
        l.off_var + t * t * l.slope_var
    };
    let (v1, v2) = (off_var(l1), off_var(l2));
    // dp = inv * (dc1, dc2).
    let mut cov = [[0.0; 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            cov[i][j] = inv[(i, 0)] * inv[(j, 0)] * v1 + inv[(i, 1)] * inv[(j, 1)] * v2;
        }
    }
    Some((p, cov))
}

/// Homography from module coordinates (corner `k` of the unit square scaled by `m`) to the
/// image quad `q`.
fn homography(q: &[Point2<f64>; 4], m: f64) -> Option<Matrix3<f64>> {
    let src = [(0.0, 0.0), (m, 0.0), (m, m), (0.0, m)];
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    let mut b = SVector::<f64, 8>::zeros();
    for k in 0..4 {
        let (x, y) = src[k];
        let (u, v) = (q[k].x, q[k].y);
        a.set_row(2 * k, &nalgebra::RowSVector::<f64, 8>::from_row_slice(&[x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y]));
        a.set_row(
            2 * k + 1,
            &nalgebra::RowSVector::<f64, 8>::from_row_slice(&[0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y]),
        );
        b[2 * k] = u;
        b[2 * k + 1] = v;
    }
    let hv = a.lu().solve(&b)?;
    Some(Matrix3::new(hv[0], hv[1], hv[2], hv[3], hv[4], hv[5], hv[6], hv[7], 1.0))
}

fn apply_h(hm: &Matrix3<f64>, x: f64, y: f64) -> Point2<f64> {
    let p = hm * nalgebra::Vector3::new(x, y, 1.0);
    Point2::new(p.x / p.z, p.y / p.z)
}

fn candidate(
    img: &GrayImage,
    dict: &Dictionary,
    p: &DetectParams,
    parity: Option<usize>,
    pixels: &[(u32, u32)],
) -> Option<Detection> {
    let mut q = initial_quad(pixels)?;
    let sides: Vec<f64> = (0..4).map(|i| (q[(i + 1) % 4] - q[i]).norm()).collect();
    let (smin, smax) = sides.iter().fold((f64::MAX, 0.0f64), |a, &s| (a.0.min(s), a.1.max(s)));
    if smax < p.min_side_px || smin < 0.25 * p.min_side_px || smax > p.max_side_frac * img.width.min(img.height) as f64
    {
        return None;
    }
    // Every region pixel inside the quad (with a tolerance): rejects blobs that are not
    // quads and markers merged with dark neighbours.
    let tol = 1.5 + 0.04 * smax;
    let outside = pixels
        .iter()
        .filter(|px| {
            let pt = Point2::new(px.0 as f64, px.1 as f64);
            (0..4).any(|i| {
                let (a, b) = (q[i], q[(i + 1) % 4]);
                let d = (b - a).normalize();
                cross(d, pt - a) < -tol
            })
        })
        .count();
    if outside * 100 > pixels.len() {
        return None;
    }
    let modules = (dict.size + 2) as f64;
    let cam = p.camera.as_ref();
    // Three refinement passes: the later ones centre the scanlines on the first pass's lines.
    let mut fits: Vec<EdgeFit> = Vec::new();
    let mut cov = [[[0.0; 2]; 2]; 4];
    for _pass in 0..3 {
        fits.clear();
        for i in 0..4 {
            let (a, b) = (q[i], q[(i + 1) % 4]);
            let across = module_across(&q, i, modules);
            // Symmetric window of half a module (at most 3 px): the outer quarters give the
            // levels. (An asymmetric window reaching farther into the quiet zone measured worse.)
            let ad = (0.5 * across).clamp(1.0, 3.0);
            let bl = ad;
            fits.push(fit_edge(img, cam, a, b, ad, bl)?);
        }
        let mut nq = q;
        for k in 0..4 {
            // Corner k joins edge k-1 (from corner k-1) and edge k.
            let (pt, c) = intersect(&fits[(k + 3) % 4], &fits[k])?;
            nq[k] = from_fit(cam, pt)?;
            let f2 = p.corner_sigma_floor_px * p.corner_sigma_floor_px;
            cov[k] = [[c[0][0] + f2, c[0][1]], [c[1][0], c[1][1] + f2]];
        }
        // The refined corners must stay near the region's.
        if (0..4).any(|k| (nq[k] - q[k]).norm() > 0.25 * smin + 2.0) {
            return None;
        }
        q = nq;
    }
    let edge_rms = [fits[0].rms, fits[1].rms, fits[2].rms, fits[3].rms];
    if edge_rms.iter().any(|&r| r > p.max_edge_rms_px) {
        return None;
    }
    if p.edge_model {
        // If an edge's model fit fails, the scanline corners stay.
        'model: {
            let mut mf = Vec::with_capacity(4);
            let mut bands = [(0.0, 0.0); 4];
            for i in 0..4 {
                let (a, b) = (q[i], q[(i + 1) % 4]);
                let across = module_across(&q, i, modules);
                // Inside, the border is one module wide (a white data module may follow);
                // outside, the quiet zone is wider.
                let hin = (0.55 * across).clamp(1.0, 4.0);
                let hout = across.clamp(1.5, 4.0);
                bands[i] = (hin, hout);
                match fit_edge_model(img, parity, cam, [q[(i + 3) % 4], a, b, q[(i + 2) % 4]], hin, hout, None) {
                    Some(f) => mf.push(f),
                    None => break 'model,
                }
            }
            // The blur belongs to the camera, not to an edge: where one edge's data cannot
            // tell it from a shift (a sharp edge along a pixel row, few samples on its
            // slope), refit that edge with the marker's blur (the inverse-variance mean).
            let (sw, swb) = mf
                .iter()
                .filter(|f| f.blur_var.is_finite() && f.blur_var > 0.0)
                .fold((0.0, 0.0), |acc, f| (acc.0 + 1.0 / f.blur_var, acc.1 + f.blur / f.blur_var));
            if sw > 0.0 {
                let blur = (swb / sw).max(B_MIN);
                for i in 0..4 {
                    if mf[i].blur_var.sqrt() > 0.3 || mf[i].off_var.sqrt() > 0.05 {
                        let (a, b) = (q[i], q[(i + 1) % 4]);
                        let (hin, hout) = bands[i];
                        let corners = [q[(i + 3) % 4], a, b, q[(i + 2) % 4]];
                        match fit_edge_model(img, parity, cam, corners, hin, hout, Some(blur)) {
                            Some(f) => mf[i] = f,
                            None => break 'model,
                        }
                    }
                }
            }
            let mut nq = q;
            let mut ncov = cov;
            for k in 0..4 {
                let Some((pt, c)) = intersect(&mf[(k + 3) % 4], &mf[k]) else { break 'model };
                let Some(im) = from_fit(cam, pt) else { break 'model };
                if (im - q[k]).norm() > 1.0 {
                    break 'model;
                }
                nq[k] = im;
                let f2 = p.corner_sigma_floor_px * p.corner_sigma_floor_px;
                ncov[k] = [[c[0][0] + f2, c[0][1]], [c[1][0], c[1][1] + f2]];
            }
            q = nq;
            cov = ncov;
        }
    }
    let dark = fits.iter().map(|f| f.dark).sum::<f64>() / 4.0;
    let light = fits.iter().map(|f| f.light).sum::<f64>() / 4.0;
    let contrast = (light - dark) / light;
    if !(light > 0.0 && contrast >= p.min_relative_contrast) {
        return None;
    }
    let thr = 0.5 * (dark + light);
    // Sample the module grid: mean of 3x3 points in each module's central half.
    let hm = homography(&q, modules)?;
    let n = dict.size + 2;
    let mut white = vec![false; n * n];
    for r in 0..n {
        for c in 0..n {
            let mut s = 0.0;
            for a in [-0.25, 0.0, 0.25] {
                for b in [-0.25, 0.0, 0.25] {
                    let pt = apply_h(&hm, c as f64 + 0.5 + a, r as f64 + 0.5 + b);
                    s += img.bilinear(pt.x, pt.y);
                }
            }
            white[r * n + c] = s / 9.0 > thr;
        }
    }
    let border_errors =
        (0..n * n).filter(|&i| white[i] && (i / n == 0 || i % n == 0 || i / n == n - 1 || i % n == n - 1)).count();
    if border_errors as u32 > p.max_border_errors {
        return None;
    }
    let mut code = 0u64;
    for r in 0..dict.size {
        for c in 0..dict.size {
            if white[(r + 1) * n + c + 1] {
                code |= 1 << (r * dict.size + c);
            }
        }
    }
    // Best (id, start corner): the code read from quad corner k is the observed code turned
    // k quarter turns.
    let mut best = (u32::MAX, 0usize, 0usize);
    let mut obs = code;
    for k in 0..4 {
        for (id, &cd) in dict.codes.iter().enumerate() {
            let d = (obs ^ cd).count_ones();
            if d < best.0 {
                best = (d, id, k);
            }
        }
        obs = dict.rotate(obs);
    }
    let (ham, id, k) = best;
    if ham > p.max_hamming {
        return None;
    }
    let module_px = sides.iter().sum::<f64>() / (4.0 * modules);
    let mut flags = 0;
    if ham > 0 {
        flags |= Quality::CORRECTED;
    }
    if module_px < 4.0 {
        flags |= Quality::SMALL_MODULES;
    }
    if edge_rms.iter().any(|&r| r > 0.5 * p.max_edge_rms_px) {
        flags |= Quality::ROUGH_EDGE;
    }
    let idx = |j: usize| (k + j) % 4;
    let sigma = |c: &[[f64; 2]; 2]| (0.5 * (c[0][0] + c[1][1])).sqrt();
    Some(Detection {
        id: id as u32,
        corners: std::array::from_fn(|j| q[idx(j)]),
        corner_sigma_px: std::array::from_fn(|j| sigma(&cov[idx(j)])),
        corner_cov_px2: std::array::from_fn(|j| cov[idx(j)]),
        hamming: ham,
        quality: Quality { edge_rms_px: std::array::from_fn(|j| edge_rms[idx(j)]), contrast, module_px, flags },
    })
}

/// The parity (`(x + y) % 2`) of the genuine samples, if `img` is the green channel of a
/// bilinear demosaic: then every pixel of the other parity is the mean of its four
/// neighbours (to float rounding), which the genuine photosites (noisy) are not. Flat
/// places (all four neighbours equal) do not count.
fn demosaic_green_parity(img: &GrayImage) -> Option<usize> {
    let (w, h) = (img.width, img.height);
    if w < 8 || h < 8 {
        return None;
    }
    let (mut tested, mut hold) = ([0usize; 2], [0usize; 2]);
    // Every eighth row is plenty (about 240 000 pixels tested on a 1600 x 1200 frame).
    for y in (1..h - 1).step_by(8) {
        for x in 1..w - 1 {
            let nb = [img.at(x - 1, y), img.at(x + 1, y), img.at(x, y - 1), img.at(x, y + 1)];
            let (lo, hi) = nb.iter().fold((f32::MAX, f32::MIN), |a, &v| (a.0.min(v), a.1.max(v)));
            let scale = hi.abs().max(lo.abs());
            if !(hi - lo > 1e-4 * scale) {
                continue;
            }
            let mean = (f64::from(nb[0]) + f64::from(nb[1]) + f64::from(nb[2]) + f64::from(nb[3])) / 4.0;
            let par = (x + y) % 2;
            tested[par] += 1;
            if (f64::from(img.at(x, y)) - mean).abs() <= 1e-5 * f64::from(scale) {
                hold[par] += 1;
            }
        }
    }
    for par in 0..2 {
        let other = 1 - par;
        if tested[par] >= 1000 && hold[par] * 100 >= tested[par] * 99 && hold[other] * 2 <= tested[other] {
            return Some(other);
        }
    }
    None
}

/// Model-based refinement of edge `a -> b` (as in [`fit_edge`]: marker dark on the
/// right-hand side, outward normal `(dy, -dx)`): every sample pixel (of parity `parity`
/// when given) within `h` of the line and more than `margin` from its ends is fitted by a
/// blurred step `D + (L - D) (1 + tanh((s - e0 - e1 u) / w)) / 2` across the line (`s` the
/// signed distance, `u` the position along it from the samples' mean), by Gauss-Newton over
/// `(e0, e1, D, L, w)`. Any symmetric blur (pixel area, demosaic, optics) leaves the fitted
/// centre unbiased; using every pixel in the band, not scanlines, keeps the short
/// foreshortened edges' samples up to the corners.
/// Module size across edge `i` of quad `q` (corner `i` to `i + 1`): the distance of the two
/// other corners from the edge's line over the module count. (Not the adjacent sides'
/// length: a sheared, foreshortened quad is much thinner across an edge than its sides.)
fn module_across(q: &[Point2<f64>; 4], i: usize, modules: f64) -> f64 {
    let (a, b) = (q[i], q[(i + 1) % 4]);
    let d = (b - a).normalize();
    let dist = |p: Point2<f64>| cross(d, p - a).abs();
    0.5 * (dist(q[(i + 2) % 4]) + dist(q[(i + 3) % 4])) / modules
}

/// Smallest blur of the edge model (pixels): below it an axis-parallel edge on a pixel
/// boundary leaves no sample on the model's slope (singular fit).
const B_MIN: f64 = 0.1;

/// Gauss-Newton iterations of the edge model at most (it starts from the scanline edge and
/// usually converges in 3 to 6).
const MODEL_ITERATIONS: usize = 12;

fn fit_edge_model(
    img: &GrayImage,
    parity: Option<usize>,
    cam: Option<&CameraModel>,
    corners: [Point2<f64>; 4],
    hin: f64,
    hout: f64,
    fixed_blur: Option<f64>,
) -> Option<EdgeFit> {
    // corners: the previous corner, this edge's two, the next one (clockwise on screen).
    let [prev, a, b, next] = corners;
    // Signed distance inside the adjacent edge `u -> v` (outward normal `(dy, -dx)`).
    let inside = |u: Point2<f64>, v: Point2<f64>, p: Point2<f64>| {
        let d = (v - u).normalize();
        -(Vector2::new(d.y, -d.x).dot(&(p - u)))
    };
    let h = hin.max(hout);
    let (af, bf) = (to_fit(cam, a)?, to_fit(cam, b)?);
    let len = (bf - af).norm();
    let dir = (bf - af) / len;
    let nrm = Vector2::new(dir.y, -dir.x);
    let margin = 1.5f64.min(0.2 * len);
    let len_img = (b - a).norm();
    let dir_img = (b - a) / len_img;
    let nrm_img = Vector2::new(dir_img.y, -dir_img.x);
    // Samples (u along, s across, value), from the pixels in the band's bounding box.
    let pad = h + 1.0;
    let (xa, xb) = (a.x.min(b.x) - pad, a.x.max(b.x) + pad);
    let (ya, yb) = (a.y.min(b.y) - pad, a.y.max(b.y) + pad);
    let x0 = xa.floor().max(0.0) as usize;
    let x1 = (xb.ceil().max(0.0) as usize).min(img.width - 1);
    let y0 = ya.floor().max(0.0) as usize;
    let y1 = (yb.ceil().max(0.0) as usize).min(img.height - 1);
    let mut samples: Vec<(f64, f64, f64)> = Vec::new();
    for y in y0..=y1 {
        for x in x0..=x1 {
            if parity.is_some_and(|p| (x + y) % 2 != p) {
                continue;
            }
            let px = Point2::new(x as f64, y as f64);
            // Cheap test in image coordinates first (distortion moves a point by far less
            // than a pixel within an edge's length).
            let (ti, si) = (dir_img.dot(&(px - a)), nrm_img.dot(&(px - a)));
            if si < -hin - 1.0 || si > hout + 1.0 || ti < margin - 1.0 || ti > len_img - margin + 1.0 {
                continue;
            }
            // Near an acute corner the inner band crosses the adjacent edge: those samples
            // are light, not the border's dark.
            if (inside(prev, a, px) < 1.0 || inside(b, next, px) < 1.0) && nrm_img.dot(&(px - a)) < 0.0 {
                continue;
            }
            let pf = to_fit(cam, px)?;
            let d = pf - af;
            let (t, s) = (dir.dot(&d), nrm.dot(&d));
            if t >= margin && t <= len - margin && s >= -hin && s <= hout {
                samples.push((t, s, f64::from(img.at(x, y))));
            }
        }
    }
    if samples.len() < 20 {
        return None;
    }
    let n = samples.len() as f64;
    let tm = samples.iter().map(|q| q.0).sum::<f64>() / n;
    let level = |lo: f64, hi: f64| {
        let (sum, cnt) =
            samples.iter().filter(|q| q.1 >= lo && q.1 <= hi).fold((0.0, 0.0), |acc, q| (acc.0 + q.2, acc.1 + 1.0));
        (cnt > 0.0).then(|| sum / cnt)
    };
    // The pixel footprint (a unit square) projected on the line's normal: two uniform
    // widths; the fitted blur `b` is a third.
    let (wa, wb) = (nrm.x.abs().max(0.02), nrm.y.abs().max(0.02));
    // Starting levels: the outer halves of the band (on a narrow band along a pixel row
    // the outer half may hold no sample row: then beyond 0.4 px).
    let d0 = level(-hin, -0.5 * hin).or_else(|| level(-hin, -0.4));
    let l0 = level(0.5 * hout, hout).or_else(|| level(0.4, hout));
    let (Some(d0), Some(l0)) = (d0, l0) else {
        return None;
    };
    let mut p = [0.0, 0.0, d0, l0, fixed_blur.unwrap_or(0.3), 0.0];
    // The blur is left out of a step (and of the covariance) when fixed or at its bound.
    let pin_blur = |p: &[f64; 6], m: &mut SMatrix<f64, 6, 6>, r: &mut SVector<f64, 6>| {
        if fixed_blur.is_some() || p[4] <= B_MIN * 1.001 && r[4] < 0.0 {
            m.row_mut(4).fill(0.0);
            m.column_mut(4).fill(0.0);
            m[(4, 4)] = 1.0;
            r[4] = 0.0;
        }
    };
    if !(p[3] > p[2]) {
        return None;
    }
    // p: offset, slope, dark, light, blur, shading gradient along the line (per px).
    // Value, and the step's density and derivative in the blur width.
    let shade = |p: &[f64; 6], t: f64| 1.0 + p[5] * (t - tm);
    let model = |p: &[f64; 6], t: f64, s: f64| -> (f64, f64, f64, f64) {
        let x = s - p[0] - p[1] * (t - tm);
        let (cdf, pdf, dcdf) = uniform3_cdf(x, wa, wb, p[4]);
        ((p[2] + (p[3] - p[2]) * cdf) * shade(p, t), cdf, pdf, dcdf)
    };
    let sse = |p: &[f64; 6]| samples.iter().map(|&(t, s, v)| (v - model(p, t, s).0).powi(2)).sum::<f64>();
    let mut cur = sse(&p);
    let mut lambda = 1e-3;
    let mut jtj = SMatrix::<f64, 6, 6>::zeros();
    for _ in 0..MODEL_ITERATIONS {
        jtj.fill(0.0);
        let mut jtr = SVector::<f64, 6>::zeros();
        for &(t, s, v) in &samples {
            let u = t - tm;
            let (f, cdf, pdf, dcdf) = model(&p, t, s);
            let sh = shade(&p, t);
            let amp = p[3] - p[2];
            let g0 = -amp * pdf * sh;
            let gb = amp * dcdf * sh;
            let j = SVector::<f64, 6>::from([g0, g0 * u, (1.0 - cdf) * sh, cdf * sh, gb, f / sh * u]);
            jtj += j * j.transpose();
            jtr += j * (v - f);
        }
        let mut improved = false;
        for _ in 0..8 {
            let mut m = jtj;
            pin_blur(&p, &mut m, &mut jtr);
            for i in 0..6 {
                m[(i, i)] *= 1.0 + lambda;
                m[(i, i)] += 1e-12;
            }
            let Some(step) = m.cholesky().map(|c| c.solve(&jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let mut q = p;
            for i in 0..6 {
                q[i] += step[i];
            }
            q[4] = q[4].max(B_MIN);
            if q[0].abs() > hin.min(hout) || q[4] > h {
                lambda *= 10.0;
                continue;
            }
            let new = sse(&q);
            if new <= cur {
                let small = step[0].abs() < 1e-5 && step[1].abs() < 1e-7;
                p = q;
                cur = new;
                lambda = (lambda * 0.3).max(1e-7);
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    if !(p[3] > p[2]) {
        return None;
    }
    // At its lower bound the blur is not a free parameter: leave it out of the covariance
    // (a sharp axis-parallel edge on a pixel boundary would otherwise look singular).
    if fixed_blur.is_some() || p[4] <= B_MIN * 1.001 {
        jtj.row_mut(4).fill(0.0);
        jtj.column_mut(4).fill(0.0);
        jtj[(4, 4)] = 1.0;
    }
    let inv = jtj.try_inverse()?;
    let cov = inv * (cur / (n - 6.0));
    let ldir = (dir + nrm * p[1]).normalize();
    let mid = af + dir * tm + nrm * p[0];
    let ln = Vector2::new(ldir.y, -ldir.x);
    // Offset variance across the line; the slope's variance in radians^2 (1 / (1 + e1^2)^2 ~ 1).
    Some(EdgeFit {
        n: ln,
        c: ln.dot(&mid.coords),
        mid,
        dir: ldir,
        rms: 0.0,
        dark: p[2],
        light: p[3],
        off_var: cov[(0, 0)],
        slope_var: cov[(1, 1)],
        blur: p[4],
        blur_var: if fixed_blur.is_some() { f64::INFINITY } else { cov[(4, 4)] },
    })
}

/// CDF and density at `x` of the sum of three centred uniform variables of widths `a`, `b`,
/// `c` (each at least 0.02): a pixel's footprint across an edge (two widths) blurred by a
/// box of width `c`. From the density of a sum of uniforms, `sum_S (-1)^|S| (x + A/2 -
/// sum_S a_i)_+^2 / (2 abc)` over the subsets `S`.
fn uniform3_cdf(x: f64, a: f64, b: f64, c: f64) -> (f64, f64, f64) {
    let c = c.max(0.02);
    let half = 0.5 * (a + b + c);
    if x <= -half {
        return (0.0, 0.0, 0.0);
    }
    if x >= half {
        return (1.0, 0.0, 0.0);
    }
    let y = x + half;
    let (mut cdf, mut pdf, mut dc) = (0.0, 0.0, 0.0);
    for mask in 0..8u32 {
        let mut shift = 0.0;
        if mask & 1 == 1 {
            shift += a;
        }
        if mask & 2 == 2 {
            shift += b;
        }
        let with_c = mask & 4 == 4;
        if with_c {
            shift += c;
        }
        let z = y - shift;
        if z > 0.0 {
            let sign = if mask.count_ones() % 2 == 0 { 1.0 } else { -1.0 };
            let z2 = z * z;
            cdf += sign * z2 * z;
            pdf += sign * z2;
            // dz/dc: +1/2 from the centring, -1 when c is in the shift.
            dc += sign * 3.0 * z2 * if with_c { -0.5 } else { 0.5 };
        }
    }
    let abc = a * b * c;
    let f = cdf / (6.0 * abc);
    ((f).clamp(0.0, 1.0), (pdf / (2.0 * abc)).max(0.0), dc / (6.0 * abc) - f / c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform3_cdf_matches_a_monte_carlo_free_reference_and_its_derivatives() {
        // Reference: the CDF of the sum of three uniforms by midpoint integration over the
        // first two (the third's CDF is a clamped ramp).
        let (a, b, c) = (0.8, 0.35, 0.2);
        let reference = |x: f64| {
            let n = 400;
            let mut s = 0.0;
            for i in 0..n {
                for j in 0..n {
                    let u = a * ((i as f64 + 0.5) / n as f64 - 0.5);
                    let v = b * ((j as f64 + 0.5) / n as f64 - 0.5);
                    s += ((x - u - v) / c + 0.5).clamp(0.0, 1.0);
                }
            }
            s / (n * n) as f64
        };
        for x in [-0.7, -0.6, -0.4, -0.2, -0.05, 0.0, 0.1, 0.3, 0.55, 0.69] {
            let (f, pdf, dc) = uniform3_cdf(x, a, b, c);
            assert!((f - reference(x)).abs() < 1e-4, "x {x}: {f} vs {}", reference(x));
            let h = 1e-6;
            let num_pdf = (uniform3_cdf(x + h, a, b, c).0 - uniform3_cdf(x - h, a, b, c).0) / (2.0 * h);
            assert!((pdf - num_pdf).abs() < 1e-5, "x {x}: pdf {pdf} vs {num_pdf}");
            let num_dc = (uniform3_cdf(x, a, b, c + h).0 - uniform3_cdf(x, a, b, c - h).0) / (2.0 * h);
            assert!((dc - num_dc).abs() < 1e-5, "x {x}: d/dc {dc} vs {num_dc}");
        }
        // Symmetric about 0, and 0 / 1 beyond the support.
        assert!((uniform3_cdf(0.0, a, b, c).0 - 0.5).abs() < 1e-12);
        assert_eq!(uniform3_cdf(-0.7, a, b, c).0, 0.0);
        assert_eq!(uniform3_cdf(0.7, a, b, c).0, 1.0);
    }

    #[test]
    fn a_bilinear_demosaic_green_channel_is_recognised_and_nothing_else() {
        // Photosites from a seeded xorshift (values 0..1); green at (x + y) odd (RGGB) or
        // even (GRBG); the other sites the mean of their four neighbours, as a bilinear
        // demosaic's green channel.
        let (w, h) = (200, 136);
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f32 / (1u64 << 53) as f32
        };
        let raw: Vec<f32> = (0..w * h).map(|_| rnd()).collect();
        for genuine in [0usize, 1] {
            let mut g = raw.clone();
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    if (x + y) % 2 != genuine {
                        let i = y * w + x;
                        g[i] = (raw[i - 1] + raw[i + 1] + raw[i - w] + raw[i + w]) / 4.0;
                    }
                }
            }
            let img = GrayImage::new(w, h, &g).unwrap();
            assert_eq!(demosaic_green_parity(&img), Some(genuine));
            // Scaled (any linear scale) it still is one.
            let scaled: Vec<f32> = g.iter().map(|v| 1000.0 * v).collect();
            assert_eq!(demosaic_green_parity(&GrayImage::new(w, h, &scaled).unwrap()), Some(genuine));
        }
        // Not one: the raw values themselves, a flat image, a smooth ramp (every pixel the
        // mean of its neighbours on both parities), a 3x3 box blur.
        let img = GrayImage::new(w, h, &raw).unwrap();
        assert_eq!(demosaic_green_parity(&img), None);
        let flat = vec![0.5f32; w * h];
        assert_eq!(demosaic_green_parity(&GrayImage::new(w, h, &flat).unwrap()), None);
        let ramp: Vec<f32> = (0..w * h).map(|i| (i % w) as f32 * 0.01 + (i / w) as f32 * 0.003).collect();
        assert_eq!(demosaic_green_parity(&GrayImage::new(w, h, &ramp).unwrap()), None);
        let mut boxed = raw.clone();
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let mut s = 0.0;
                for dy in 0..3 {
                    for dx in 0..3 {
                        s += raw[(y + dy - 1) * w + x + dx - 1];
                    }
                }
                boxed[y * w + x] = s / 9.0;
            }
        }
        assert_eq!(demosaic_green_parity(&GrayImage::new(w, h, &boxed).unwrap()), None);
    }
}
