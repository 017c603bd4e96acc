//! Recognising the green channel of a bilinear demosaic (its genuine photosites).

use super::{GrayImage, Window};

/// The parity (`(x + y) % 2`) of the genuine samples, if `img` is the green channel of a
/// bilinear demosaic: then every pixel of the other parity is the mean of its four
/// neighbours (to float rounding), which the genuine photosites (noisy) are not. Flat
/// places (all four neighbours equal) do not count. Tested: every `row_step`-th row of each
/// of `windows` (the whole frame every eighth row: about 240 000 pixels at 1600 x 1200).
pub(super) fn demosaic_green_parity(img: &GrayImage, windows: &[Window], row_step: usize) -> Option<usize> {
    let (w, h) = (img.width, img.height);
    if w < 8 || h < 8 {
        return None;
    }
    let (mut tested, mut hold) = ([0usize; 2], [0usize; 2]);
    for win in windows {
        let (xa, xb) = (win.x0.max(1), win.x1.min(w - 1));
        for y in (win.y0.max(1)..win.y1.min(h - 1)).step_by(row_step.max(1)) {
            for x in xa..xb {
                let nb = [img.at(x - 1, y), img.at(x + 1, y), img.at(x, y - 1), img.at(x, y + 1)];
                let (lo, hi) = nb.iter().fold((f32::MAX, f32::MIN), |a, &v| (a.0.min(v), a.1.max(v)));
                let scale = hi.abs().max(lo.abs());
                if !(hi - lo > 1e-4 * scale) {
                    continue;
                }
                let mean = (f64::from(nb[0]) + f64::from(nb[1]) + f64::from(nb[2]) + f64::from(nb[3])) / 4.0;
                let par = (x + y) % 2;
                tested[par] += 1;
                if (f64::from(img.at(x, y)) - mean).abs() <= 1e-5 * f64::from(scale) {
                    hold[par] += 1;
                }
            }
        }
    }
    for par in 0..2 {
        let other = 1 - par;
        if tested[par] >= 1000 && hold[par] * 100 >= tested[par] * 99 && hold[other] * 2 <= tested[other] {
            return Some(other);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bilinear_demosaic_green_channel_is_recognised_and_nothing_else() {
        // Photosites from a seeded xorshift (values 0..1); green at (x + y) odd (RGGB) or
        // even (GRBG); the other sites the mean of their four neighbours, as a bilinear
        // demosaic's green channel.
        let (w, h) = (200, 136);
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f32 / (1u64 << 53) as f32
        };
        let raw: Vec<f32> = (0..w * h).map(|_| rnd()).collect();
        for genuine in [0usize, 1] {
            let mut g = raw.clone();
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    if (x + y) % 2 != genuine {
                        let i = y * w + x;
                        g[i] = (raw[i - 1] + raw[i + 1] + raw[i - w] + raw[i + w]) / 4.0;
                    }
                }
            }
            let img = GrayImage::new(w, h, &g).unwrap();
            assert_eq!(demosaic_green_parity(&img, &[Window::all(&img)], 8), Some(genuine));
            // Scaled (any linear scale) it still is one.
            let scaled: Vec<f32> = g.iter().map(|v| 1000.0 * v).collect();
            assert_eq!(
                demosaic_green_parity(&GrayImage::new(w, h, &scaled).unwrap(), &[Window::new(0, 0, w, h)], 8),
                Some(genuine)
            );
        }
        // Not one: the raw values themselves, a flat image, a smooth ramp (every pixel the
        // mean of its neighbours on both parities), a 3x3 box blur.
        let img = GrayImage::new(w, h, &raw).unwrap();
        assert_eq!(demosaic_green_parity(&img, &[Window::all(&img)], 8), None);
        let flat = vec![0.5f32; w * h];
        assert_eq!(demosaic_green_parity(&GrayImage::new(w, h, &flat).unwrap(), &[Window::new(0, 0, w, h)], 8), None);
        let ramp: Vec<f32> = (0..w * h).map(|i| (i % w) as f32 * 0.01 + (i / w) as f32 * 0.003).collect();
        assert_eq!(demosaic_green_parity(&GrayImage::new(w, h, &ramp).unwrap(), &[Window::new(0, 0, w, h)], 8), None);
        let mut boxed = raw.clone();
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let mut s = 0.0;
                for dy in 0..3 {
                    for dx in 0..3 {
                        s += raw[(y + dy - 1) * w + x + dx - 1];
                    }
                }
                boxed[y * w + x] = s / 9.0;
            }
        }
        assert_eq!(demosaic_green_parity(&GrayImage::new(w, h, &boxed).unwrap(), &[Window::new(0, 0, w, h)], 8), None);
    }
}
