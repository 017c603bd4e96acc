//! The grey image the detector reads.

use super::DetectError;

/// A grey image borrowed as `f32` values, row-major, any linear scale (dark = low).
#[derive(Debug, Clone, Copy)]
pub struct GrayImage<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height` values, row-major.
    pub data: &'a [f32],
}

impl<'a> GrayImage<'a> {
    /// Wraps `data`; fails unless it holds `width * height` values and both are positive.
    pub fn new(width: usize, height: usize, data: &'a [f32]) -> Result<Self, DetectError> {
        if width == 0 || height == 0 || data.len() != width * height {
            return Err(DetectError::BadImage { width, height, len: data.len() });
        }
        Ok(GrayImage { width, height, data })
    }

    pub(super) fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Bilinear value at `(x, y)` (integer = pixel centre), clamped at the image edge.
    pub(super) fn bilinear(&self, x: f64, y: f64) -> f64 {
        let xm = (self.width - 1) as f64;
        let ym = (self.height - 1) as f64;
        let x = x.clamp(0.0, xm);
        let y = y.clamp(0.0, ym);
        // `as usize` truncates, which is the floor here (x, y >= 0): `floor()` is a libm call
        // on the baseline x86-64 target, and this runs for every profile sample.
        let x0 = (x as usize).min(self.width.saturating_sub(2));
        let y0 = (y as usize).min(self.height.saturating_sub(2));
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let a = f64::from(self.at(x0, y0)) * (1.0 - fx) + f64::from(self.at(x1, y0)) * fx;
        let b = f64::from(self.at(x0, y1)) * (1.0 - fx) + f64::from(self.at(x1, y1)) * fx;
        a * (1.0 - fy) + b * fy
    }
}
