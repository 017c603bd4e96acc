//! The height field of a sample and ray queries against it.
//!
//! Heights are given at the corners of an `N x N` texel grid over the sample square
//! (`(N+1)^2` vertices, row-major, row 0 at the `+y` edge, metres above the plate plane
//! `z = 0`); each texel is a bilinear patch, so the surface is continuous and, with the
//! outer ring of vertices at 0, meets the plate without a step. Shading normals are
//! interpolated bilinearly from vertex normals (central differences), so highlights do not
//! show the patch facets.
//!
//! Ray queries ([`HeightField::first_hit`]) walk the ray's projection through the grid cell
//! by cell (a 2D DDA) and solve exactly, in each cell, where the ray meets the bilinear
//! patch: along the ray the patch height is a quadratic in `t`, so the first crossing is the
//! smallest root of a quadratic in the cell's `t` interval. The same query answers primary
//! rays (masking: the first surface point the camera ray meets) and shadow rays
//! (self-shadowing: is anything between a surface point and the lamp).

use nalgebra::Vector3;

/// Counters of a ray query, summed into the render statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MarchCount {
    /// Grid cells visited.
    pub cells: u64,
    /// Cells whose bilinear patch was intersected (the rest were rejected by their height bound).
    pub patch_tests: u64,
}

/// A height field over the centred sample square.
#[derive(Debug, Clone)]
pub struct HeightField {
    n: usize,
    half: f64,
    texel: f64,
    heights: Vec<f64>,
    normals: Vec<[f64; 3]>,
    cell_max: Vec<f64>,
    h_min: f64,
    h_max: f64,
    max_slope: f64,
}

impl HeightField {
    /// A height field of `n x n` texels over a square of side `side_m`, from `(n+1)^2` vertex
    /// heights (row 0 at `+y`).
    pub fn new(n: usize, side_m: f64, heights: Vec<f64>) -> HeightField {
        assert_eq!(heights.len(), (n + 1) * (n + 1), "height field: (n+1)^2 vertex heights");
        let texel = side_m / n as f64;
        let v = n + 1;
        let at = |i: usize, j: usize| heights[j * v + i];
        let mut normals = vec![[0.0, 0.0, 1.0]; v * v];
        for j in 0..v {
            for i in 0..v {
                let (il, ir) = (i.saturating_sub(1), (i + 1).min(n));
                let (ju, jd) = (j.saturating_sub(1), (j + 1).min(n));
                let gx = (at(ir, j) - at(il, j)) / ((ir - il) as f64 * texel);
                // Rows grow along -y: dh/dy = (upper row - lower row) / distance.
                let gy = (at(i, ju) - at(i, jd)) / ((jd - ju) as f64 * texel);
                let nn = Vector3::new(-gx, -gy, 1.0).normalize();
                normals[j * v + i] = [nn.x, nn.y, nn.z];
            }
        }
        let mut cell_max = vec![0.0; n * n];
        let mut max_slope: f64 = 0.0;
        for j in 0..n {
            for i in 0..n {
                let (h00, h10, h01, h11) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
                cell_max[j * n + i] = h00.max(h10).max(h01).max(h11);
                // The patch gradient is linear along each axis, so its extremes are the edge differences.
                let gx = (h10 - h00).abs().max((h11 - h01).abs());
                let gy = (h01 - h00).abs().max((h11 - h10).abs());
                max_slope = max_slope.max((gx * gx + gy * gy).sqrt() / texel);
            }
        }
        let h_min = heights.iter().copied().fold(0.0, f64::min);
        let h_max = heights.iter().copied().fold(0.0, f64::max);
        HeightField { n, half: side_m / 2.0, texel, heights, normals, cell_max, h_min, h_max, max_slope }
    }

    /// Texels per side.
    pub fn texels(&self) -> usize {
        self.n
    }

    /// Texel side, metres.
    pub fn texel_m(&self) -> f64 {
        self.texel
    }

    /// Lowest and highest height (the plate's 0 included), metres.
    pub fn range(&self) -> (f64, f64) {
        (self.h_min, self.h_max)
    }

    /// Upper bound of the surface slope `|grad h|` (plate included, which is flat).
    pub fn max_slope(&self) -> f64 {
        self.max_slope
    }

    /// True when every height is 0: the sample is the plane `z = 0`.
    pub fn is_flat(&self) -> bool {
        self.h_min == 0.0 && self.h_max == 0.0
    }

    /// Vertex heights, row-major, row 0 at `+y`.
    pub fn vertex_heights(&self) -> &[f64] {
        &self.heights
    }

    fn grid(&self, x: f64, y: f64) -> (usize, usize, f64, f64) {
        let gx = ((x + self.half) / self.texel).clamp(0.0, self.n as f64);
        let gy = ((self.half - y) / self.texel).clamp(0.0, self.n as f64);
        let i = (gx.floor() as usize).min(self.n - 1);
        let j = (gy.floor() as usize).min(self.n - 1);
        (i, j, gx - i as f64, gy - j as f64)
    }

    /// Surface height at `(x, y)` (clamped to the square), metres.
    pub fn height(&self, x: f64, y: f64) -> f64 {
        let (i, j, s, u) = self.grid(x, y);
        let v = self.n + 1;
        let h = &self.heights;
        let (h00, h10, h01, h11) = (h[j * v + i], h[j * v + i + 1], h[(j + 1) * v + i], h[(j + 1) * v + i + 1]);
        (h00 * (1.0 - s) + h10 * s) * (1.0 - u) + (h01 * (1.0 - s) + h11 * s) * u
    }

    /// Unit shading normal at `(x, y)`: bilinear blend of the vertex normals.
    pub fn normal(&self, x: f64, y: f64) -> Vector3<f64> {
        let (i, j, s, u) = self.grid(x, y);
        let v = self.n + 1;
        let nn = &self.normals;
        let w = [(1.0 - s) * (1.0 - u), s * (1.0 - u), (1.0 - s) * u, s * u];
        let idx = [j * v + i, j * v + i + 1, (j + 1) * v + i, (j + 1) * v + i + 1];
        let mut acc = Vector3::zeros();
        for k in 0..4 {
            let q = nn[idx[k]];
            acc += Vector3::new(q[0], q[1], q[2]) * w[k];
        }
        acc.normalize()
    }

    /// First `t` in `[t0, t1]` at which the ray `o + t d` (sample frame, metres) is on or
    /// below the surface inside the sample square, or `None`. Outside the square the caller
    /// handles the plate plane.
    ///
    /// `bounded` enables the height-range bounds: the ray is first clipped to the slab
    /// `h_min <= z <= h_max` (outside it the surface cannot be met), and a cell whose highest
    /// vertex lies below the ray over the whole cell is passed without solving its patch.
    /// Both only skip work whose answer is known to be "no crossing here".
    pub fn first_hit(
        &self,
        o: &Vector3<f64>,
        d: &Vector3<f64>,
        t0: f64,
        t1: f64,
        bounded: bool,
        count: &mut MarchCount,
    ) -> Option<f64> {
        let n = self.n as f64;
        // Grid coordinates: X along +x, Y along -y, one unit per texel.
        let (x0, y0) = ((o.x + self.half) / self.texel, (self.half - o.y) / self.texel);
        let (dx, dy) = (d.x / self.texel, -d.y / self.texel);
        let (mut ta, mut tb) = (t0, t1);
        clip(&mut ta, &mut tb, x0, dx, 0.0, n);
        clip(&mut ta, &mut tb, y0, dy, 0.0, n);
        if bounded {
            clip(&mut ta, &mut tb, o.z, d.z, self.h_min, self.h_max);
        }
        if !(ta <= tb) || !ta.is_finite() {
            return None;
        }
        let last = self.n as isize - 1;
        let mut i = ((x0 + dx * ta).floor() as isize).clamp(0, last);
        let mut j = ((y0 + dy * ta).floor() as isize).clamp(0, last);
        let (si, mut tnx, dtx) = axis_setup(i, x0, dx);
        let (sj, mut tny, dty) = axis_setup(j, y0, dy);
        let mut t = ta;
        loop {
            let t_exit = tnx.min(tny).min(tb);
            count.cells += 1;
            let idx = j as usize * self.n + i as usize;
            // The ray's z is linear over the cell: its lower end bounds it from below.
            let above = bounded && (o.z + d.z * t).min(o.z + d.z * t_exit) > self.cell_max[idx];
            if !above {
                count.patch_tests += 1;
                if let Some(tau) = self.cell_hit(i as usize, j as usize, x0, y0, dx, dy, o.z, d.z, t, t_exit) {
                    return Some(t + tau);
                }
            }
            if t_exit >= tb {
                return None;
            }
            if tnx < tny {
                i += si;
                t = tnx;
                tnx += dtx;
            } else {
                j += sj;
                t = tny;
                tny += dty;
            }
            if i < 0 || j < 0 || i > last || j > last {
                return None;
            }
        }
    }

    /// Within cell `(i, j)`, the first `tau` in `[0, t_out - t_in]` where the ray is on or
    /// below the patch.
    #[allow(clippy::too_many_arguments)]
    fn cell_hit(
        &self,
        i: usize,
        j: usize,
        x0: f64,
        y0: f64,
        dx: f64,
        dy: f64,
        oz: f64,
        dz: f64,
        t_in: f64,
        t_out: f64,
    ) -> Option<f64> {
        let v = self.n + 1;
        let h = &self.heights;
        let (h00, h10, h01, h11) = (h[j * v + i], h[j * v + i + 1], h[(j + 1) * v + i], h[(j + 1) * v + i + 1]);
        let (b, c, e) = (h10 - h00, h01 - h00, h00 - h10 - h01 + h11);
        let s = x0 + dx * t_in - i as f64;
        let u = y0 + dy * t_in - j as f64;
        let z = oz + dz * t_in;
        // Patch height along the ray: A + B tau + C tau^2; f = ray z - patch height.
        let a_ = h00 + b * s + c * u + e * s * u;
        let b_ = b * dx + c * dy + e * (s * dy + u * dx);
        let c_ = e * dx * dy;
        let f0 = z - a_;
        if f0 <= 0.0 {
            return Some(0.0);
        }
        let len = t_out - t_in;
        let (qa, qb, qc) = (-c_, dz - b_, f0);
        let mut best = f64::INFINITY;
        if qa == 0.0 {
            if qb < 0.0 {
                best = -qc / qb;
            }
        } else {
            let disc = qb * qb - 4.0 * qa * qc;
            if disc >= 0.0 {
                // Numerically stable pair of roots.
                let q = -0.5 * (qb + qb.signum() * disc.sqrt());
                for r in [q / qa, if q != 0.0 { qc / q } else { f64::INFINITY }] {
                    if r >= 0.0 && r < best {
                        best = r;
                    }
                }
            }
        }
        if best <= len {
            return Some(best);
        }
        // A sign change that rounding hid from the root formula still counts as a crossing.
        let f_end = qc + qb * len + qa * len * len;
        if f_end <= 0.0 {
            return Some(len);
        }
        None
    }
}

/// Clips `[ta, tb]` to where `p + t v` lies in `[lo, hi]`.
fn clip(ta: &mut f64, tb: &mut f64, p: f64, v: f64, lo: f64, hi: f64) {
    if v == 0.0 {
        if p < lo || p > hi {
            *ta = f64::INFINITY;
        }
        return;
    }
    let (a, b) = ((lo - p) / v, (hi - p) / v);
    let (a, b) = if a < b { (a, b) } else { (b, a) };
    *ta = ta.max(a);
    *tb = tb.min(b);
}

/// DDA set-up along one axis: step, `t` of the next cell boundary, `t` per cell.
fn axis_setup(i: isize, p: f64, v: f64) -> (isize, f64, f64) {
    if v > 0.0 {
        (1, ((i + 1) as f64 - p) / v, 1.0 / v)
    } else if v < 0.0 {
        (-1, (i as f64 - p) / v, -1.0 / v)
    } else {
        (0, f64::INFINITY, f64::INFINITY)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_field(n: usize, amp: f64, seed: u64) -> HeightField {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut h = vec![0.0; (n + 1) * (n + 1)];
        for j in 1..n {
            for i in 1..n {
                h[j * (n + 1) + i] = rng.gen_range(-amp..amp);
            }
        }
        HeightField::new(n, 0.01, h)
    }

    /// Brute force: march in tiny steps and find the first point below the surface.
    fn brute(hf: &HeightField, o: &Vector3<f64>, d: &Vector3<f64>, t1: f64) -> Option<f64> {
        let steps = 200_000;
        let mut prev = 0.0;
        for k in 0..=steps {
            let t = t1 * k as f64 / steps as f64;
            let p = o + d * t;
            if p.x.abs() <= 0.005 && p.y.abs() <= 0.005 && p.z <= hf.height(p.x, p.y) {
                return Some(0.5 * (t + prev));
            }
            prev = t;
        }
        None
    }

    #[test]
    fn dda_hits_agree_with_brute_force_marching_with_and_without_bounds() {
        let hf = random_field(16, 4e-4, 3);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut hits = 0;
        for _ in 0..200 {
            let target = Vector3::new(rng.gen_range(-0.005..0.005), rng.gen_range(-0.005..0.005), 0.0);
            let th: f64 = rng.gen_range(0.0f64..1.4);
            let ph: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let dir = Vector3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
            let o = target + dir * 0.02;
            let d = -dir;
            let mut c = MarchCount::default();
            let a = hf.first_hit(&o, &d, 0.0, 0.04, true, &mut c);
            let b = hf.first_hit(&o, &d, 0.0, 0.04, false, &mut c);
            let r = brute(&hf, &o, &d, 0.04);
            assert_eq!(a.is_some(), r.is_some());
            if let (Some(a), Some(r)) = (a, r) {
                hits += 1;
                assert!((a - r).abs() < 0.04 / 200_000.0 * 1.5, "dda {a} brute {r}");
                assert!((a - b.unwrap()).abs() <= 1e-15, "bounded {a} unbounded {b:?}");
                // The hit is on the surface.
                let p = o + d * a;
                assert!((p.z - hf.height(p.x, p.y)).abs() < 1e-12);
            }
        }
        assert!(hits > 150);
    }

    #[test]
    fn slope_bound_is_an_upper_bound() {
        let hf = random_field(12, 3e-4, 5);
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..5000 {
            let (x, y) = (rng.gen_range(-0.005..0.005), rng.gen_range(-0.005..0.005));
            let a: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let e = 1e-7;
            let g = (hf.height(x + e * a.cos(), y + e * a.sin()) - hf.height(x, y)) / e;
            assert!(g <= hf.max_slope() * (1.0 + 1e-6), "slope {g} > bound {}", hf.max_slope());
        }
    }
}
