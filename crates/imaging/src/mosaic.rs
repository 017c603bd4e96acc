//! A frame's photosite mosaic read in place: the bilinear demosaic's value at any pixel,
//! computed from the photosites around it when it is read, so that a frame is never
//! demosaiced whole. The marker search reads the green channel only in its windows, the
//! rectification reads RGB only under the sample's footprint.
//!
//! Every value equals, bit for bit, the same pixel of [`crate::demosaic::demosaic_bilinear`]
//! (or [`crate::demosaic::demosaic_bilinear_values`]): the same normalisation, the same sums
//! in the same order ([`crate::demosaic`]'s `interior_pixel` and `bilinear_pixel`).

use btfrig_core::frame::{BayerPattern, RawFrame};
use rayon::prelude::*;

use crate::demosaic::{bilinear_pixel, interior_pixel};
use crate::rectify::RgbSource;

/// Where a mosaic's normalised photosite values come from.
#[derive(Debug, Clone, Copy)]
enum Values<'a> {
    /// Raw DN, normalised when read: `(DN - black) / range`.
    Raw { data: &'a [u16], black: f32, range: f32 },
    /// Already normalised (dark/flat-corrected or merged).
    Normalised(&'a [f32]),
}

/// A mosaic of normalised photosite values (`(DN - black) / (white - black)`), row-major,
/// with its colour filter array (`None`: monochrome, equal channels).
#[derive(Debug, Clone, Copy)]
pub struct Mosaic<'a> {
    /// Width in photosites.
    pub width: usize,
    /// Height in photosites.
    pub height: usize,
    /// Colour filter array; `None` for a monochrome sensor.
    pub bayer: Option<BayerPattern>,
    values: Values<'a>,
}

/// Why a mosaic cannot be made.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("mosaic of {width} x {height} photosites needs {} values, got {len} (allowed: width, height > 0)", width * height)]
pub struct MosaicSizeError {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Values given.
    pub len: usize,
}

impl<'a> Mosaic<'a> {
    /// The raw frame's photosites, normalised as [`crate::demosaic::demosaic_bilinear`] does.
    pub fn of_raw(raw: &'a RawFrame) -> Result<Self, MosaicSizeError> {
        let black = f32::from(raw.meta.black_level);
        let range = (f32::from(raw.meta.white_level) - black).max(1.0);
        Self::checked(
            raw.width,
            raw.height,
            raw.meta.bayer,
            raw.data.len(),
            Values::Raw { data: &raw.data, black, range },
        )
    }

    /// Already normalised values, as [`crate::demosaic::demosaic_bilinear_values`] takes them.
    pub fn of_values(
        width: usize,
        height: usize,
        bayer: Option<BayerPattern>,
        values: &'a [f32],
    ) -> Result<Self, MosaicSizeError> {
        Self::checked(width, height, bayer, values.len(), Values::Normalised(values))
    }

    fn checked(
        width: usize,
        height: usize,
        bayer: Option<BayerPattern>,
        len: usize,
        values: Values<'a>,
    ) -> Result<Self, MosaicSizeError> {
        if width == 0 || height == 0 || len != width * height {
            return Err(MosaicSizeError { width, height, len });
        }
        Ok(Mosaic { width, height, bayer, values })
    }

    /// The normalised photosite `i` (row-major).
    #[inline(always)]
    fn value(&self, i: usize) -> f32 {
        match self.values {
            Values::Raw { data, black, range } => (f32::from(data[i]) - black) / range,
            Values::Normalised(v) => v[i],
        }
    }

    /// The demosaiced camera RGB of pixel `(x, y)` (inside the mosaic).
    #[inline]
    pub fn rgb(&self, x: usize, y: usize) -> [f32; 3] {
        let (w, h) = (self.width, self.height);
        let Some(bayer) = self.bayer else {
            return [self.value(y * w + x); 3];
        };
        if x == 0 || y == 0 || x + 1 >= w || y + 1 >= h {
            return bilinear_pixel(w, h, bayer, x, y, &|i| self.value(i));
        }
        let base = (y - 1) * w + x - 1;
        interior_pixel(bayer, x, y, |dx, dy| self.value(base + dy * w + dx))
    }

    /// The demosaiced green of pixel `(x, y)` (inside the mosaic): [`Mosaic::rgb`]'s green,
    /// without the other channels' sums.
    #[inline]
    pub fn green(&self, x: usize, y: usize) -> f32 {
        let (w, h) = (self.width, self.height);
        let i = y * w + x;
        let Some(bayer) = self.bayer else {
            return self.value(i);
        };
        if bayer.channel_at(x, y) == 1 {
            return self.value(i);
        }
        if x == 0 || y == 0 || x + 1 >= w || y + 1 >= h {
            return bilinear_pixel(w, h, bayer, x, y, &|i| self.value(i))[1];
        }
        // The cross, summed as `interior_pixel` sums it.
        (0.0 + self.value(i - w) + self.value(i - 1) + self.value(i + 1) + self.value(i + w)) / 4.0
    }

    /// Writes the demosaiced green of columns `x0..x1`, rows `y0..y1` (clipped to the mosaic)
    /// into `out`, a row-major buffer of the whole mosaic; rows in parallel.
    pub fn fill_green(&self, (x0, y0, x1, y1): (usize, usize, usize, usize), out: &mut [f32]) {
        let (w, h) = (self.width, self.height);
        let (x1, y1) = (x1.min(w), y1.min(h));
        if x0 >= x1 || y0 >= y1 || out.len() != w * h {
            return;
        }
        out[y0 * w..y1 * w].par_chunks_mut(w).enumerate().for_each(|(r, row)| {
            let y = y0 + r;
            for (x, o) in row.iter_mut().enumerate().take(x1).skip(x0) {
                *o = self.green(x, y);
            }
        });
    }
}

impl RgbSource for Mosaic<'_> {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn pixels_held(&self) -> usize {
        match self.values {
            Values::Raw { data, .. } => data.len(),
            Values::Normalised(v) => v.len(),
        }
    }

    #[inline]
    fn rgb(&self, x: usize, y: usize) -> [f32; 3] {
        Mosaic::rgb(self, x, y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::demosaic::{demosaic_bilinear, demosaic_bilinear_values};
    use btfrig_core::frame::FrameMeta;

    fn xorshift(seed: u64) -> impl FnMut() -> u64 {
        let mut state = seed;
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        }
    }

    fn raw(w: usize, h: usize, bayer: Option<BayerPattern>, seed: u64) -> RawFrame {
        let mut rnd = xorshift(seed);
        RawFrame {
            width: w,
            height: h,
            // Below black too: noise is not clipped.
            data: (0..w * h).map(|_| (rnd() % 4200) as u16).collect(),
            meta: FrameMeta {
                sequence: 0,
                exposure_s: 0.01,
                gain: 1.0,
                f_number: None,
                black_level: 64,
                white_level: 4095,
                bit_depth: 12,
                bayer,
                timestamp_s: 0.0,
                temperature_c: None,
            },
        }
    }

    const PATTERNS: [Option<BayerPattern>; 5] =
        [Some(BayerPattern::Rggb), Some(BayerPattern::Bggr), Some(BayerPattern::Grbg), Some(BayerPattern::Gbrg), None];

    #[test]
    fn every_pixel_is_the_whole_frame_demosaics_bit_for_bit() {
        // Seeded photosites, every pattern and mono, odd and even sizes, thin images.
        for (k, (w, h)) in [(37, 70), (36, 33), (2, 5), (5, 1), (1, 1), (64, 64)].into_iter().enumerate() {
            for (p, bayer) in PATTERNS.into_iter().enumerate() {
                let frame = raw(w, h, bayer, 0x9e37_79b9_7f4a_7c15 + (10 * k + p) as u64);
                let whole = demosaic_bilinear(&frame);
                let m = Mosaic::of_raw(&frame).unwrap();
                let values: Vec<f32> = frame.data.iter().map(|&v| (f32::from(v) - 64.0) / 4031.0).collect();
                let whole_values = demosaic_bilinear_values(w, h, bayer, &values);
                let mv = Mosaic::of_values(w, h, bayer, &values).unwrap();
                let mut green = vec![f32::NAN; w * h];
                m.fill_green((0, 0, w, h), &mut green);
                for y in 0..h {
                    for x in 0..w {
                        let i = y * w + x;
                        let at = format!("{bayer:?} {w}x{h} ({x}, {y})");
                        assert_eq!(m.rgb(x, y).map(f32::to_bits), whole.data[i].map(f32::to_bits), "{at}");
                        assert_eq!(mv.rgb(x, y).map(f32::to_bits), whole_values.data[i].map(f32::to_bits), "{at}");
                        assert_eq!(m.green(x, y).to_bits(), whole.data[i][1].to_bits(), "{at}");
                        assert_eq!(green[i].to_bits(), whole.data[i][1].to_bits(), "{at}");
                    }
                }
            }
        }
    }

    #[test]
    fn green_is_filled_only_inside_the_window_and_sizes_are_checked() {
        let frame = raw(20, 12, Some(BayerPattern::Grbg), 7);
        let m = Mosaic::of_raw(&frame).unwrap();
        let mut out = vec![-9.0f32; 20 * 12];
        m.fill_green((3, 2, 9, 30), &mut out);
        for y in 0..12 {
            for x in 0..20 {
                let inside = (3..9).contains(&x) && (2..12).contains(&y);
                assert_eq!(out[y * 20 + x] != -9.0, inside, "({x}, {y})");
            }
        }
        let e = Mosaic::of_values(4, 3, None, &[0.0; 11]).unwrap_err();
        assert_eq!(e, MosaicSizeError { width: 4, height: 3, len: 11 });
        assert!(e.to_string().contains("needs 12 values, got 11"), "{e}");
    }

    #[test]
    fn rectifying_the_mosaic_gives_the_demosaiced_frames_texture_and_vignetting_bit_for_bit() {
        use crate::{rectify, rectify_vignetted, vignetting_map, Filter, LinearImage, Region};
        use btfrig_core::camera::{CameraModel, Distortion, Vignetting};
        use btfrig_core::pose::ScenePose;
        use btfrig_core::Direction;
        // A distorting, vignetting lens; a frontal and a grazing view; every filter (the
        // area filters read many pixels per texel, the border included at the grazing view).
        let (w, h) = (160, 120);
        let dist = Distortion { k1: -0.08, k2: 0.02, k3: 0.0, p1: 1e-4, p2: -1.5e-4 };
        let vig = Vignetting { cos4: true, poly: [-0.1, 0.0, 0.0] };
        let cam = CameraModel::new(w, h, 480.0, 481.0, 80.3, 59.2, dist, vig).unwrap();
        let frame = raw(w, h, Some(BayerPattern::Rggb), 42);
        let mosaic = Mosaic::of_raw(&frame).unwrap();
        let dm = demosaic_bilinear(&frame);
        let whole = LinearImage { width: dm.width, height: dm.height, data: dm.data };
        let region = Region::centred_square(0.12);
        let filters = [Filter::Bilinear, Filter::Supersample { n: 3 }, Filter::Footprint { max: 4 }, Filter::Ewa];
        for view in [(0.0, 0.0), (78.0, 90.0)] {
            let light = Direction::from_degrees(45.0, 0.0);
            let pose = ScenePose::looking_at(light, Direction::from_degrees(view.0, view.1), 1.0, 2.0);
            for filter in filters {
                let a = rectify(&mosaic, &cam, &pose, region, 48, filter).unwrap();
                let b = rectify(&whole, &cam, &pose, region, 48, filter).unwrap();
                assert!(a.texels_outside < 48 * 48, "{view:?}: the sample must be in view");
                let bits = |t: &crate::Texture| t.data.iter().map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
                assert_eq!(bits(&a), bits(&b), "{view:?} {filter:?}");
                assert_eq!(a.texels_outside, b.texels_outside);
                let (c, v) = rectify_vignetted(&mosaic, &cam, &pose, region, 48, filter).unwrap();
                assert_eq!(bits(&c), bits(&b), "{view:?} {filter:?}");
                let map = vignetting_map(&cam, &pose, region, 48).unwrap();
                assert_eq!(
                    v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                    map.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
                );
                assert!(v.iter().any(|&x| x > 0.0 && x < 1.0));
            }
        }
    }
}
