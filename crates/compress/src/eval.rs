//! Measuring a model: relative RMSE against a reference BTF, and decode throughput.
//!
//! $\text{rel RMSE} = \sqrt{\sum (\hat B - B)^2 / \sum B^2}$ over every captured (light, view)
//! pair, texel and RGB channel (pooled, as the pipeline's `texture_rel_rmse`).

use std::time::Instant;

use btfrig_core::Direction;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::build::RowSource;
use crate::error::Result;
use crate::model::Model;

/// Sums of squared error and squared reference.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ErrorSums {
    /// `sum (model - reference)^2`.
    pub sq_err: f64,
    /// `sum reference^2`.
    pub sq_ref: f64,
}

impl ErrorSums {
    /// `sqrt(sq_err / sq_ref)`.
    pub fn rel_rmse(&self) -> f64 {
        (self.sq_err / self.sq_ref.max(f64::MIN_POSITIVE)).sqrt()
    }

    /// Adds one texture.
    pub fn add(&mut self, model: &[[f32; 3]], reference: &[[f32; 3]]) {
        for (p, q) in model.iter().zip(reference) {
            for c in 0..3 {
                self.sq_err += f64::from(p[c] - q[c]).powi(2);
                self.sq_ref += f64::from(q[c]).powi(2);
            }
        }
    }
}

/// The model's error against every capture `reference` delivers.
pub fn error_against(model: &Model, reference: &mut dyn RowSource) -> Result<ErrorSums> {
    let mut e = ErrorSums::default();
    reference.for_each(&mut |l, v, tex| {
        let a = model.layout.index(l as usize, v as usize);
        e.add(&model.texture(a), tex);
        Ok(())
    })?;
    Ok(e)
}

/// Decode throughput at random (uniform on the hemisphere below 80 degrees) direction
/// pairs: whole textures through [`Model::query`], texels per second (all rayon threads).
/// Returns `(texels_per_s, checksum)`; the checksum keeps the work from being optimised out.
pub fn decode_throughput(model: &Model, queries: usize, seed: u64) -> (f64, f64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut dir = || {
        let ct: f64 = rng.gen_range(80f64.to_radians().cos()..=1.0);
        Direction::new(ct.acos(), rng.gen_range(0.0..std::f64::consts::TAU))
    };
    let dirs: Vec<(Direction, Direction)> = (0..queries).map(|_| (dir(), dir())).collect();
    let t = Instant::now();
    let mut sum = 0.0f64;
    for (v, l) in dirs {
        let tex = model.query(v, l).texture();
        sum += f64::from(tex[tex.len() / 2][1]);
    }
    let s = t.elapsed().as_secs_f64();
    ((queries * model.layout.texels()) as f64 / s.max(1e-9), sum)
}
