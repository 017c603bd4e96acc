//! Step 5: each edge refined by fitting a blurred, area-sampled step to the pixels around it.

use btfrig_core::camera::CameraModel;
use nalgebra::{Point2, SMatrix, SVector, Vector2};

use super::edge::{to_fit, EdgeBandMap, EdgeFit};
use super::GrayImage;

/// Smallest blur of the edge model (pixels): below it an axis-parallel edge on a pixel
/// boundary leaves no sample on the model's slope (singular fit).
pub(super) const B_MIN: f64 = 0.1;

/// Gauss-Newton iterations of the edge model at most (it starts from the scanline edge and
/// usually converges in 3 to 6).
const MODEL_ITERATIONS: usize = 12;

/// Model-based refinement of edge `a -> b` (as in [`fit_edge`]: marker dark on the
/// right-hand side, outward normal `(dy, -dx)`): every sample pixel (of parity `parity`
/// when given) within `h` of the line and more than `margin` from its ends is fitted by a
/// blurred step `D + (L - D) (1 + tanh((s - e0 - e1 u) / w)) / 2` across the line (`s` the
/// signed distance, `u` the position along it from the samples' mean), by Gauss-Newton over
/// `(e0, e1, D, L, w)`. Any symmetric blur (pixel area, demosaic, optics) leaves the fitted
/// centre unbiased; using every pixel in the band, not scanlines, keeps the short
/// foreshortened edges' samples up to the corners.
pub(super) fn fit_edge_model(
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
    let x0 = xa as usize;
    let x1 = (xb.ceil().max(0.0) as usize).min(img.width - 1);
    let y0 = ya as usize;
    let y1 = (yb.ceil().max(0.0) as usize).min(img.height - 1);
    // The cheap test below keeps pixels with `t` in this range and `s` in this one.
    let band =
        EdgeBandMap::new(cam, a, dir_img, nrm_img, (margin - 1.0, len_img - margin + 1.0), (-hin - 1.0, hout + 1.0))?;
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
            let pf = band.to_fit(px)?;
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
pub(super) fn uniform3_cdf(x: f64, a: f64, b: f64, c: f64) -> (f64, f64, f64) {
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
}
