//! Step 1: the adaptive threshold.

use super::{DetectParams, GrayImage, Window};

/// Dark mask of the pixels of `win` (row-major, `win.width() * win.height()`):
/// `v < (1 - rel) * local mean` (compared as `v * area < (1 - rel) * box sum`: no division), the mean over a square window clipped to the IMAGE (not to
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
    // Columns whose box is not clipped by the image share its width: there the box sums are
    // four shifted rows of the integral image, a loop the compiler vectorises.
    let (inner0, inner1) = (win.x0.max(r), win.x1.min(w.saturating_sub(r + 1)).max(win.x0.max(r)));
    let dark_at = |v: f32, s: f64, area: f64| s > 0.0 && f64::from(v) * area < k * s;
    for y in win.y0..win.y1 {
        let (ya, yb) = (y.saturating_sub(r) - ey0, (y + r + 1).min(h) - ey0);
        let (top, bottom) = (&integ[ya * iw..(ya + 1) * iw], &integ[yb * iw..(yb + 1) * iw]);
        let values = &img.data[y * w..(y + 1) * w];
        let out = &mut dark[(y - win.y0) * ww..(y - win.y0 + 1) * ww];
        let rows = (yb - ya) as f64;
        // A positive box sum only: on black velvet (mean ~ 0) nothing counts as dark.
        let clipped = |x: usize| {
            let (xa, xb) = (x.saturating_sub(r) - ex0, (x + r + 1).min(w) - ex0);
            let s = bottom[xb] - top[xb] - bottom[xa] + top[xa];
            dark_at(values[x], s, rows * (xb - xa) as f64)
        };
        for x in (win.x0..inner0.min(win.x1)).chain(inner1.max(win.x0)..win.x1) {
            out[x - win.x0] = clipped(x);
        }
        if inner1 > inner0 {
            let n = inner1 - inner0;
            let (a0, b0) = (inner0 - r - ex0, inner0 + r + 1 - ex0);
            let area = rows * (2 * r + 1) as f64;
            let boxes = bottom[b0..b0 + n].iter().zip(&top[b0..b0 + n]).zip(&bottom[a0..a0 + n]).zip(&top[a0..a0 + n]);
            for ((o, &v), (((&bb, &tb), &ba), &ta)) in
                out[inner0 - win.x0..inner1 - win.x0].iter_mut().zip(&values[inner0..inner1]).zip(boxes)
            {
                *o = dark_at(v, bb - tb - ba + ta, area);
            }
        }
    }
    dark
}
