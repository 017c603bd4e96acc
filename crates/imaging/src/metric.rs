//! Error of a texture against a reference (usually the renderer's ground truth).

use crate::rectify::RectifyError;

/// How far a texture is from its reference, over all texels and channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextureError {
    /// `sqrt(mean((a - b)²)) / sqrt(mean(b²))`.
    pub rel_rmse: f64,
    /// `mean(|a - b|)`.
    pub mean_abs: f64,
    /// `max(|a - b|)`.
    pub max_abs: f64,
}

/// Compares `a` with the reference `b` (same texel order); refuses different sizes and an
/// all-zero reference (relative error undefined).
pub fn compare(a: &[[f32; 3]], b: &[[f32; 3]]) -> Result<TextureError, RectifyError> {
    if a.len() != b.len() || a.is_empty() {
        return Err(RectifyError::Mismatch { what: "texture", got: a.len(), expected: b.len() });
    }
    let (mut se, mut sb, mut sa, mut max) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (p, q) in a.iter().zip(b) {
        for c in 0..3 {
            let d = f64::from(p[c]) - f64::from(q[c]);
            se += d * d;
            sb += f64::from(q[c]) * f64::from(q[c]);
            sa += d.abs();
            max = max.max(d.abs());
        }
    }
    if sb.is_nan() || sb <= 0.0 {
        return Err(RectifyError::Radiometry { name: "reference energy", value: sb, allowed: "> 0" });
    }
    let n = (3 * a.len()) as f64;
    Ok(TextureError { rel_rmse: (se / sb).sqrt(), mean_abs: sa / n, max_abs: max })
}

/// [`compare`]'s relative RMSE alone.
pub fn rel_rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> Result<f64, RectifyError> {
    compare(a, b).map(|e| e.rel_rmse)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values() {
        let b = vec![[1.0f32, 1.0, 1.0], [3.0, 3.0, 3.0]];
        let a = vec![[1.0f32, 1.0, 1.0], [3.0, 3.0, 5.0]];
        let e = compare(&a, &b).unwrap();
        // se = 4, sb = 3 + 27 = 30.
        assert!((e.rel_rmse - (4.0f64 / 30.0).sqrt()).abs() < 1e-12);
        assert!((e.mean_abs - 2.0 / 6.0).abs() < 1e-12);
        assert_eq!(e.max_abs, 2.0);
        assert_eq!(compare(&b, &b).unwrap().rel_rmse, 0.0);
        assert!(compare(&a[..1], &b).is_err());
        assert!(compare(&[[1.0; 3]], &[[0.0; 3]]).is_err());
    }
}
