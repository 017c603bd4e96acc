//! Step 4: sub-pixel edges from scanline profiles, straight lines through them, and the
//! corners where adjacent lines meet (with their covariance).

use btfrig_core::camera::CameraModel;
use nalgebra::{Point2, Point3, Vector2};

use super::GrayImage;

/// One edge's sub-pixel line in the (possibly undistorted) fitting frame.
pub(super) struct EdgeFit {
    /// Unit normal `n` and offset `c` of the line `n . p = c`.
    pub(super) n: Vector2<f64>,
    pub(super) c: f64,
    /// Centroid of the points and unit direction.
    pub(super) mid: Point2<f64>,
    pub(super) dir: Vector2<f64>,
    /// RMS residual of the edge points (scanline fits; 0 for model fits).
    pub(super) rms: f64,
    pub(super) dark: f64,
    pub(super) light: f64,
    /// Variance of the line's offset at `mid` and of its slope (px^2, rad^2).
    pub(super) off_var: f64,
    pub(super) slope_var: f64,
    /// Model fits only: the fitted blur width and its variance (infinite when it was fixed).
    pub(super) blur: f64,
    pub(super) blur_var: f64,
}

pub(super) fn to_fit(cam: Option<&CameraModel>, p: Point2<f64>) -> Option<Point2<f64>> {
    match cam {
        None => Some(p),
        Some(c) => {
            let r = c.try_pixel_ray(p)?;
            Some(Point2::new(c.fx * r.x / r.z + c.cx, c.fy * r.y / r.z + c.cy))
        }
    }
}

pub(super) fn from_fit(cam: Option<&CameraModel>, p: Point2<f64>) -> Option<Point2<f64>> {
    match cam {
        None => Some(p),
        Some(c) => c.project(&Point3::new((p.x - c.cx) / c.fx, (p.y - c.cy) / c.fy, 1.0)),
    }
}

/// Fits edge `a -> b` (marker dark on the right-hand side of the direction in screen
/// coordinates, i.e. the outward normal is `(dy, -dx)`). Each scanline's profile runs from
/// `ad` pixels inside (dark) to `bl` pixels outside (light).
pub(super) fn fit_edge(
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
pub(super) fn intersect(l1: &EdgeFit, l2: &EdgeFit) -> Option<(Point2<f64>, [[f64; 2]; 2])> {
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
