//! Steps 3 to 6 for one dark region: quad check, corner refinement, unwarp and decoding.

use btfrig_core::homography::{dlt, map};
use nalgebra::Point2;

use super::edge::{fit_edge, from_fit, intersect, EdgeFit};
use super::edge_model::{fit_edge_model, B_MIN};
use super::grid::{fit_grid, GridStart};
use super::quad::{cross, initial_quad, module_across, pixel_centre};
use super::{DetectParams, Detection, GrayImage, Quality};
use crate::dictionary::Dictionary;

pub(super) fn candidate(
    img: &GrayImage,
    dict: &Dictionary,
    p: &DetectParams,
    parity: Option<usize>,
    pixels: &[(u32, u32)],
    bin: usize,
) -> Option<Detection> {
    let mut q = initial_quad(pixels, bin)?;
    let sides: Vec<f64> = (0..4).map(|i| (q[(i + 1) % 4] - q[i]).norm()).collect();
    let (smin, smax) = sides.iter().fold((f64::MAX, 0.0f64), |a, &s| (a.0.min(s), a.1.max(s)));
    if smax < p.min_side_px || smin < 0.25 * p.min_side_px || smax > p.max_side_frac * img.width.min(img.height) as f64
    {
        return None;
    }
    // Every region pixel inside the quad (with a tolerance): rejects blobs that are not
    // quads and markers merged with dark neighbours.
    let tol = 1.5 * bin as f64 + 0.04 * smax;
    let outside = pixels
        .iter()
        .filter(|px| {
            let pt = pixel_centre(px, bin);
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
    // The marker's blur, when the edge model ran on all four edges.
    let mut marker_blur = None;
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
            let blur = if sw > 0.0 {
                (swb / sw).max(B_MIN)
            } else {
                (mf.iter().map(|f| f.blur).sum::<f64>() / 4.0).max(B_MIN)
            };
            if sw > 0.0 {
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
            marker_blur = Some(blur);
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
    // Module coordinates (the unit square scaled by the module count) to the image quad.
    let square = [(0.0, 0.0), (modules, 0.0), (modules, modules), (0.0, modules)].map(|(x, y)| Point2::new(x, y));
    let hm = dlt(&square, &q)?;
    let n = dict.size + 2;
    let mut white = vec![false; n * n];
    for r in 0..n {
        for c in 0..n {
            let mut s = 0.0;
            for a in [-0.25, 0.0, 0.25] {
                for b in [-0.25, 0.0, 0.25] {
                    let pt = map(&hm, &Point2::new(c as f64 + 0.5 + a, r as f64 + 0.5 + b))?;
                    s += img.bilinear(pt.x, pt.y);
                }
            }
            white[r * n + c] = s / 9.0 > thr;
        }
    }
    let on_border = |i: usize| i / n == 0 || i % n == 0 || i / n == n - 1 || i % n == n - 1;
    let border_errors = (0..n * n).filter(|&i| white[i] && on_border(i)).count();
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
    // Narrow modules: the whole grid (the decoded bits, exact when nothing was corrected).
    let narrowest = (0..4).map(|i| module_across(&q, i, modules)).fold(f64::INFINITY, f64::min);
    if let (Some(blur), 0) = (marker_blur, ham) {
        if narrowest < p.module_grid_below_px {
            // The border is black whatever it read as (`max_border_errors`).
            let lit: Vec<bool> = (0..n * n).map(|i| white[i] && !on_border(i)).collect();
            let start = GridStart { corners: q, light: &lit, modules: n, levels: (dark, light), blur };
            if let Some(g) = fit_grid(img, parity, cam, &start) {
                if (0..4).all(|j| (g.corners[j] - q[j]).norm() < 0.5) {
                    let f2 = p.corner_sigma_floor_px * p.corner_sigma_floor_px;
                    q = g.corners;
                    cov = g.cov.map(|c| [[c[0][0] + f2, c[0][1]], [c[1][0], c[1][1] + f2]]);
                }
            }
        }
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
