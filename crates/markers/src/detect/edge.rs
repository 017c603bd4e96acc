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

/// The fitting frame's coordinates ([`to_fit`]) of the image points in a band along one
/// edge, interpolated bilinearly from exact ones on a grid in the edge's own coordinates
/// (`t` along `a -> b`, `s` along its normal): nodes at most [`EdgeBandMap::MAX_STEP_PX`]
/// apart along the edge and across a wide band, at least three across (a band along an edge
/// is at most 10 px wide: three). With the axes as `dir` and `nrm` it maps any rectangle of
/// the image (the module grid fit's patch around a marker). Undistortion is a Newton iteration per
/// point and was most of a windowed marker search at 12 MP when done for every band pixel
/// (`docs/benchmarks.md`); the lens moves a point smoothly (at most ~2e-5 px per px² of
/// curvature on the simulated rigs), so the interpolation is within ~2e-4 px of the exact
/// value, 1 % of the corners' 0.02 px floor. Without a camera it is the identity, exactly.
pub(super) struct EdgeBandMap<'a> {
    cam: Option<&'a CameraModel>,
    origin: Point2<f64>,
    dir: Vector2<f64>,
    nrm: Vector2<f64>,
    t0: f64,
    dt: f64,
    nt: usize,
    s0: f64,
    ds: f64,
    ns: usize,
    /// Exact fitting-frame points, `s` index major: `nodes[j * nt + i]` at `(t0 + i dt, s0 + j ds)`.
    nodes: Vec<Point2<f64>>,
}

impl<'a> EdgeBandMap<'a> {
    /// Largest node spacing along the edge, px.
    pub(super) const MAX_STEP_PX: f64 = 8.0;

    /// The band `t` in `[t_lo, t_hi]`, `s` in `[s_lo, s_hi]` of the edge from `a` along the
    /// unit direction `dir` (normal `nrm`), image coordinates. `None` if a node has no
    /// preimage (far outside the image).
    pub(super) fn new(
        cam: Option<&'a CameraModel>,
        a: Point2<f64>,
        dir: Vector2<f64>,
        nrm: Vector2<f64>,
        (t_lo, t_hi): (f64, f64),
        (s_lo, s_hi): (f64, f64),
    ) -> Option<Self> {
        let mut map = EdgeBandMap {
            cam,
            origin: a,
            dir,
            nrm,
            t0: t_lo,
            dt: 1.0,
            nt: 0,
            s0: s_lo,
            ds: 1.0,
            ns: 0,
            nodes: Vec::new(),
        };
        let Some(c) = cam else { return Some(map) };
        map.nt = (((t_hi - t_lo) / Self::MAX_STEP_PX).ceil() as usize).max(1) + 1;
        map.dt = ((t_hi - t_lo) / (map.nt - 1) as f64).max(1e-9);
        map.ns = (((s_hi - s_lo) / Self::MAX_STEP_PX).ceil() as usize + 1).max(3);
        map.ds = ((s_hi - s_lo) / (map.ns - 1) as f64).max(1e-9);
        map.nodes.reserve(map.ns * map.nt);
        for j in 0..map.ns {
            for i in 0..map.nt {
                let p = a + dir * (t_lo + i as f64 * map.dt) + nrm * (s_lo + j as f64 * map.ds);
                map.nodes.push(to_fit(Some(c), p)?);
            }
        }
        Some(map)
    }

    /// The fitting-frame point of image point `p` (exact outside the band).
    pub(super) fn to_fit(&self, p: Point2<f64>) -> Option<Point2<f64>> {
        if self.cam.is_none() {
            return Some(p);
        }
        let d = p - self.origin;
        let u = (self.dir.dot(&d) - self.t0) / self.dt;
        let v = (self.nrm.dot(&d) - self.s0) / self.ds;
        let eps = 1e-9;
        if !(u >= -eps && u <= (self.nt - 1) as f64 + eps && v >= -eps && v <= (self.ns - 1) as f64 + eps) {
            return to_fit(self.cam, p);
        }
        let i = (u as usize).min(self.nt - 2);
        let j = (v as usize).min(self.ns - 2);
        let (fu, fv) = (u - i as f64, v - j as f64);
        let n = |i: usize, j: usize| self.nodes[j * self.nt + i].coords;
        let q = n(i, j) * ((1.0 - fu) * (1.0 - fv))
            + n(i + 1, j) * (fu * (1.0 - fv))
            + n(i, j + 1) * ((1.0 - fu) * fv)
            + n(i + 1, j + 1) * (fu * fv);
        Some(Point2::from(q))
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
    // Per scanline only its base point and the profile's trapezoid integral are kept (no
    // profile vectors): the same sums in the same order as summing stored profiles.
    let mut profiles = Vec::with_capacity(nlines + 1);
    let (mut dsum, mut lsum, mut dn, mut ln) = (0.0, 0.0, 0.0, 0.0);
    let q = (ns / 4).max(1);
    for k in 0..=nlines {
        let t = margin + k as f64 * (len - 2.0 * margin) / nlines as f64;
        let base = a + dir * t;
        let (mut all, mut head, mut tail, mut first, mut last) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..ns {
            let p = base + nrm * (-ad + i as f64 * step);
            let v = img.bilinear(p.x, p.y);
            all += v;
            if i < q {
                head += v;
            }
            if i >= ns - q {
                tail += v;
            }
            if i == 0 {
                first = v;
            }
            last = v;
        }
        dsum += head;
        dn += q as f64;
        lsum += tail;
        ln += q as f64;
        // Trapezoid integral of the profile over [-ad, bl].
        profiles.push((base, step * (all - 0.5 * (first + last))));
    }
    let (dark, light) = (dsum / dn, lsum / ln);
    if !(light - dark > 0.0) {
        return None;
    }
    // Scanline points into the fitting frame: interpolated from exact undistortions every
    // few px along the edge (`EdgeBandMap`), not one Newton iteration per scanline.
    let band = EdgeBandMap::new(cam, a, dir, nrm, (margin, len - margin), (-ad, bl))?;
    let mut pts = Vec::with_capacity(profiles.len());
    for &(base, integ) in &profiles {
        // A step from `dark` to `light` at `e` has this integral over [-ad, bl].
        let e = (dark * ad + light * bl - integ) / (light - dark);
        if e < -ad || e > bl {
            continue;
        }
        if let Some(p) = band.to_fit(base + nrm * e) {
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

#[cfg(test)]
mod tests {
    use btfrig_core::camera::{CameraModel, Distortion, Vignetting};
    use nalgebra::{Point2, Vector2};

    use super::{to_fit, EdgeBandMap};

    /// The simulated rigs' lens (k1 = -0.08, k2 = 0.02, p1 = -p2 = 1e-4) at 1600 x 1200 and a
    /// stronger one (k1 = -0.3): the interpolated band agrees with the exact undistortion to
    /// 2e-4 px (resp. 2e-3) on edges in the image corner, every 0.37 px across the band.
    #[test]
    fn band_map_matches_the_exact_undistortion() {
        for (k1, tol) in [(-0.08, 2e-4), (-0.3, 2e-3)] {
            let d = Distortion { k1, k2: 0.02, k3: 0.0, p1: 1e-4, p2: -1e-4 };
            let cam = CameraModel::new(1600, 1200, 4800.0, 4800.0, 799.5, 599.5, d, Vignetting::default()).unwrap();
            let mut worst = 0.0f64;
            for (a, b) in
                [((20.0, 30.0), (190.0, 60.0)), ((1580.0, 1170.0), (1580.0, 900.0)), ((700.0, 600.0), (760.0, 640.0))]
            {
                let (a, b): (Point2<f64>, Point2<f64>) = (Point2::new(a.0, a.1), Point2::new(b.0, b.1));
                let len = (b - a).norm();
                let dir: Vector2<f64> = (b - a) / len;
                let nrm = Vector2::new(dir.y, -dir.x);
                let map = EdgeBandMap::new(Some(&cam), a, dir, nrm, (0.5, len - 0.5), (-4.0, 5.0)).unwrap();
                let mut t = 0.5;
                while t <= len - 0.5 {
                    let mut s = -4.0;
                    while s <= 5.0 {
                        let p = a + dir * t + nrm * s;
                        let e = (map.to_fit(p).unwrap() - to_fit(Some(&cam), p).unwrap()).norm();
                        worst = worst.max(e);
                        s += 0.37;
                    }
                    t += 0.37;
                }
                // Outside the band: exact.
                let far = a + nrm * 9.0;
                assert_eq!(map.to_fit(far), to_fit(Some(&cam), far));
            }
            assert!(worst < tol, "k1 {k1}: largest difference {worst} px");
            assert!(worst > 0.0, "the map interpolates (it is not the exact path)");
        }
        let p = Point2::new(3.25, 4.5);
        let id = EdgeBandMap::new(None, p, Vector2::x(), Vector2::y(), (0.0, 10.0), (-1.0, 1.0)).unwrap();
        assert_eq!(id.to_fit(p + Vector2::new(2.0, 0.5)), Some(p + Vector2::new(2.0, 0.5)));
    }
}
