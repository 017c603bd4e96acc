//! From a raw frame to something a person can look at: bilinear demosaicing to linear camera
//! RGB, and an 8-bit sRGB preview (white balance, camera-to-output matrix, sRGB encoding).
//!
//! Bilinear: each missing channel at a photosite is the mean of the photosites of that
//! channel in its 3x3 neighbourhood (2 or 4 of them on a Bayer mosaic; fewer at the border,
//! where only neighbours inside the image count). Good enough for previews; calibration works
//! on the raw mosaic.

use btfrig_core::frame::{BayerPattern, RawFrame};
use rayon::prelude::*;

/// A linear camera-RGB image, row-major, one `[R, G, B]` per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraRgbImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Values as fractions of the white level above black: `(DN - black) / (white - black)`.
    pub data: Vec<[f32; 3]>,
}

/// Bilinear demosaic of `raw` to linear camera RGB, scaled so that the white level is 1 and
/// the black level 0 (values below black stay negative: noise is not clipped). A
/// monochrome frame gives equal channels.
pub fn demosaic_bilinear(raw: &RawFrame) -> CameraRgbImage {
    let (w, h) = (raw.width, raw.height);
    let black = f32::from(raw.meta.black_level);
    let range = (f32::from(raw.meta.white_level) - black).max(1.0);
    let norm = |i: usize| (f32::from(raw.data[i]) - black) / range;
    CameraRgbImage { width: w, height: h, data: bilinear(w, h, raw.meta.bayer, norm) }
}

/// Rows per parallel job of [`bilinear`]: the job normalises its rows and one more on each
/// side once, so each photosite is normalised about 1.1 times instead of 9.
const ROWS_PER_JOB: usize = 32;

/// The bilinear demosaic of the mosaic `value(y * w + x)`, every pixel exactly as
/// [`bilinear_pixel`] computes it: inside the border each channel's neighbours (a pair, a
/// cross or the diagonals) are summed in the same row-major order from rows normalised once
/// per job, without per-neighbour channel lookups; the border pixels go through
/// [`bilinear_pixel`] itself.
fn bilinear(w: usize, h: usize, bayer: Option<BayerPattern>, value: impl Fn(usize) -> f32 + Sync) -> Vec<[f32; 3]> {
    let mut data = vec![[0.0f32; 3]; w * h];
    let Some(bayer) = bayer else {
        data.par_iter_mut().enumerate().for_each(|(i, o)| *o = [value(i); 3]);
        return data;
    };
    data.par_chunks_mut((ROWS_PER_JOB * w).max(1)).enumerate().for_each(|(job, rows)| {
        let y0 = job * ROWS_PER_JOB;
        let n = rows.len() / w.max(1);
        // Normalised rows y0 - 1 ..= y0 + n (those inside the image).
        let (ya, yb) = (y0.saturating_sub(1), (y0 + n + 1).min(h));
        let norm: Vec<f32> = (ya * w..yb * w).map(&value).collect();
        for (r, row) in rows.chunks_mut(w).enumerate() {
            let y = y0 + r;
            if y == 0 || y + 1 == h || w < 3 {
                for (x, out) in row.iter_mut().enumerate() {
                    *out = bilinear_pixel(w, h, bayer, x, y, &value);
                }
                continue;
            }
            row[0] = bilinear_pixel(w, h, bayer, 0, y, &value);
            row[w - 1] = bilinear_pixel(w, h, bayer, w - 1, y, &value);
            let (up, mid, down) = (
                &norm[(y - 1 - ya) * w..(y - ya) * w],
                &norm[(y - ya) * w..(y + 1 - ya) * w],
                &norm[(y + 1 - ya) * w..(y + 2 - ya) * w],
            );
            for (x, out) in row.iter_mut().enumerate().take(w - 1).skip(1) {
                *out = interior_pixel(bayer, x, y, |dx, dy| {
                    let line = [up, mid, down][dy];
                    line[x + dx - 1]
                });
            }
        }
    });
    data
}

/// One pixel of the bilinear demosaic away from the border (`0 < x < w - 1`,
/// `0 < y < h - 1`), `v(dx, dy)` the normalised photosite at `(x + dx - 1, y + dy - 1)`: on a
/// Bayer mosaic a green site has its two other channels as a horizontal and a vertical pair,
/// a red or blue site has green as a cross and the other as the diagonals; the sums run from
/// 0 in the row-major order of [`bilinear_pixel`], so the result is its, bit for bit.
#[inline(always)]
pub(crate) fn interior_pixel(bayer: BayerPattern, x: usize, y: usize, v: impl Fn(usize, usize) -> f32) -> [f32; 3] {
    let mut out = [0.0f32; 3];
    let own = bayer.channel_at(x, y);
    let (l, c, r) = (v(0, 1), v(1, 1), v(2, 1));
    let (u, d) = (v(1, 0), v(1, 2));
    if own == 1 {
        let horizontal = (0.0 + l + r) / 2.0;
        let vertical = (0.0 + u + d) / 2.0;
        let hc = bayer.channel_at(x + 1, y);
        out[1] = c;
        out[hc] = horizontal;
        out[2 - hc] = vertical;
    } else {
        let cross = (0.0 + u + l + r + d) / 4.0;
        let diagonal = (0.0 + v(0, 0) + v(2, 0) + v(0, 2) + v(2, 2)) / 4.0;
        out[own] = c;
        out[1] = cross;
        out[2 - own] = diagonal;
    }
    out
}

/// One pixel of the bilinear demosaic: each missing channel the mean of its photosites in the
/// 3x3 neighbourhood that lie inside the image, summed in row-major order.
pub(crate) fn bilinear_pixel(
    w: usize,
    h: usize,
    bayer: BayerPattern,
    x: usize,
    y: usize,
    value: &impl Fn(usize) -> f32,
) -> [f32; 3] {
    let mut sum = [0.0f32; 3];
    let mut count = [0u32; 3];
    for yy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
        for xx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
            let c = bayer.channel_at(xx, yy);
            sum[c] += value(yy * w + xx);
            count[c] += 1;
        }
    }
    let own = bayer.channel_at(x, y);
    std::array::from_fn(|c| {
        if c == own {
            value(y * w + x)
        } else if count[c] > 0 {
            sum[c] / count[c] as f32
        } else {
            0.0 // a 1-pixel-wide image lacks the channel entirely
        }
    })
}

/// An 8-bit sRGB preview, interleaved `RGBRGB...`, row-major: per pixel
/// `srgb_encode(clamp(exposure · M · (wb ⊙ rgb), 0, 1))`, rounded. `wb` and `M` usually come
/// from a colour calibration or the simulator's manufacturer-style matrix.
pub fn preview_srgb8(img: &CameraRgbImage, white_balance: [f64; 3], matrix: &[[f64; 3]; 3], exposure: f64) -> Vec<u8> {
    // Fold white balance and exposure into one matrix.
    let m: [[f32; 3]; 3] =
        std::array::from_fn(|r| std::array::from_fn(|c| (matrix[r][c] * white_balance[c] * exposure) as f32));
    // The sRGB curve through a 4096-entry table: previews need 8 bits, not powf per pixel.
    const N: usize = 4096;
    let lut: Vec<u8> =
        (0..N).map(|i| (btfrig_color::space::srgb_encode(i as f64 / (N - 1) as f64) * 255.0).round() as u8).collect();
    let mut out = vec![0u8; img.width * img.height * 3];
    out.par_chunks_mut(3 * img.width.max(1)).zip(img.data.par_chunks(img.width.max(1))).for_each(|(o, row)| {
        for (px, v) in o.chunks_exact_mut(3).zip(row) {
            for r in 0..3 {
                let lin = m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2];
                let idx = (lin.clamp(0.0, 1.0) * (N - 1) as f32).round() as usize;
                px[r] = lut[idx];
            }
        }
    });
    out
}

/// Bilinear demosaic, as [`demosaic_bilinear`], of a mosaic of already-normalised values
/// (`values[y * width + x]`, e.g. a raw frame after dark subtraction and flat-field division),
/// with `bayer` its colour filter array (`None`: monochrome, equal channels).
pub fn demosaic_bilinear_values(
    width: usize,
    height: usize,
    bayer: Option<btfrig_core::frame::BayerPattern>,
    values: &[f32],
) -> CameraRgbImage {
    CameraRgbImage { width, height, data: bilinear(width, height, bayer, |i| values[i]) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::frame::{BayerPattern, FrameMeta};

    fn frame(w: usize, h: usize, bayer: Option<BayerPattern>, f: impl Fn(usize, usize, usize) -> u16) -> RawFrame {
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y, bayer.map_or(1, |b| b.channel_at(x, y))))
            .collect();
        RawFrame {
            width: w,
            height: h,
            data,
            meta: FrameMeta {
                sequence: 0,
                exposure_s: 0.01,
                gain: 1.0,
                f_number: None,
                black_level: 100,
                white_level: 1100,
                bit_depth: 12,
                bayer,
                timestamp_s: 0.0,
                temperature_c: None,
            },
        }
    }

    #[test]
    fn flat_colour_field_is_recovered_exactly_for_every_pattern() {
        for p in [BayerPattern::Rggb, BayerPattern::Bggr, BayerPattern::Grbg, BayerPattern::Gbrg] {
            let raw = frame(9, 7, Some(p), |_, _, c| [600, 350, 850][c]);
            let img = demosaic_bilinear(&raw);
            for v in &img.data {
                assert_eq!(*v, [0.5, 0.25, 0.75], "{p:?}");
            }
        }
    }

    #[test]
    fn demosaic_of_values_equals_demosaic_of_the_normalised_raw_frame() {
        for bayer in [Some(BayerPattern::Grbg), None] {
            let raw = frame(11, 6, bayer, |x, y, c| (100 + 37 * x + 11 * y * y + 90 * c) as u16);
            let values: Vec<f32> = raw.data.iter().map(|&v| (f32::from(v) - 100.0) / 1000.0).collect();
            assert_eq!(demosaic_bilinear_values(11, 6, bayer, &values), demosaic_bilinear(&raw), "{bayer:?}");
        }
    }

    #[test]
    fn the_row_kernel_equals_the_per_pixel_definition_bit_for_bit() {
        // Seeded values (negative ones included), every pattern, odd and even sizes, images
        // taller than one parallel job and thinner than three pixels.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32 * 1.3 - 0.1
        };
        for (w, h) in [(37, 70), (36, 33), (2, 5), (5, 1), (64, 64)] {
            let values: Vec<f32> = (0..w * h).map(|_| rnd()).collect();
            for p in [BayerPattern::Rggb, BayerPattern::Bggr, BayerPattern::Grbg, BayerPattern::Gbrg] {
                let fast = demosaic_bilinear_values(w, h, Some(p), &values);
                for y in 0..h {
                    for x in 0..w {
                        let slow = bilinear_pixel(w, h, p, x, y, &|i| values[i]);
                        assert_eq!(
                            fast.data[y * w + x].map(f32::to_bits),
                            slow.map(f32::to_bits),
                            "{p:?} {w}x{h} ({x}, {y})"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn linear_ramp_is_interpolated_exactly_inside() {
        // Bilinear interpolation reproduces a linear function away from the border.
        let raw = frame(10, 10, Some(BayerPattern::Rggb), |x, y, _| (100 + 10 * x + 20 * y) as u16);
        let img = demosaic_bilinear(&raw);
        for y in 1..9 {
            for x in 1..9 {
                let expect = (10 * x + 20 * y) as f32 / 1000.0;
                for c in 0..3 {
                    assert!((img.data[y * 10 + x][c] - expect).abs() < 1e-6, "({x},{y}) c{c}");
                }
            }
        }
    }

    #[test]
    fn mono_replicates_and_preview_encodes_srgb() {
        let raw = frame(4, 3, None, |x, _, _| if x == 0 { 100 } else { 1100 });
        let img = demosaic_bilinear(&raw);
        assert_eq!(img.data[0], [0.0; 3]);
        assert_eq!(img.data[1], [1.0; 3]);
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let p = preview_srgb8(&img, [1.0; 3], &id, 0.18);
        assert_eq!(&p[0..3], &[0, 0, 0]);
        // 0.18 linear -> 0.4614 encoded -> 118.
        assert_eq!(&p[3..6], &[118, 118, 118]);
        let p = preview_srgb8(&img, [1.0; 3], &id, 2.0);
        assert_eq!(&p[3..6], &[255, 255, 255]); // clipped
    }
}
