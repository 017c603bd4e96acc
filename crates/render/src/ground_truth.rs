//! Ground truth: the true texture on the sample plane for one pose.
//!
//! For every texel centre `p` of a grid on the sample plane `z = 0` (by default the sample
//! region on the material's own texel grid), the value is the noise-free radiance along the
//! actual camera ray through `p`: the ray from the camera centre towards `p`, its first
//! surface hit (which is not `p` when the relief masks `p` or lies above it) shaded exactly as
//! in a frame, with self-shadowing, but in the OUTPUT colour space (linear sRGB,
//! D65-relative, scaled by `lamp_scale`: a white Lambertian reflector lit normally from 1 m
//! gives `lamp_scale * (1, 1, 1)`), without vignetting, lens distortion or sensor effects.

use btfrig_core::pose::ScenePose;
use nalgebra::Vector3;
use rayon::prelude::*;

use crate::renderer::{Frame, RenderStats, Renderer};
use crate::scene::ColourSpace;

/// A rectangle of the sample plane, metres (sample frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    /// Left edge (smallest x).
    pub x_min: f64,
    /// Right edge.
    pub x_max: f64,
    /// Bottom edge (smallest y).
    pub y_min: f64,
    /// Top edge (row 0 of a texture lies along it).
    pub y_max: f64,
}

/// A true texture: linear sRGB (D65-relative) radiance per texel, row-major, row 0 at the
/// region's `+y` edge, column 0 at its `-x` edge.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTruth {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The region the texels tile.
    pub region: Region,
    /// `width * height` RGB triples.
    pub data: Vec<[f32; 3]>,
}

impl GroundTruth {
    /// Sample-plane position of texel centre `(col, row)`.
    pub fn texel_centre(&self, col: usize, row: usize) -> (f64, f64) {
        texel_centre(&self.region, self.width, self.height, col, row)
    }

    /// The area-averaged truth of a `k` times coarser grid: each output texel is the mean of
    /// the `k x k` texels it covers (render the point truth at `k` times the size first). What
    /// a texel holds if it stands for its whole square. Sizes not divisible by `k` are cut.
    pub fn box_average(&self, k: usize) -> GroundTruth {
        let k = k.max(1);
        let (w, h) = (self.width / k, self.height / k);
        let mut data = Vec::with_capacity(w * h);
        for row in 0..h {
            for col in 0..w {
                let mut sum = [0.0f64; 3];
                for fr in row * k..(row + 1) * k {
                    for v in &self.data[fr * self.width + col * k..fr * self.width + (col + 1) * k] {
                        for c in 0..3 {
                            sum[c] += f64::from(v[c]);
                        }
                    }
                }
                data.push(sum.map(|x| (x / (k * k) as f64) as f32));
            }
        }
        GroundTruth { width: w, height: h, region: self.region, data }
    }
}

fn texel_centre(r: &Region, w: usize, h: usize, col: usize, row: usize) -> (f64, f64) {
    (
        r.x_min + (col as f64 + 0.5) * (r.x_max - r.x_min) / w as f64,
        r.y_max - (row as f64 + 0.5) * (r.y_max - r.y_min) / h as f64,
    )
}

impl Renderer {
    /// The sample region as a [`Region`].
    pub fn sample_region(&self) -> Region {
        let h = self.scene().layout.sample_side_m / 2.0;
        Region { x_min: -h, x_max: h, y_min: -h, y_max: h }
    }

    /// The ground-truth texture of `width x height` texels over `region` (default: the sample
    /// region) for `pose`. See the module documentation for the definition.
    pub fn ground_truth(&self, pose: &ScenePose, width: usize, height: usize, region: Option<Region>) -> GroundTruth {
        let region = region.unwrap_or_else(|| self.sample_region());
        let f = Frame::new(pose);
        let mut data = vec![[0.0f32; 3]; width * height];
        data.par_chunks_mut(width.max(1)).enumerate().for_each(|(row, out)| {
            let mut st = RenderStats::default();
            for (col, px) in out.iter_mut().enumerate() {
                let (x, y) = texel_centre(&region, width, height, col, row);
                let d = (Vector3::new(x, y, 0.0) - f.origin).normalize();
                let v = self.radiance_along(&f.origin, &d, &f.lamp, ColourSpace::Output, true, &mut st);
                *px = v.map(|c| c as f32);
            }
        });
        GroundTruth { width, height, region, data }
    }
}

#[cfg(test)]
mod box_tests {
    use super::*;

    #[test]
    fn box_average_is_the_mean_of_each_block() {
        let region = Region { x_min: -1.0, x_max: 1.0, y_min: -1.0, y_max: 1.0 };
        let data = (0..16).map(|i| [i as f32, 2.0 * i as f32, 1.0]).collect();
        let fine = GroundTruth { width: 4, height: 4, region, data };
        let c = fine.box_average(2);
        assert_eq!((c.width, c.height), (2, 2));
        // Top-left block: 0, 1, 4, 5.
        assert_eq!(c.data[0], [2.5, 5.0, 1.0]);
        // Bottom-right block: 10, 11, 14, 15.
        assert_eq!(c.data[3], [12.5, 25.0, 1.0]);
        assert_eq!(fine.box_average(1).data, fine.data);
    }
}
