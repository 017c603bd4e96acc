//! Step 1: the adaptive threshold.

use super::{DetectParams, GrayImage, Window};

/// Dark mask of the pixels of `win` (row-major, `win.width() * win.height()`):
/// `v < (1 - rel) * local mean`, the mean over a square window clipped to the IMAGE (not to
/// `win`), from an integral image over `win` grown by the window's half side. A pixel's value
/// is therefore the same whichever search window it is computed in (up to the rounding of the
/// integral's origin).
pub(super) fn threshold(img: &GrayImage, p: &DetectParams, win: Window) -> Vec<bool> {
    let (w, h) = (img.width, img.height);
    let r = p.threshold_window_px / 2;
    // The integral image covers `ex0..ex1` x `ey0..ey1`: every box a pixel of `win` needs.
    let (ex0, ey0) = (win.x0.saturating_sub(r), win.y0.saturating_sub(r));
    let (ex1, ey1) = ((win.x1 + r).min(w), (win.y1 + r).min(h));
    let iw = ex1 - ex0 + 1;
    let mut integ = vec![0.0f64; iw * (ey1 - ey0 + 1)];
    for y in ey0..ey1 {
        let mut row = 0.0;
        let (above, here) = ((y - ey0) * iw, (y - ey0 + 1) * iw);
        let line = &img.data[y * w + ex0..y * w + ex1];
        for (i, &v) in line.iter().enumerate() {
            row += f64::from(v);
            integ[here + i + 1] = integ[above + i + 1] + row;
        }
    }
    let k = 1.0 - p.threshold_rel;
    let ww = win.x1 - win.x0;
    let mut dark = vec![false; ww * (win.y1 - win.y0)];
    for y in win.y0..win.y1 {
        let (ya, yb) = (y.saturating_sub(r) - ey0, (y + r + 1).min(h) - ey0);
        let out = &mut dark[(y - win.y0) * ww..(y - win.y0 + 1) * ww];
        for (o, x) in out.iter_mut().zip(win.x0..win.x1) {
            let (xa, xb) = (x.saturating_sub(r) - ex0, (x + r + 1).min(w) - ex0);
            let s = integ[yb * iw + xb] - integ[ya * iw + xb] - integ[yb * iw + xa] + integ[ya * iw + xa];
            let mean = s / ((yb - ya) * (xb - xa)) as f64;
            // A positive mean only: on black velvet (mean ~ 0) nothing counts as dark.
            *o = mean > 0.0 && f64::from(img.at(x, y)) < k * mean;
        }
    }
    dark
}
