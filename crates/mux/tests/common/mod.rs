//! Helpers shared by the mux tests: seeded data and the sensor noise model of
//! `btfrig-render` (`crates/render/src/sensor.rs`): Poisson shot noise, saturation at the full
//! well, Gaussian read noise, quantisation to DN.
#![allow(dead_code)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Poisson};

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// `rows × cols` uniform values in [lo, hi), pattern-major.
pub fn uniform(rows: usize, cols: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut r = rng(seed);
    (0..rows * cols).map(|_| r.gen_range(lo..hi)).collect()
}

/// The sensor as `btfrig-render` models it, in electrons.
#[derive(Debug, Clone, Copy)]
pub struct Sensor {
    pub read_noise_e: f64,
    pub full_well_e: f64,
    pub dn_per_e: f64,
}

impl Sensor {
    /// One photosite reading of mean `lambda` electrons, returned in electrons:
    /// `round(k · (min(Poisson(λ), well) + N(0, σ²))) / k`.
    pub fn read(&self, lambda: f64, r: &mut ChaCha8Rng) -> f64 {
        let z: f64 = r.sample(rand_distr::StandardNormal);
        // As the renderer: exact Poisson below 1000 e-, Gaussian (exact mean and variance) above.
        let shot = if lambda <= 0.0 {
            0.0
        } else if lambda < 1000.0 {
            Poisson::new(lambda).unwrap().sample(r)
        } else {
            lambda + lambda.sqrt() * r.sample::<f64, _>(rand_distr::StandardNormal)
        };
        let e = shot.min(self.full_well_e) + self.read_noise_e * z;
        (e * self.dn_per_e).round() / self.dn_per_e
    }
}

/// Captures of `truth` (sources × cols, electrons per frame at unit intensity) under the
/// patterns `w` (frames × sources, row-major, entries = relative intensity × lit), with an
/// optional stuck LED lit in every frame. Returns frames × cols in electrons (f32).
pub fn capture(
    w: &[f64],
    frames: usize,
    sources: usize,
    truth: &[f64],
    cols: usize,
    sensor: &Sensor,
    seed: u64,
) -> Vec<f32> {
    let mut r = rng(seed);
    let mut out = vec![0.0f32; frames * cols];
    for f in 0..frames {
        let lit: Vec<(usize, f64)> =
            (0..sources).filter(|&j| w[f * sources + j] != 0.0).map(|j| (j, w[f * sources + j])).collect();
        for c in 0..cols {
            let lambda: f64 = lit.iter().map(|&(j, a)| a * truth[j * cols + c]).sum();
            out[f * cols + c] = sensor.read(lambda, &mut r) as f32;
        }
    }
    out
}

/// RMS of `a − b` over the rows in `rows` (each `cols` long).
pub fn rms_rows(a: &[f32], b: &[f64], cols: usize, rows: impl Iterator<Item = usize>) -> f64 {
    let (mut s, mut k) = (0.0, 0usize);
    for j in rows {
        for c in 0..cols {
            let d = f64::from(a[j * cols + c]) - b[j * cols + c];
            s += d * d;
            k += 1;
        }
    }
    (s / k.max(1) as f64).sqrt()
}

/// Mean of `a − b` over the rows in `rows`.
pub fn bias_rows(a: &[f32], b: &[f64], cols: usize, rows: impl Iterator<Item = usize>) -> f64 {
    let (mut s, mut k) = (0.0, 0usize);
    for j in rows {
        for c in 0..cols {
            s += f64::from(a[j * cols + c]) - b[j * cols + c];
            k += 1;
        }
    }
    s / k.max(1) as f64
}

/// Readings of the mean electron counts `lambda` (any layout).
pub fn read_all(lambda: &[f64], sensor: &Sensor, seed: u64) -> Vec<f32> {
    let mut r = rng(seed);
    lambda.iter().map(|&l| sensor.read(l, &mut r) as f32).collect()
}
