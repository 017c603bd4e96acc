//! The detector: threshold, regions, quads, sub-pixel edges, decoding. One file per step;
//! this one holds the results and the two entry points (region finding included).

mod candidate;
mod edge;
mod edge_model;
mod green;
mod grid;
mod image;
mod params;
mod quad;
mod threshold;

pub use image::GrayImage;
pub use params::{DetectError, DetectParams, GreenSites};
pub use quad::module_across;

use nalgebra::Point2;

use crate::dictionary::Dictionary;
use candidate::candidate;
use green::demosaic_green_parity;
use threshold::threshold;

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

/// A rectangle of pixels to search: columns `x0..x1`, rows `y0..y1` (ends exclusive).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// One past the last column.
    pub x1: usize,
    /// One past the last row.
    pub y1: usize,
}

impl Window {
    /// The window `x0..x1` x `y0..y1`.
    pub fn new(x0: usize, y0: usize, x1: usize, y1: usize) -> Self {
        Window { x0, y0, x1, y1 }
    }

    /// The whole of `image`.
    pub fn all(image: &GrayImage) -> Self {
        Window { x0: 0, y0: 0, x1: image.width, y1: image.height }
    }

    /// Pixels in the window.
    pub fn area(&self) -> usize {
        self.x1.saturating_sub(self.x0) * self.y1.saturating_sub(self.y0)
    }

    /// The window cut to an image of `width` x `height` (empty if it lies outside).
    pub fn clipped(&self, width: usize, height: usize) -> Self {
        let (x1, y1) = (self.x1.min(width), self.y1.min(height));
        Window { x0: self.x0.min(x1), y0: self.y0.min(y1), x1, y1 }
    }

    /// The smallest window holding both.
    pub fn union(&self, other: &Window) -> Self {
        Window {
            x0: self.x0.min(other.x0),
            y0: self.y0.min(other.y0),
            x1: self.x1.max(other.x1),
            y1: self.y1.max(other.y1),
        }
    }

    /// Whether the point `(x, y)` (pixel coordinates, integer = centre) lies inside.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x0 as f64 && y >= self.y0 as f64 && x <= self.x1 as f64 - 1.0 && y <= self.y1 as f64 - 1.0
    }
}

/// What a search of windows found and did.
#[derive(Debug, Clone, PartialEq)]
pub struct WindowSearch {
    /// The markers, as [`detect`] reports them.
    pub detections: Vec<Detection>,
    /// Pixels thresholded and scanned (overlaps counted twice).
    pub pixels: usize,
    /// Dark regions dropped because they reached a window's side inside the image: something
    /// there continues beyond the window, so the window cannot tell whether it is a marker.
    pub cut_by_window: usize,
}

/// Finds the markers of `dict` in `image`. Markers touching the border (within
/// [`DetectParams::border_margin_px`]), regions that are not clean quads, and quads whose
/// border is not black or whose code is farther than [`DetectParams::max_hamming`] from
/// every code are rejected. Each id is reported at most once (the best fit wins).
pub fn detect(image: &GrayImage, dict: &Dictionary, params: &DetectParams) -> Result<Vec<Detection>, DetectError> {
    params.validate(image)?;
    let all = Window::all(image);
    let parity = match params.green_sites {
        GreenSites::Auto => demosaic_green_parity(image, &[all], 8),
        g => fixed_parity(g),
    };
    let mut out = Vec::new();
    for d in search_window(image, dict, params, parity, all).0 {
        keep_best(&mut out, d);
    }
    out.sort_by_key(|d| d.id);
    Ok(out)
}

/// Finds the markers of `dict` inside `windows` only (each clipped to the image), the windows
/// searched in parallel. A marker region lying wholly inside a window, clear of the window's
/// sides, is found exactly as [`detect`] finds it on the whole image: the threshold's local
/// mean reads the image beyond the window, and the corner fits read the image, not the
/// window. A region reaching a window's side inside the image is dropped and counted
/// ([`WindowSearch::cut_by_window`]): the caller's windows must hold each marker with a margin.
/// With [`GreenSites::Auto`] the demosaic is recognised from the windows' pixels.
pub fn detect_in_windows(
    image: &GrayImage,
    dict: &Dictionary,
    params: &DetectParams,
    windows: &[Window],
) -> Result<WindowSearch, DetectError> {
    use rayon::prelude::*;
    params.validate(image)?;
    let windows: Vec<Window> =
        windows.iter().map(|w| w.clipped(image.width, image.height)).filter(|w| w.area() > 0).collect();
    let parity = match params.green_sites {
        // Every second row of the windows: a window around a marker holds a few thousand
        // non-flat pixels, the recogniser needs 1000.
        GreenSites::Auto => demosaic_green_parity(image, &windows, 2),
        g => fixed_parity(g),
    };
    let found: Vec<(Vec<Detection>, usize)> =
        windows.par_iter().map(|&win| search_window(image, dict, params, parity, win)).collect();
    let mut out = Vec::new();
    let mut cut_by_window = 0;
    for (dets, cut) in found {
        cut_by_window += cut;
        for d in dets {
            keep_best(&mut out, d);
        }
    }
    out.sort_by_key(|d| d.id);
    Ok(WindowSearch { detections: out, pixels: windows.iter().map(Window::area).sum(), cut_by_window })
}

fn fixed_parity(g: GreenSites) -> Option<usize> {
    match g {
        GreenSites::Even => Some(0),
        GreenSites::Odd => Some(1),
        GreenSites::All | GreenSites::Auto => None,
    }
}

/// Adds `d` to `out` unless a better fit of the same id is there.
fn keep_best(out: &mut Vec<Detection>, d: Detection) {
    match out.iter_mut().find(|o| o.id == d.id) {
        Some(o) => {
            if score(&d) < score(o) {
                *o = d;
            }
        }
        None => out.push(d),
    }
}

/// Steps 1 to 6 inside `win`: the detections (an id may repeat) and the number of regions
/// dropped for reaching a side of `win` that is not the image's border.
fn search_window(
    image: &GrayImage,
    dict: &Dictionary,
    params: &DetectParams,
    parity: Option<usize>,
    win: Window,
) -> (Vec<Detection>, usize) {
    let (w, h) = (image.width, image.height);
    let max_side = params.max_side_frac * w.min(h) as f64;
    let bin = params.region_bin;
    let mut out: Vec<Detection> = Vec::new();
    // A region in the searched image's pixels (`bin` full pixels a side), bounding box
    // `[x0, x1] x [y0, y1]` inclusive, in the full image's pixels.
    let mut each_region = |pixels: &[(u32, u32)], [x0, y0, x1, y1]: [usize; 4]| {
        let (bw, bh) = ((x1 - x0 + 1) as f64, (y1 - y0 + 1) as f64);
        if bw.max(bh) < params.min_side_px || bw.max(bh) > max_side * 1.5 || bw.min(bh) < 3.0 {
            return;
        }
        let m = params.border_margin_px;
        if x0 < m || y0 < m || x1 + m >= w || y1 + m >= h {
            return;
        }
        if let Some(d) = candidate(image, dict, params, parity, pixels, bin) {
            out.push(d);
        }
    };
    let cut = if bin == 1 {
        let dark = threshold(image, params, win);
        dark_regions(&dark, win, (w, h), (0, 0), |pixels, b| each_region(pixels, b))
    } else {
        // The binned image of the window grown by the threshold's half window: every box
        // the threshold reads inside the window (clipped where the image ends, as in full
        // resolution), so the sub-image's sides are the binned image's only where the
        // image's are.
        let (bw, bh) = (w / bin, h / bin);
        let bp =
            DetectParams { threshold_window_px: ((params.threshold_window_px / bin) | 1).max(3), ..params.clone() };
        let r = bp.threshold_window_px / 2;
        let bwin = Window::new(win.x0 / bin, win.y0 / bin, win.x1.div_ceil(bin), win.y1.div_ceil(bin)).clipped(bw, bh);
        let (sx0, sy0) = (bwin.x0.saturating_sub(r), bwin.y0.saturating_sub(r));
        let (sx1, sy1) = ((bwin.x1 + r).min(bw), (bwin.y1 + r).min(bh));
        let sw = sx1 - sx0;
        let norm = 1.0 / (bin * bin) as f32;
        let mut sub = vec![0.0f32; sw * (sy1 - sy0)];
        for (j, row) in sub.chunks_exact_mut(sw).enumerate() {
            for dy in 0..bin {
                let line = &image.data[((sy0 + j) * bin + dy) * w + sx0 * bin..][..sw * bin];
                for (o, px) in row.iter_mut().zip(line.chunks_exact(bin)) {
                    *o += px.iter().sum::<f32>();
                }
            }
            row.iter_mut().for_each(|v| *v *= norm);
        }
        let Ok(sub_image) = GrayImage::new(sw, sy1 - sy0, &sub) else { return (out, 0) };
        let swin = Window::new(bwin.x0 - sx0, bwin.y0 - sy0, bwin.x1 - sx0, bwin.y1 - sy0);
        if swin.area() == 0 {
            return (out, 0);
        }
        let dark = threshold(&sub_image, &bp, swin);
        dark_regions(&dark, swin, (sw, sy1 - sy0), (sx0, sy0), |pixels, [x0, y0, x1, y1]| {
            each_region(pixels, [x0 * bin, y0 * bin, x1 * bin + bin - 1, y1 * bin + bin - 1])
        })
    };
    (out, cut)
}

/// Step 2: the 8-connected regions of `dark` (the mask of `win` in an image of `size`), each
/// given to `each` as its pixels (image coordinates plus `origin`) and bounding box (the same
/// coordinates, inclusive). Returns the number of regions dropped for reaching a side of
/// `win` that is not the image's: they may continue outside.
fn dark_regions(
    dark: &[bool],
    win: Window,
    (w, h): (usize, usize),
    origin: (usize, usize),
    mut each: impl FnMut(&[(u32, u32)], [usize; 4]),
) -> usize {
    let (ww, wh) = (win.x1 - win.x0, win.y1 - win.y0);
    // Dark pixels not yet visited, in the window framed by one row and column of zeros: the
    // flood fill's neighbours then need no bounds test, and a pixel's position travels with
    // it on the stack (no division of an index per pixel).
    let pw = ww + 2;
    let mut open = vec![0u8; pw * (wh + 2)];
    for y in 0..wh {
        let row = &mut open[(y + 1) * pw + 1..(y + 1) * pw + 1 + ww];
        for (o, &d) in row.iter_mut().zip(&dark[y * ww..(y + 1) * ww]) {
            *o = u8::from(d);
        }
    }
    let (ox, oy) = (win.x0 + origin.0, win.y0 + origin.1);
    let mut stack: Vec<(u32, u32)> = Vec::new();
    let mut pixels: Vec<(u32, u32)> = Vec::new();
    let mut cut = 0;
    for (sy, sx) in (0..wh).flat_map(|y| (0..ww).map(move |x| (y, x))) {
        if open[(sy + 1) * pw + sx + 1] == 0 {
            continue;
        }
        // Flood fill (8-connected) of one dark region, in window coordinates.
        pixels.clear();
        stack.push((sx as u32, sy as u32));
        open[(sy + 1) * pw + sx + 1] = 0;
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        while let Some((x, y)) = stack.pop() {
            let (x, y) = (x as usize, y as usize);
            pixels.push(((x + ox) as u32, (y + oy) as u32));
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
            // Padded coordinates of the 3 x 3 neighbourhood: rows y .. y + 2, columns x .. x + 2.
            for ny in y..y + 3 {
                let row = ny * pw;
                for nx in x..x + 3 {
                    if open[row + nx] != 0 {
                        open[row + nx] = 0;
                        stack.push(((nx - 1) as u32, (ny - 1) as u32));
                    }
                }
            }
        }
        // A region at a side of the window that is not the image's may continue outside.
        if (x0 == 0 && win.x0 > 0)
            || (y0 == 0 && win.y0 > 0)
            || (x1 + 1 == ww && win.x1 < w)
            || (y1 + 1 == wh && win.y1 < h)
        {
            cut += 1;
            continue;
        }
        each(&pixels, [x0 + ox, y0 + oy, x1 + ox, y1 + oy]);
    }
    cut
}

/// Finds the markers in a raw frame: the edges are fitted on its green photosites (on every
/// photosite of a frame without mosaic), the rest runs on the green channel interpolated as
/// a bilinear demosaic does (the mean of the 3 x 3 neighbourhood's green sites), values
/// `(dn - black) / (white - black)`. Same results as [`detect`] on the green channel of
/// `btfrig_imaging::demosaic`'s bilinear demosaic with `green_sites` set by the pattern; it does not
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
