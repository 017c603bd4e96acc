//! Samplings of the hemisphere: named lists of [`Direction`]s.
//!
//! Constructors: the Bonn 81-direction table of the gonioreflectometer
//! ([`Sampling::bonn81`]), the Bonn Dome-1 151-direction layout ([`Sampling::bonn_dome1`]),
//! generic ring layouts ([`Sampling::from_rings`]) and arbitrary validated lists
//! ([`Sampling::from_list`]). Every sampling answers nearest-direction queries
//! ([`Sampling::nearest`]) and interpolates barycentrically over a Delaunay triangulation of
//! its directions ([`Sampling::interpolate`]); the triangulation lives in the projection
//! `(theta cos phi, theta sin phi)`, see `docs/conventions.md`.

mod triangulation;

use nalgebra::Vector3;

use crate::direction::Direction;
use triangulation::{project, Triangulation};

/// Two directions closer than this (radians) are the same direction.
pub const DUPLICATE_TOLERANCE_RAD: f64 = 1e-9;

/// Why a list of directions or a ring layout is not a valid sampling.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SamplingError {
    /// A sampling needs at least one direction.
    #[error("sampling {name:?} has no directions")]
    Empty {
        /// Name of the sampling.
        name: String,
    },
    /// A direction lies outside the open upper hemisphere.
    #[error("sampling {name:?}: direction {index} has theta = {theta_deg} deg, allowed [0, 90)")]
    ThetaOutOfRange {
        /// Name of the sampling.
        name: String,
        /// Position of the direction in the list.
        index: usize,
        /// Its polar angle, degrees.
        theta_deg: f64,
    },
    /// A direction is not a finite number.
    #[error("sampling {name:?}: direction {index} is not finite (theta = {theta}, phi = {phi} rad)")]
    NotFinite {
        /// Name of the sampling.
        name: String,
        /// Position of the direction in the list.
        index: usize,
        /// Polar angle, radians.
        theta: f64,
        /// Azimuth, radians.
        phi: f64,
    },
    /// Two entries describe the same direction (within [`DUPLICATE_TOLERANCE_RAD`]).
    #[error(
        "sampling {name:?}: directions {first} and {second} are the same direction ({theta_deg} deg, {phi_deg} deg)"
    )]
    Duplicate {
        /// Name of the sampling.
        name: String,
        /// Index of the first occurrence.
        first: usize,
        /// Index of the repeat.
        second: usize,
        /// Polar angle of the repeat, degrees.
        theta_deg: f64,
        /// Azimuth of the repeat, degrees.
        phi_deg: f64,
    },
    /// A ring of a ring layout has no directions.
    #[error("sampling {name:?}: ring {ring} (theta = {theta_deg} deg) has count 0, allowed >= 1")]
    EmptyRing {
        /// Name of the sampling.
        name: String,
        /// Position of the ring in the layout.
        ring: usize,
        /// Polar angle of the ring, degrees.
        theta_deg: f64,
    },
}

/// One ring of a ring (dome) layout: `count` directions at polar angle `theta_deg`, at
/// azimuths `phi_offset_deg + j * 360 / count` for `j = 0..count`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ring {
    /// Polar angle of the ring, degrees.
    pub theta_deg: f64,
    /// Number of directions on the ring.
    pub count: usize,
    /// Azimuth of the first direction, degrees.
    pub phi_offset_deg: f64,
}

impl Ring {
    /// Shorthand constructor.
    pub const fn new(theta_deg: f64, count: usize, phi_offset_deg: f64) -> Self {
        Ring { theta_deg, count, phi_offset_deg }
    }
}

/// The Bonn gonioreflectometer table (Mueller et al. 2005, table 1): theta 0/15/30/45/60/75
/// with delta-phi -/60/30/20/18/15, every ring starting at phi = 0.
pub const BONN81_RINGS: [Ring; 6] = [
    Ring::new(0.0, 1, 0.0),
    Ring::new(15.0, 6, 0.0),
    Ring::new(30.0, 12, 0.0),
    Ring::new(45.0, 18, 0.0),
    Ring::new(60.0, 20, 0.0),
    Ring::new(75.0, 24, 0.0),
];

/// The Bonn Dome-1 layout (btflib `create_ubo_dome1_sampling.m`): 151 directions.
pub const BONN_DOME1_RINGS: [Ring; 10] = [
    Ring::new(0.0, 1, 0.0),
    Ring::new(11.0, 6, 15.0),
    Ring::new(23.5, 12, 0.0),
    Ring::new(30.0, 12, 15.0),
    Ring::new(37.5, 12, 0.0),
    Ring::new(45.0, 18, 0.0),
    Ring::new(52.5, 18, 7.5),
    Ring::new(60.0, 24, 0.0),
    Ring::new(67.5, 24, 7.5),
    Ring::new(75.0, 24, 0.0),
];

/// Up to three sample indices with non-negative weights summing to 1. Unused slots have
/// weight 0 (and repeat a used index), so `iter()` is the convenient way to read it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Barycentric {
    /// Sample indices.
    pub indices: [usize; 3],
    /// Weights of `indices`, each `>= 0`, summing to 1.
    pub weights: [f64; 3],
    /// How many leading slots are used (1 = a single sample, 2 = an edge, 3 = a triangle).
    pub count: usize,
}

impl Barycentric {
    /// The used `(index, weight)` pairs.
    pub fn iter(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.indices.iter().copied().zip(self.weights.iter().copied()).take(self.count)
    }

    /// Blends per-sample values: `sum_i w_i * values[index_i]`.
    pub fn apply(&self, values: &[f64]) -> f64 {
        self.iter().map(|(i, w)| w * values[i]).sum()
    }
}

/// A named list of directions on the upper hemisphere, with the precomputed data for
/// nearest lookup and interpolation.
#[derive(Debug, Clone)]
pub struct Sampling {
    name: String,
    directions: Vec<Direction>,
    units: Vec<Vector3<f64>>,
    projected: Vec<[f64; 2]>,
    triangulation: Triangulation,
}

impl Sampling {
    /// The Bonn 81-direction table, ring by ring, phi ascending. Named `bonn81`.
    pub fn bonn81() -> Self {
        Self::from_rings("bonn81", &BONN81_RINGS).expect("the Bonn table is valid")
    }

    /// The Bonn Dome-1 151-direction layout, ring by ring, phi ascending within each ring
    /// (starting at the ring's offset). Named `bonn-dome1-151`.
    pub fn bonn_dome1() -> Self {
        Self::from_rings("bonn-dome1-151", &BONN_DOME1_RINGS).expect("the Dome-1 layout is valid")
    }

    /// A ring (dome) layout: each ring's directions in order `j = 0..count`, rings in the
    /// given order. Validated like [`Sampling::from_list`].
    pub fn from_rings(name: &str, rings: &[Ring]) -> Result<Self, SamplingError> {
        let mut dirs = Vec::new();
        for (k, r) in rings.iter().enumerate() {
            if r.count == 0 {
                return Err(SamplingError::EmptyRing { name: name.into(), ring: k, theta_deg: r.theta_deg });
            }
            for j in 0..r.count {
                let phi = r.phi_offset_deg + j as f64 * 360.0 / r.count as f64;
                dirs.push(Direction::from_degrees(r.theta_deg, phi));
            }
        }
        Self::from_list(name, dirs)
    }

    /// An arbitrary list: every theta in `[0, 90)` degrees, no two entries within
    /// [`DUPLICATE_TOLERANCE_RAD`] of each other (so `(0, 0)` and `(0, 90)` are duplicates).
    pub fn from_list(name: &str, directions: Vec<Direction>) -> Result<Self, SamplingError> {
        if directions.is_empty() {
            return Err(SamplingError::Empty { name: name.into() });
        }
        for (i, d) in directions.iter().enumerate() {
            if !d.theta.is_finite() || !d.phi.is_finite() {
                return Err(SamplingError::NotFinite { name: name.into(), index: i, theta: d.theta, phi: d.phi });
            }
            if !(0.0..std::f64::consts::FRAC_PI_2).contains(&d.theta) {
                return Err(SamplingError::ThetaOutOfRange {
                    name: name.into(),
                    index: i,
                    theta_deg: d.theta.to_degrees(),
                });
            }
        }
        let units: Vec<Vector3<f64>> = directions.iter().map(|d| d.to_vector()).collect();
        // Quadratic, but samplings have at most a few thousand entries and this runs once.
        for j in 1..units.len() {
            for i in 0..j {
                if crate::direction::angle_between(&units[i], &units[j]) < DUPLICATE_TOLERANCE_RAD {
                    let (t, p) = directions[j].to_degrees();
                    return Err(SamplingError::Duplicate {
                        name: name.into(),
                        first: i,
                        second: j,
                        theta_deg: t,
                        phi_deg: p,
                    });
                }
            }
        }
        let projected: Vec<[f64; 2]> = directions.iter().map(|d| project(*d)).collect();
        let triangulation = Triangulation::build(&projected);
        Ok(Sampling { name: name.into(), directions, units, projected, triangulation })
    }

    /// Name of the sampling (e.g. `bonn81`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The directions in order.
    pub fn directions(&self) -> &[Direction] {
        &self.directions
    }

    /// Number of directions.
    pub fn len(&self) -> usize {
        self.directions.len()
    }

    /// True if there are no directions (never, for a validated sampling).
    pub fn is_empty(&self) -> bool {
        self.directions.is_empty()
    }

    /// Direction number `i`.
    pub fn get(&self, i: usize) -> Direction {
        self.directions[i]
    }

    /// The triangles of the interpolation triangulation, as sample-index triples
    /// (counter-clockwise in the `(theta cos phi, theta sin phi)` projection).
    pub fn triangles(&self) -> Vec<[usize; 3]> {
        self.triangulation.tris.iter().map(|t| t.v).collect()
    }

    /// Index of the sample nearest to `d` by angular distance (ties: the lower index).
    /// One pass of dot products with precomputed unit vectors, no trigonometry beyond
    /// converting the query.
    pub fn nearest(&self, d: Direction) -> usize {
        self.nearest_to_vector(&d.to_vector())
    }

    /// Like [`Sampling::nearest`] for a unit vector in the sample frame.
    pub fn nearest_to_vector(&self, v: &Vector3<f64>) -> usize {
        let mut best = 0;
        let mut best_dot = f64::NEG_INFINITY;
        for (i, u) in self.units.iter().enumerate() {
            let dot = u.dot(v);
            if dot > best_dot {
                best_dot = dot;
                best = i;
            }
        }
        best
    }

    /// Barycentric weights of `d` over the triangulation. Inside the convex hull of the
    /// projected samples: the containing triangle's weights, which reproduce any function
    /// linear in `(theta cos phi, theta sin phi)` and are exact at the samples. Outside
    /// (below the lowest ring, or between hull edges and the ring's circle): the query is
    /// clamped to the nearest point of the hull boundary and blended along that edge.
    /// A sampling with fewer than 3 non-collinear directions falls back to its nearest
    /// hull edge, or to the nearest sample.
    pub fn interpolate(&self, d: Direction) -> Barycentric {
        let q = project(d);
        const INSIDE_TOL: f64 = -1e-12;
        for t in &self.triangulation.tris {
            let w = Triangulation::barycentric(t, q);
            if w.iter().all(|&x| x >= INSIDE_TOL) {
                let w = [w[0].max(0.0), w[1].max(0.0), w[2].max(0.0)];
                let s = w[0] + w[1] + w[2];
                return Barycentric { indices: t.v, weights: [w[0] / s, w[1] / s, w[2] / s], count: 3 };
            }
        }
        let mut best: Option<(f64, usize, usize, f64)> = None;
        for e in &self.triangulation.hull {
            let (a, b) = (self.projected[e[0]], self.projected[e[1]]);
            let ab = [b[0] - a[0], b[1] - a[1]];
            let len2 = ab[0] * ab[0] + ab[1] * ab[1];
            let t =
                if len2 > 0.0 { (((q[0] - a[0]) * ab[0] + (q[1] - a[1]) * ab[1]) / len2).clamp(0.0, 1.0) } else { 0.0 };
            let p = [a[0] + t * ab[0], a[1] + t * ab[1]];
            let dist2 = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2);
            if best.is_none_or(|(bd, ..)| dist2 < bd) {
                best = Some((dist2, e[0], e[1], t));
            }
        }
        match best {
            Some((_, i, j, t)) => Barycentric { indices: [i, j, j], weights: [1.0 - t, t, 0.0], count: 2 },
            None => {
                let i = self.nearest(d);
                Barycentric { indices: [i, i, i], weights: [1.0, 0.0, 0.0], count: 1 }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_direction(rng: &mut ChaCha8Rng, max_theta_deg: f64) -> Direction {
        // Uniform on the spherical cap (cos theta uniform).
        let ct = rng.gen_range(max_theta_deg.to_radians().cos()..=1.0f64);
        Direction::new(ct.acos(), rng.gen_range(0.0..std::f64::consts::TAU))
    }

    #[test]
    fn bonn81_counts_per_ring_and_order() {
        let s = Sampling::bonn81();
        assert_eq!(s.len(), 81);
        assert_eq!(s.name(), "bonn81");
        let expected =
            [(0.0, 1, 0.0), (15.0, 6, 60.0), (30.0, 12, 30.0), (45.0, 18, 20.0), (60.0, 20, 18.0), (75.0, 24, 15.0)];
        let mut k = 0;
        for (theta, count, dphi) in expected {
            for j in 0..count {
                let (t, p) = s.get(k).to_degrees();
                assert!((t - theta).abs() < 1e-12, "index {k}");
                assert!((p - j as f64 * dphi).abs() < 1e-9, "index {k}: phi {p}");
                k += 1;
            }
        }
        assert_eq!(k, 81);
        // The file-name check: the 75 deg ring ends at phi 345.
        assert!((s.get(80).to_degrees().1 - 345.0).abs() < 1e-9);
    }

    #[test]
    fn dome1_counts_and_offsets() {
        let s = Sampling::bonn_dome1();
        assert_eq!(s.len(), 151);
        let counts: Vec<usize> = BONN_DOME1_RINGS.iter().map(|r| r.count).collect();
        assert_eq!(counts, [1, 6, 12, 12, 12, 18, 18, 24, 24, 24]);
        // Ring 11 deg starts at 15 deg and steps by 60; ring 52.5 starts at 7.5 and steps by 20.
        assert!((s.get(1).to_degrees().1 - 15.0).abs() < 1e-9);
        assert!((s.get(2).to_degrees().1 - 75.0).abs() < 1e-9);
        let start_52 = 1 + 6 + 12 + 12 + 12 + 18;
        assert!((s.get(start_52).to_degrees().0 - 52.5).abs() < 1e-12);
        assert!((s.get(start_52 + 1).to_degrees().1 - 27.5).abs() < 1e-9);
    }

    #[test]
    fn list_validation_names_the_problem() {
        let bad_theta =
            Sampling::from_list("x", vec![Direction::from_degrees(10.0, 0.0), Direction::from_degrees(90.0, 0.0)]);
        assert!(matches!(bad_theta, Err(SamplingError::ThetaOutOfRange { index: 1, .. })));
        let negative = Sampling::from_list("x", vec![Direction::new(-0.1, 0.0)]);
        assert!(matches!(negative, Err(SamplingError::ThetaOutOfRange { index: 0, .. })));
        // Two spellings of the pole are the same direction.
        let dup = Sampling::from_list("x", vec![Direction::from_degrees(0.0, 0.0), Direction::from_degrees(0.0, 90.0)]);
        assert!(matches!(dup, Err(SamplingError::Duplicate { first: 0, second: 1, .. })));
        let dup2 = Sampling::from_list(
            "x",
            vec![
                Direction::from_degrees(30.0, 10.0),
                Direction::from_degrees(20.0, 0.0),
                Direction::from_degrees(30.0, 370.0),
            ],
        );
        assert!(matches!(dup2, Err(SamplingError::Duplicate { first: 0, second: 2, .. })));
        assert!(matches!(Sampling::from_list("x", vec![]), Err(SamplingError::Empty { .. })));
        let empty_ring = Sampling::from_rings("x", &[Ring::new(0.0, 1, 0.0), Ring::new(30.0, 0, 0.0)]);
        assert!(matches!(empty_ring, Err(SamplingError::EmptyRing { ring: 1, .. })));
        let msg = Sampling::from_list("mine", vec![Direction::from_degrees(95.0, 0.0)]).unwrap_err().to_string();
        assert!(msg.contains("mine") && msg.contains("95") && msg.contains("[0, 90)"), "{msg}");
    }

    #[test]
    fn nearest_equals_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(81);
        for s in [Sampling::bonn81(), Sampling::bonn_dome1()] {
            for _ in 0..20_000 {
                let q = random_direction(&mut rng, 90.0);
                let fast = s.nearest(q);
                let brute = (0..s.len())
                    .min_by(|&a, &b| q.angle_to(s.get(a)).total_cmp(&q.angle_to(s.get(b))))
                    .expect("non-empty");
                // Equal up to exact ties, which random queries do not hit.
                assert_eq!(fast, brute, "{q:?}");
            }
            for i in 0..s.len() {
                assert_eq!(s.nearest(s.get(i)), i);
            }
        }
    }

    /// Area of the convex hull of the projected points (gift wrapping is overkill: the
    /// samplings used here have their hull on the outermost ring, a regular polygon).
    fn outer_ring_polygon_area(theta_deg: f64, count: usize) -> f64 {
        let r = theta_deg.to_radians();
        0.5 * count as f64 * r * r * (std::f64::consts::TAU / count as f64).sin()
    }

    #[test]
    fn triangulation_covers_the_hull_without_overlap() {
        for s in [Sampling::bonn81(), Sampling::bonn_dome1()] {
            let tris = s.triangles();
            // Euler: a triangulation of n points with h on the hull has 2n - 2 - h triangles.
            let h = 24;
            assert_eq!(tris.len(), 2 * s.len() - 2 - h, "{}", s.name());
            let area: f64 = tris
                .iter()
                .map(|t| {
                    let (a, b, c) = (s.projected[t[0]], s.projected[t[1]], s.projected[t[2]]);
                    0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
                })
                .sum();
            assert!((area - outer_ring_polygon_area(75.0, 24)).abs() < 1e-12, "{}: {area}", s.name());
        }
    }

    #[test]
    fn weights_are_a_partition_of_unity_and_exact_at_nodes() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for s in [Sampling::bonn81(), Sampling::bonn_dome1()] {
            for _ in 0..5000 {
                let b = s.interpolate(random_direction(&mut rng, 89.9));
                assert!(b.weights.iter().all(|&w| w >= 0.0));
                assert!((b.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                assert!(b.iter().all(|(i, _)| i < s.len()));
            }
            for i in 0..s.len() {
                let b = s.interpolate(s.get(i));
                let w: f64 = b.iter().filter(|&(k, _)| k == i).map(|(_, w)| w).sum();
                assert!(w > 1.0 - 1e-12, "{} node {i}: {b:?}", s.name());
            }
        }
    }

    #[test]
    fn linear_functions_of_the_projection_are_reproduced() {
        let f = |d: Direction| {
            let p = project(d);
            0.3 - 1.7 * p[0] + 2.2 * p[1]
        };
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for s in [Sampling::bonn81(), Sampling::bonn_dome1()] {
            let values: Vec<f64> = s.directions().iter().map(|&d| f(d)).collect();
            let mut inside = 0;
            for _ in 0..5000 {
                let q = random_direction(&mut rng, 75.0);
                let b = s.interpolate(q);
                if b.count == 3 {
                    inside += 1;
                    assert!((b.apply(&values) - f(q)).abs() < 1e-12, "{q:?}");
                }
            }
            // Most of the 75 deg cap is inside the 24-gon (the rest is clamped).
            assert!(inside > 4800, "{inside}");
        }
    }

    #[test]
    fn directions_below_the_lowest_ring_clamp_to_the_hull_edge() {
        let s = Sampling::bonn81();
        // Straight below a 75 deg sample: clamps to that sample alone.
        let b = s.interpolate(Direction::from_degrees(85.0, 30.0));
        let w: f64 = b.iter().filter(|&(k, _)| k == 81 - 24 + 2).map(|(_, w)| w).sum();
        assert!(w > 1.0 - 1e-12, "{b:?}");
        // Between two 75 deg samples: half and half.
        let b = s.interpolate(Direction::from_degrees(88.0, 37.5));
        assert_eq!(b.count, 2);
        let mut idx = [b.indices[0], b.indices[1]];
        idx.sort();
        assert_eq!(idx, [81 - 24 + 2, 81 - 24 + 3]);
        assert!((b.weights[0] - 0.5).abs() < 1e-12 && (b.weights[1] - 0.5).abs() < 1e-12);
    }

    #[test]
    fn tiny_lists_fall_back_sensibly() {
        let one = Sampling::from_list("one", vec![Direction::from_degrees(20.0, 40.0)]).expect("valid");
        let b = one.interpolate(Direction::from_degrees(50.0, 200.0));
        assert_eq!((b.count, b.indices[0], b.weights[0]), (1, 0, 1.0));
        let two =
            Sampling::from_list("two", vec![Direction::from_degrees(20.0, 0.0), Direction::from_degrees(40.0, 0.0)])
                .expect("valid");
        let b = two.interpolate(Direction::from_degrees(30.0, 0.0));
        assert_eq!(b.count, 2);
        assert!((b.weights[0] - 0.5).abs() < 1e-12);
        // Collinear projections: no triangle; falls back to the nearest sample.
        let line =
            Sampling::from_list("line", (0..4).map(|i| Direction::from_degrees(10.0 * i as f64 + 5.0, 0.0)).collect())
                .expect("valid");
        assert!(line.triangles().is_empty());
        let b = line.interpolate(Direction::from_degrees(20.0, 0.0));
        assert!((b.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
}
