//! The detector: threshold, regions, quads, sub-pixel edges, decoding. One file per step;
//! this one holds the results and the two entry points (region finding included).

mod candidate;
mod edge;
mod edge_model;
mod green;
mod image;
mod params;
mod quad;
mod threshold;

pub use image::GrayImage;
pub use params::{DetectError, DetectParams, GreenSites};

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
