//! Step 5b: the whole module grid of a marker fitted at once, for markers whose modules are
//! narrow across a side (grazing views).
//!
//! There the four outer edges carry little: a border module 2-4 px across leaves the edge
//! model one or two rows of dark samples, and on a green-only mosaic an edge along the pixel
//! diagonal is sampled in rows 1.4 px apart. Every boundary between a black and a white
//! module inside the marker is an edge of the same grid, as sharp as the outer ones: fitting
//! the four corners to all of them (the decoded bits say where they are) uses about twice
//! the edge length of the border alone.

use btfrig_core::camera::CameraModel;
use btfrig_core::homography::{map, square_to_quad};
use nalgebra::{Matrix3, Point2, SMatrix, SVector, Vector2};

use super::edge::{from_fit, to_fit, EdgeBandMap};
use super::edge_model::uniform3_cdf;
use super::GrayImage;

/// Parameters: the 4 corners in the fitting frame (x, y each), dark and light levels, and a
/// planar shading gradient (per px, x and y).
const P: usize = 12;
type Mat = SMatrix<f64, P, P>;
type Vct = SVector<f64, P>;

/// Levenberg-Marquardt iterations at most (from the edge model's corners it converges in 4 to 7
/// on the 75-80 degree frames).
const ITERATIONS: usize = 15;

/// Extra reach (px) beyond a pixel's footprint and the blur within which a boundary counts as
/// touching the pixel: the corners move by less than this during the fit.
const REACH_MARGIN_PX: f64 = 0.25;

/// A line `n . p = c` (unit `n`) of the grid in the fitting frame, `n` pointing towards
/// increasing module coordinate.
#[derive(Clone, Copy)]
struct Line {
    n: Vector2<f64>,
    c: f64,
}

/// The grid's `2 (modules + 1)` lines for corners `qf` (module square corner `k` at `qf[k]`):
/// rows `y = 0..=m` first, then columns `x = 0..=m`.
fn grid_lines(qf: &[Point2<f64>; 4], m: usize) -> Option<Vec<Line>> {
    let mf = m as f64;
    let h = square_to_quad(mf, qf)?;
    let mut lines = Vec::with_capacity(2 * (m + 1));
    for across in [false, true] {
        for k in 0..=m {
            let kf = k as f64;
            let pt = |u: f64, w: f64| if across { map(&h, &Point2::new(w, u)) } else { map(&h, &Point2::new(u, w)) };
            let (a, b) = (pt(0.0, kf)?, pt(mf, kf)?);
            let toward = pt(0.5 * mf, kf + 0.5)? - pt(0.5 * mf, kf)?;
            let d = (b - a).try_normalize(1e-12)?;
            let mut n = Vector2::new(d.y, -d.x);
            if n.dot(&toward) < 0.0 {
                n = -n;
            }
            lines.push(Line { n, c: n.dot(&a.coords) });
        }
    }
    Some(lines)
}

/// What a sample sees: one module's level, or one boundary between a dark and a light module
/// (`sign` +1 when the light module lies towards increasing module coordinate).
#[derive(Clone, Copy)]
enum Kind {
    Level { light: bool },
    Step { line: usize, sign: f64 },
}

/// The corners of a marker and their covariances (pixels, pixels²), from its whole grid.
pub(super) struct GridFit {
    pub(super) corners: [Point2<f64>; 4],
    pub(super) cov: [[[f64; 2]; 2]; 4],
}

/// What the grid fit starts from: a decoded marker of `modules x modules` modules (border
/// included) with corners `corners` (image pixels, module square corner `k` at `corners[k]`),
/// module `(row r, column c)` light when `light[r * modules + c]`, its (dark, light) levels
/// and its blur (the edge model's).
pub(super) struct GridStart<'a> {
    pub(super) corners: [Point2<f64>; 4],
    pub(super) light: &'a [bool],
    pub(super) modules: usize,
    pub(super) levels: (f64, f64),
    pub(super) blur: f64,
}

/// Derivatives of one line's `(n, c)` in the 8 corner coordinates.
type LineDerivs = [(Vector2<f64>, f64); 8];

/// Fits the corners of the marker `start` to the pixels of the marker and a few pixels
/// around it (of parity `parity` when given): each pixel is either one module's level or a
/// blurred step across one boundary between a dark and a light module (the edge model's
/// pixel footprint and the marker's blur); pixels that two boundaries reach are left out.
/// `None` when the fit fails or has too few boundary pixels.
pub(super) fn fit_grid(
    img: &GrayImage,
    parity: Option<usize>,
    cam: Option<&CameraModel>,
    start: &GridStart,
) -> Option<GridFit> {
    let GridStart { corners: q, light, modules: m, levels, blur } = *start;
    let mut qf = [Point2::origin(); 4];
    for k in 0..4 {
        qf[k] = to_fit(cam, q[k])?;
    }
    let lines = grid_lines(&qf, m)?;
    let mf = m as f64;
    let to_module: Matrix3<f64> = square_to_quad(mf, &qf)?.try_inverse()?;
    // The marker's bounding box grown by 4 px: beyond the border, a few pixels of the quiet
    // zone give its level and the outer steps (a whole module would be 14 px along the long
    // sides at 80 degrees, for nothing more).
    let grow = 4.0;
    let (mut xa, mut ya, mut xb, mut yb) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in &q {
        xa = xa.min(p.x - grow);
        ya = ya.min(p.y - grow);
        xb = xb.max(p.x + grow);
        yb = yb.max(p.y + grow);
    }
    let (x0, y0) = (xa.max(0.0) as usize, ya.max(0.0) as usize);
    let (x1, y1) = ((xb.max(0.0) as usize).min(img.width - 1), (yb.max(0.0) as usize).min(img.height - 1));
    // The fitting frame over the patch, bilinear between exact nodes at most 8 px apart.
    let (xf, yf) = ((x1 - x0) as f64, (y1 - y0) as f64);
    let patch =
        EdgeBandMap::new(cam, Point2::new(x0 as f64, y0 as f64), Vector2::x(), Vector2::y(), (0.0, xf), (0.0, yf))?;
    let cell = |r: i64, c: i64| {
        if r < 0 || c < 0 || r >= m as i64 || c >= m as i64 {
            true // the quiet zone around the marker
        } else {
            light[r as usize * m + c as usize]
        }
    };
    let reach = |l: &Line| 0.5 * (l.n.x.abs() + l.n.y.abs()) + 0.5 * blur + REACH_MARGIN_PX;
    // Samples: fitting-frame point, value, kind.
    let mut samples: Vec<(Point2<f64>, f64, Kind)> = Vec::new();
    let mut steps = 0usize;
    for y in y0..=y1 {
        for x in x0..=x1 {
            if parity.is_some_and(|p| (x + y) % 2 != p) {
                continue;
            }
            let Some(pf) = patch.to_fit(Point2::new(x as f64, y as f64)) else { continue };
            let Some(mm) = map(&to_module, &pf) else { continue };
            if !(mm.x > -1.0 && mm.x < mf + 1.0 && mm.y > -1.0 && mm.y < mf + 1.0) {
                continue;
            }
            let (cx, cy) = (mm.x.floor() as i64, mm.y.floor() as i64);
            let near = |idx: usize| {
                let l = &lines[idx];
                (l.n.dot(&pf.coords) - l.c).abs() < reach(l)
            };
            // The boundaries of this pixel's cell that reach it: at most one row line and one
            // column line (modules narrower than two reaches are left out).
            let lines_near = |first: usize, own: i64| -> Option<Option<i64>> {
                let mut found = None;
                for k in [own, own + 1] {
                    if (0..=m as i64).contains(&k) && near(first + k as usize) {
                        if found.is_some() {
                            return None;
                        }
                        found = Some(k);
                    }
                }
                Some(found)
            };
            let (Some(row), Some(col)) = (lines_near(0, cy), lines_near(m + 1, cx)) else { continue };
            let step = |line: usize, before: bool, after: bool| {
                if before == after {
                    Kind::Level { light: before }
                } else {
                    Kind::Step { line, sign: if after { 1.0 } else { -1.0 } }
                }
            };
            let kind = match (row, col) {
                (None, None) => Kind::Level { light: cell(cy, cx) },
                (Some(ky), None) => step(ky as usize, cell(ky - 1, cx), cell(ky, cx)),
                (None, Some(kx)) => step(m + 1 + kx as usize, cell(cy, kx - 1), cell(cy, kx)),
                // At a junction: one step only if the four modules around it make one straight
                // boundary (or none).
                (Some(ky), Some(kx)) => {
                    let (a, b, c, d) = (cell(ky - 1, kx - 1), cell(ky - 1, kx), cell(ky, kx - 1), cell(ky, kx));
                    if a == c && b == d {
                        step(m + 1 + kx as usize, a, b)
                    } else if a == b && c == d {
                        step(ky as usize, a, c)
                    } else {
                        continue;
                    }
                }
            };
            if matches!(kind, Kind::Step { .. }) {
                steps += 1;
            }
            samples.push((pf, f64::from(img.at(x, y)), kind));
        }
    }
    if steps < 40 {
        return None;
    }
    let nsamp = samples.len() as f64;
    let centre = samples.iter().fold(Vector2::zeros(), |a, s| a + s.0.coords) / nsamp;

    // Line parameters and their derivatives in the 8 corner coordinates (central differences:
    // the lines are smooth functions of the corners).
    let derivs = |qf: &[Point2<f64>; 4]| -> Option<(Vec<Line>, Vec<LineDerivs>)> {
        let base = grid_lines(qf, m)?;
        let mut d = vec![[(Vector2::zeros(), 0.0); 8]; base.len()];
        const H: f64 = 1e-3;
        for j in 0..8 {
            let mut plus = *qf;
            let mut minus = *qf;
            plus[j / 2][j % 2] += H;
            minus[j / 2][j % 2] -= H;
            let (lp, lm) = (grid_lines(&plus, m)?, grid_lines(&minus, m)?);
            for (i, (a, b)) in lp.iter().zip(&lm).enumerate() {
                d[i][j] = ((a.n - b.n) / (2.0 * H), (a.c - b.c) / (2.0 * H));
            }
        }
        Some((base, d))
    };
    let unpack = |th: &Vct| std::array::from_fn::<Point2<f64>, 4, _>(|k| Point2::new(th[2 * k], th[2 * k + 1]));
    // The sum of squared residuals at `th` (corners already in `lines`); with `normal`, the
    // lines' derivatives and the normal equations to accumulate (upper triangle only).
    let eval = |th: &Vct, lines: &[Line], mut normal: Option<(&[LineDerivs], &mut Mat, &mut Vct)>| -> f64 {
        let (dark, lite, gx, gy) = (th[8], th[9], th[10], th[11]);
        let mut sse = 0.0;
        for &(pf, v, kind) in &samples {
            let (ux, uy) = (pf.x - centre.x, pf.y - centre.y);
            let sh = 1.0 + gx * ux + gy * uy;
            let mut j = Vct::zeros();
            let v0 = match kind {
                Kind::Level { light } => {
                    j[if light { 9 } else { 8 }] = sh;
                    if light {
                        lite
                    } else {
                        dark
                    }
                }
                Kind::Step { line, sign } => {
                    let l = &lines[line];
                    let s = l.n.dot(&pf.coords) - l.c;
                    let (cdf, pdf, _) = uniform3_cdf(sign * s, l.n.x.abs().max(0.02), l.n.y.abs().max(0.02), blur);
                    if let Some((d, _, _)) = &normal {
                        let g = (lite - dark) * pdf * sign * sh;
                        for (k, &(dn, dc)) in d[line].iter().enumerate() {
                            j[k] = g * (dn.dot(&pf.coords) - dc);
                        }
                        j[8] = (1.0 - cdf) * sh;
                        j[9] = cdf * sh;
                    }
                    dark + (lite - dark) * cdf
                }
            };
            let r = v - v0 * sh;
            sse += r * r;
            if let Some((_, jtj, jtr)) = &mut normal {
                j[10] = v0 * ux;
                j[11] = v0 * uy;
                // A level sample has 3 non-zero derivatives of 12.
                for a in 0..P {
                    if j[a] != 0.0 {
                        for b in a..P {
                            jtj[(a, b)] += j[a] * j[b];
                        }
                    }
                }
                **jtr += j * r;
            }
        }
        sse
    };
    // The residual sum and the normal equations at `th`.
    let normal_equations = |th: &Vct| -> Option<(f64, Mat, Vct)> {
        let (lines, d) = derivs(&unpack(th))?;
        let (mut jtj, mut jtr) = (Mat::zeros(), Vct::zeros());
        let sse = eval(th, &lines, Some((&d, &mut jtj, &mut jtr)));
        jtj.fill_lower_triangle_with_upper_triangle();
        Some((sse, jtj, jtr))
    };
    let mut th = Vct::from_fn(|i, _| if i < 8 { qf[i / 2][i % 2] } else { [levels.0, levels.1, 0.0, 0.0][i - 8] });
    let (mut cur, mut jtj, mut jtr) = normal_equations(&th)?;
    let mut lambda = 1e-3;
    for _ in 0..ITERATIONS {
        let mut improved = false;
        for _ in 0..8 {
            let mut a = jtj;
            for i in 0..P {
                a[(i, i)] *= 1.0 + lambda;
                a[(i, i)] += 1e-12;
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let cand = th + step;
            let cq = unpack(&cand);
            let Some(cl) = grid_lines(&cq, m) else {
                lambda *= 10.0;
                continue;
            };
            if eval(&cand, &cl, None) <= cur && cand[9] > cand[8] {
                let small = (0..8).all(|i| step[i].abs() < 1e-5);
                th = cand;
                lambda = (lambda * 0.3).max(1e-9);
                (cur, jtj, jtr) = normal_equations(&th)?;
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let inv = jtj.try_inverse()?;
    let var = cur / (nsamp - P as f64).max(1.0);
    let fitted = unpack(&th);
    let mut corners = [Point2::origin(); 4];
    let mut cov = [[[0.0; 2]; 2]; 4];
    for k in 0..4 {
        corners[k] = from_fit(cam, fitted[k])?;
        let (i, j) = (2 * k, 2 * k + 1);
        cov[k] = [[inv[(i, i)] * var, inv[(i, j)] * var], [inv[(j, i)] * var, inv[(j, j)] * var]];
        let det = cov[k][0][0] * cov[k][1][1] - cov[k][0][1] * cov[k][1][0];
        if !(cov[k][0][0] > 0.0 && cov[k][1][1] > 0.0 && det > 0.0 && det.is_finite()) {
            return None;
        }
    }
    Some(GridFit { corners, cov })
}
