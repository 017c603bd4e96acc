//! Delaunay triangulation of a sampling in the azimuthal-equidistant projection
//! `p = (theta cos phi, theta sin phi)`, and barycentric location in it.
//!
//! Why this projection: it is continuous at the pole (where `phi` is undefined), keeps the
//! rings of the usual samplings as concentric circles, and needs no special handling of the
//! open bottom of the hemisphere: the convex hull of the projected points is the region
//! where interpolation is a true blend of three samples; outside it the query is clamped to
//! the nearest hull edge.
//!
//! Why a perturbation: the usual samplings are highly degenerate for Delaunay (whole rings
//! are cocircular, pairs of rings form isosceles trapezoids). The in-circle decisions are
//! taken on copies of the points moved by a deterministic ~1e-9 offset so that every
//! decision is clear-cut and the Bowyer-Watson cavity is always well formed; weights are
//! then computed on the exact points.

use crate::direction::Direction;

/// A triangle of the triangulation with a precomputed inverse for barycentric coordinates.
#[derive(Debug, Clone)]
pub(crate) struct Tri {
    /// Sample indices, counter-clockwise in the projection.
    pub v: [usize; 3],
    a: [f64; 2],
    /// Inverse of the 2x2 matrix `[b - a, c - a]`, row-major.
    inv: [f64; 4],
}

/// Triangles plus the hull boundary edges of a sampling.
#[derive(Debug, Clone, Default)]
pub(crate) struct Triangulation {
    pub tris: Vec<Tri>,
    /// Edges that belong to exactly one triangle (the convex hull), as sample indices.
    pub hull: Vec<[usize; 2]>,
}

/// The projection used for triangulation and interpolation, radians.
pub(crate) fn project(d: Direction) -> [f64; 2] {
    let (s, c) = d.phi.sin_cos();
    [d.theta * c, d.theta * s]
}

fn orient(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Positive when `d` lies strictly inside the circumcircle of the counter-clockwise `a, b, c`.
fn in_circle(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> f64 {
    let (ax, ay) = (a[0] - d[0], a[1] - d[1]);
    let (bx, by) = (b[0] - d[0], b[1] - d[1]);
    let (cx, cy) = (c[0] - d[0], c[1] - d[1]);
    let a2 = ax * ax + ay * ay;
    let b2 = bx * bx + by * by;
    let c2 = cx * cx + cy * cy;
    ax * (by * c2 - b2 * cy) - ay * (bx * c2 - b2 * cx) + a2 * (bx * cy - by * cx)
}

/// A deterministic pseudo-random number in `[-1, 1)` for index `i` (splitmix64).
fn jitter(i: u64) -> f64 {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

impl Triangulation {
    /// Bowyer-Watson over the projected points. Fewer than 3 points, or all points on a
    /// line, give no triangles (interpolation then falls back to hull edges or nearest).
    pub fn build(points: &[[f64; 2]]) -> Self {
        let n = points.len();
        if n < 3 {
            return Triangulation { tris: Vec::new(), hull: if n == 2 { vec![[0, 1]] } else { Vec::new() } };
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in points {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-6);
        let centre = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
        let eps = 1e-9 * extent;
        let mut q: Vec<[f64; 2]> = points
            .iter()
            .enumerate()
            .map(|(i, p)| [p[0] + eps * jitter(2 * i as u64), p[1] + eps * jitter(2 * i as u64 + 1)])
            .collect();
        // Super-triangle far enough that its circumcircles near the hull are almost lines.
        let m = 100.0 * extent;
        q.push([centre[0] - 20.0 * m, centre[1] - 10.0 * m]);
        q.push([centre[0] + 20.0 * m, centre[1] - 10.0 * m]);
        q.push([centre[0], centre[1] + 20.0 * m]);
        let mut tris: Vec<[usize; 3]> = vec![[n, n + 1, n + 2]];
        for i in 0..n {
            let p = q[i];
            let mut bad = Vec::new();
            tris.retain(|t| {
                if in_circle(q[t[0]], q[t[1]], q[t[2]], p) > 0.0 {
                    bad.push(*t);
                    false
                } else {
                    true
                }
            });
            // Boundary of the cavity: directed edges of bad triangles whose reverse is not
            // also an edge of a bad triangle.
            let mut edges: Vec<[usize; 2]> = Vec::with_capacity(bad.len() * 3);
            for t in &bad {
                for k in 0..3 {
                    edges.push([t[k], t[(k + 1) % 3]]);
                }
            }
            for e in &edges {
                if !edges.iter().any(|f| f[0] == e[1] && f[1] == e[0]) {
                    tris.push([e[0], e[1], i]);
                }
            }
        }
        let mut out = Triangulation::default();
        for t in tris {
            if t.iter().any(|&k| k >= n) {
                continue;
            }
            let (a, b, c) = (points[t[0]], points[t[1]], points[t[2]]);
            let det = orient(a, b, c);
            // Drop degenerate slivers (collinear points on the hull of an arbitrary list).
            if det <= 1e-14 * extent * extent {
                continue;
            }
            let inv = [(c[1] - a[1]) / det, -(c[0] - a[0]) / det, -(b[1] - a[1]) / det, (b[0] - a[0]) / det];
            out.tris.push(Tri { v: t, a, inv });
        }
        let mut directed: Vec<[usize; 2]> = Vec::new();
        for t in &out.tris {
            for k in 0..3 {
                directed.push([t.v[k], t.v[(k + 1) % 3]]);
            }
        }
        for e in &directed {
            if !directed.iter().any(|f| f[0] == e[1] && f[1] == e[0]) {
                out.hull.push(*e);
            }
        }
        out
    }

    /// Barycentric coordinates of `q` in triangle `t`: weights of `v[0], v[1], v[2]`.
    pub fn barycentric(t: &Tri, q: [f64; 2]) -> [f64; 3] {
        let dx = q[0] - t.a[0];
        let dy = q[1] - t.a[1];
        let l1 = t.inv[0] * dx + t.inv[1] * dy;
        let l2 = t.inv[2] * dx + t.inv[3] * dy;
        [1.0 - l1 - l2, l1, l2]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn in_circle_sign() {
        let (a, b, c) = ([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]);
        assert!(orient(a, b, c) > 0.0);
        assert!(in_circle(a, b, c, [0.5, 0.5]) > 0.0);
        assert!(in_circle(a, b, c, [2.0, 2.0]) < 0.0);
    }

    #[test]
    fn square_grid_gives_two_triangles_per_cell() {
        // A 4x4 grid: every cell is cocircular, the worst case for the in-circle test.
        let pts: Vec<[f64; 2]> = (0..16).map(|i| [(i % 4) as f64, (i / 4) as f64]).collect();
        let t = Triangulation::build(&pts);
        assert_eq!(t.tris.len(), 18);
        assert_eq!(t.hull.len(), 12);
        let area: f64 = t.tris.iter().map(|tr| orient(pts[tr.v[0]], pts[tr.v[1]], pts[tr.v[2]]) / 2.0).sum();
        assert!((area - 9.0).abs() < 1e-12);
    }
}
