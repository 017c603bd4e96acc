//! Step 1: the adaptive threshold.

use super::{DetectParams, GrayImage};

/// Dark mask: `v < (1 - rel) * local mean`, the mean over a square window (integral image).
pub(super) fn threshold(img: &GrayImage, p: &DetectParams) -> Vec<bool> {
    let (w, h) = (img.width, img.height);
    let mut integ = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            row += f64::from(img.at(x, y));
            integ[(y + 1) * (w + 1) + x + 1] = integ[y * (w + 1) + x + 1] + row;
        }
    }
    let r = p.threshold_window_px / 2;
    let k = 1.0 - p.threshold_rel;
    let mut dark = vec![false; w * h];
    for y in 0..h {
        let (ya, yb) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (xa, xb) = (x.saturating_sub(r), (x + r + 1).min(w));
            let s = integ[yb * (w + 1) + xb] - integ[ya * (w + 1) + xb] - integ[yb * (w + 1) + xa]
                + integ[ya * (w + 1) + xa];
            let mean = s / ((yb - ya) * (xb - xa)) as f64;
            // A positive mean only: on black velvet (mean ~ 0) nothing counts as dark.
            dark[y * w + x] = mean > 0.0 && f64::from(img.at(x, y)) < k * mean;
        }
    }
    dark
}
