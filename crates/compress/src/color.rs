//! Colour models: how the three stored channels relate to linear RGB.
//!
//! A BTF's three colour channels are strongly correlated; most of the detail is in the
//! luminance. Each model maps linear RGB to three channels $(D_0, D_1, D_2)$ that are
//! factorised separately (each with its own number of terms) and back:
//!
//! * [`ColorModel::Rgb`]: $D = (R, G, B)$.
//! * [`ColorModel::Yuv`]: the BT.601 analog YUV of the Bonn files (`undecorrelate.m`):
//!   $Y = 0.299R + 0.587G + 0.114B$, $U = (B - Y)/2.03211$, $V = (R - Y)/1.13983$; back with
//!   $R = Y + 1.13983V$, $G = Y - 0.39464U - 0.58060V$, $B = Y + 2.03211U$ (the Bonn matrix;
//!   the forward map is its exact inverse, where the Bonn text rounds it to $0.492$, $0.877$).
//! * [`ColorModel::YlogUv`]: $D_0 = \ln(\max(Y, 0) + \varepsilon)$, $D_1 = U$, $D_2 = V$ (the
//!   log(Y) channel of den Brok et al., Bonn colour model 9); back with
//!   $Y = e^{D_0} - \varepsilon$. The logarithm compresses highlights so that the factorisation
//!   weighs relative rather than absolute error; $\varepsilon$ (`log_eps`, default $10^{-3}$ of
//!   a white reflector) bounds the weight of black texels. Negative luminance (noise in the
//!   dark) is clipped to 0 before the logarithm.

use serde::{Deserialize, Serialize};

/// How the three stored channels relate to linear RGB.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ColorModel {
    /// Linear RGB as is.
    Rgb,
    /// Luminance and two chrominance channels (BT.601 analog YUV), linear.
    Yuv,
    /// log(Y + eps), U, V.
    YlogUv,
}

impl ColorModel {
    /// All models, for help texts and benchmarks.
    pub const ALL: [ColorModel; 3] = [ColorModel::Rgb, ColorModel::Yuv, ColorModel::YlogUv];

    /// The name used on the command line and in model files (`rgb`, `yuv`, `ylog-uv`).
    pub fn name(self) -> &'static str {
        match self {
            ColorModel::Rgb => "rgb",
            ColorModel::Yuv => "yuv",
            ColorModel::YlogUv => "ylog-uv",
        }
    }

    /// Parses [`ColorModel::name`].
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == s)
    }

    /// True if the map from RGB is linear (the model's channels are linear combinations of
    /// RGB, so a linear model in them is a linear model in RGB).
    pub fn is_linear(self) -> bool {
        !matches!(self, ColorModel::YlogUv)
    }

    /// RGB to the stored channels.
    #[inline]
    pub fn forward(self, rgb: [f32; 3], log_eps: f32) -> [f32; 3] {
        match self {
            ColorModel::Rgb => rgb,
            ColorModel::Yuv => yuv(rgb),
            ColorModel::YlogUv => {
                let [y, u, v] = yuv(rgb);
                [(y.max(0.0) + log_eps).ln(), u, v]
            }
        }
    }

    /// The stored channels back to RGB.
    #[inline]
    pub fn inverse(self, d: [f32; 3], log_eps: f32) -> [f32; 3] {
        match self {
            ColorModel::Rgb => d,
            ColorModel::Yuv => rgb_of_yuv(d),
            ColorModel::YlogUv => rgb_of_yuv([d[0].exp() - log_eps, d[1], d[2]]),
        }
    }

    /// For linear models: `rgb[c] = sum_d matrix[c][d] * D[d]`.
    pub fn inverse_matrix(self) -> Option<[[f64; 3]; 3]> {
        match self {
            ColorModel::Rgb => Some([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
            ColorModel::Yuv => Some(YUV_TO_RGB),
            ColorModel::YlogUv => None,
        }
    }
}

/// BT.601 analog YUV to RGB (btflib `undecorrelate.m`).
pub const YUV_TO_RGB: [[f64; 3]; 3] =
    [[1.0, 0.0, 1.13983], [1.0, -0.114 * 2.03211 / 0.587, -0.299 * 1.13983 / 0.587], [1.0, 2.03211, 0.0]];

#[inline]
fn yuv([r, g, b]: [f32; 3]) -> [f32; 3] {
    let y = 0.299 * r + 0.587 * g + 0.114 * b;
    [y, (b - y) / 2.03211, (r - y) / 1.13983]
}

#[inline]
fn rgb_of_yuv([y, u, v]: [f32; 3]) -> [f32; 3] {
    let m = YUV_TO_RGB;
    [y + m[0][2] as f32 * v, y + m[1][1] as f32 * u + m[1][2] as f32 * v, y + m[2][1] as f32 * u]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_names() {
        for m in ColorModel::ALL {
            assert_eq!(ColorModel::from_name(m.name()), Some(m));
            for rgb in [[0.2f32, 0.5, 0.9], [1.0, 1.0, 1.0], [3.0, 0.01, 0.4]] {
                let back = m.inverse(m.forward(rgb, 1e-3), 1e-3);
                for c in 0..3 {
                    assert!((back[c] - rgb[c]).abs() < 1e-5 * (1.0 + rgb[c]), "{m:?} {rgb:?} -> {back:?}");
                }
            }
        }
        // White has no chrominance.
        let w = ColorModel::Yuv.forward([1.0, 1.0, 1.0], 0.0);
        assert!((w[0] - 1.0).abs() < 1e-6 && w[1].abs() < 1e-6 && w[2].abs() < 1e-6);
        // Negative luminance is clipped before the log, never NaN.
        let d = ColorModel::YlogUv.forward([-0.01, -0.01, -0.01], 1e-3);
        assert!(d.iter().all(|x| x.is_finite()));
    }
}
