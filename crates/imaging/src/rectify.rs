//! Rectification of a frame onto the sample plane with a known pose and camera model.
//!
//! For each texel: sample-plane point -> world (`ScenePose::sample_to_world`) -> camera frame
//! (`camera_to_world⁻¹`) -> [`CameraModel::project`] (distortion included) -> image position
//! -> filtered lookup in the image.

use btfrig_core::camera::CameraModel;
use btfrig_core::pose::ScenePose;
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

/// A linear RGB image (demosaiced camera RGB), row-major, one `[R, G, B]` per pixel; pixel
/// `(x, y)` is centred on integer coordinates (the camera model's convention).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height` RGB triples.
    pub data: Vec<[f32; 3]>,
}

/// What rectification reads: linear camera RGB by pixel. A demosaiced [`LinearImage`], or a
/// [`crate::mosaic::Mosaic`] demosaiced at the pixels read.
pub trait RgbSource: Sync {
    /// Width in pixels.
    fn width(&self) -> usize;
    /// Height in pixels.
    fn height(&self) -> usize;
    /// Pixels the source holds (must be `width * height`).
    fn pixels_held(&self) -> usize;
    /// The RGB of pixel `(x, y)`, `x < width`, `y < height`.
    fn rgb(&self, x: usize, y: usize) -> [f32; 3];
}

impl RgbSource for LinearImage {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn pixels_held(&self) -> usize {
        self.data.len()
    }

    #[inline]
    fn rgb(&self, x: usize, y: usize) -> [f32; 3] {
        self.data[y * self.width + x]
    }
}

/// A rectangle of the sample plane `z = 0`, metres, sample frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    /// Left edge (smallest x; column 0 lies along it).
    pub x_min: f64,
    /// Right edge.
    pub x_max: f64,
    /// Bottom edge (smallest y).
    pub y_min: f64,
    /// Top edge (row 0 lies along it).
    pub y_max: f64,
}

impl Region {
    /// The centred square of side `side` metres (the sample region of a holder plate).
    pub fn centred_square(side: f64) -> Region {
        let h = side / 2.0;
        Region { x_min: -h, x_max: h, y_min: -h, y_max: h }
    }

    /// Sample-plane position of the point at fractional texel coordinates `(col, row)` of a
    /// `width x height` grid: `(col + 0.5, row + 0.5)` is the centre of texel `(col, row)`.
    pub fn point(&self, width: usize, height: usize, col: f64, row: f64) -> (f64, f64) {
        (
            self.x_min + col * (self.x_max - self.x_min) / width as f64,
            self.y_max - row * (self.y_max - self.y_min) / height as f64,
        )
    }

    fn is_valid(&self) -> bool {
        [self.x_min, self.x_max, self.y_min, self.y_max].iter().all(|v| v.is_finite())
            && self.x_max > self.x_min
            && self.y_max > self.y_min
    }
}

/// A rectified texture: RGB per texel, row-major, row 0 at the region's `+y` edge, column 0
/// at its `-x` edge.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The region the texels tile.
    pub region: Region,
    /// `width * height` RGB triples.
    pub data: Vec<[f32; 3]>,
    /// Texels whose centre does not project into the image (behind the camera, beyond the
    /// lens model's field, or outside the frame); they are 0.
    pub texels_outside: usize,
}

/// How the image is sampled for each texel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Filter {
    /// One bilinear lookup at the texel centre. Cheapest; aliases (skips pixels, keeps their
    /// noise) wherever a texel covers more than one pixel along an image axis.
    Bilinear,
    /// `n x n` bilinear lookups on a regular grid over the texel's square, averaged (a box
    /// filter over the texel's footprint). Costs `n²` lookups per texel everywhere.
    Supersample {
        /// Sub-samples per texel axis, `1..=16` (1 is [`Filter::Bilinear`]).
        n: usize,
    },
    /// Like [`Filter::Supersample`], but the number of sub-samples along each texel axis is
    /// chosen per texel from the local Jacobian of the texel-to-image map: the length in
    /// pixels of the texel's footprint along that axis, rounded up, clamped to `1..=max`.
    /// Foreshortened axes get fewer lookups, so the cost follows the footprint.
    Footprint {
        /// Upper bound of sub-samples per texel axis, `1..=16`.
        max: usize,
    },
    /// Elliptical weighted average (after Heckbert): a Gaussian over the image pixels whose
    /// covariance is the texel's box (variance 1/12 per texel axis) pushed through the local
    /// Jacobian, plus a pixel reconstruction term (variance 1/4 px², so a texel smaller than a
    /// pixel still averages its neighbourhood like bilinear). Pixels within 3 sigma count.
    Ewa,
}

/// Why a rectification was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RectifyError {
    /// The image's data length does not match its size.
    #[error("image is {width}x{height} but holds {len} pixels")]
    ImageSize {
        /// Declared width.
        width: usize,
        /// Declared height.
        height: usize,
        /// Pixels in `data`.
        len: usize,
    },
    /// The image is not the size of the camera model.
    #[error("image is {image_w}x{image_h} but the camera model is {camera_w}x{camera_h}")]
    CameraSize {
        /// Image width.
        image_w: usize,
        /// Image height.
        image_h: usize,
        /// Camera width.
        camera_w: usize,
        /// Camera height.
        camera_h: usize,
    },
    /// The texture size is out of range.
    #[error("texture size {0} out of range, allowed 1..=16384")]
    Size(usize),
    /// The region is empty or not finite.
    #[error("region {0:?} is invalid: edges must be finite with x_max > x_min and y_max > y_min")]
    Region(Region),
    /// A filter parameter is out of range.
    #[error("filter {0:?}: sub-samples per axis out of range, allowed 1..=16")]
    Filter(Filter),
    /// Two textures (or a texture and its side data) differ in size.
    #[error("size mismatch: {what} has {got} entries, expected {expected}")]
    Mismatch {
        /// What was compared.
        what: &'static str,
        /// Entries found.
        got: usize,
        /// Entries expected.
        expected: usize,
    },
    /// A radiometric parameter is out of range.
    #[error("radiometry: {name} = {value} is invalid, allowed {allowed}")]
    Radiometry {
        /// Parameter name.
        name: &'static str,
        /// Offending value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
}

/// Checks the image against itself and the camera.
fn check_image<I: RgbSource + ?Sized>(img: &I, camera: &CameraModel) -> Result<(), RectifyError> {
    let (width, height) = (img.width(), img.height());
    if img.pixels_held() != width * height {
        return Err(RectifyError::ImageSize { width, height, len: img.pixels_held() });
    }
    if (width, height) != (camera.width, camera.height) {
        return Err(RectifyError::CameraSize {
            image_w: width,
            image_h: height,
            camera_w: camera.width,
            camera_h: camera.height,
        });
    }
    Ok(())
}

pub(crate) fn check_geometry(region: &Region, size: usize) -> Result<(), RectifyError> {
    if !(1..=16384).contains(&size) {
        return Err(RectifyError::Size(size));
    }
    if !region.is_valid() {
        return Err(RectifyError::Region(*region));
    }
    Ok(())
}

/// The map from sample-frame points to camera-frame points of a pose.
pub(crate) fn sample_to_camera(pose: &ScenePose) -> Isometry3<f64> {
    pose.camera_to_world.inverse() * pose.sample_to_world
}

/// Bilinear lookup at image position `(x, y)` (integer = pixel centre), edge pixels
/// extended; `None` outside the image area `[-0.5, w - 0.5] x [-0.5, h - 0.5]`.
#[inline]
pub(crate) fn bilinear<I: RgbSource + ?Sized>(img: &I, x: f64, y: f64) -> Option<[f32; 3]> {
    let (w, h) = (img.width(), img.height());
    if !(x >= -0.5 && y >= -0.5 && x <= w as f64 - 0.5 && y <= h as f64 - 0.5) {
        return None;
    }
    // Clamp to the centres of the outer pixels: the half pixel beyond them repeats the edge.
    let xc = x.clamp(0.0, (w - 1) as f64);
    let yc = y.clamp(0.0, (h - 1) as f64);
    let x0 = (xc.floor() as usize).min(w.saturating_sub(2));
    let y0 = (yc.floor() as usize).min(h.saturating_sub(2));
    let x1 = (x0 + 1).min(w - 1);
    let y1 = (y0 + 1).min(h - 1);
    let fx = (xc - x0 as f64) as f32;
    let fy = (yc - y0 as f64) as f32;
    let (a, b, c, d) = (img.rgb(x0, y0), img.rgb(x1, y0), img.rgb(x0, y1), img.rgb(x1, y1));
    Some(std::array::from_fn(|k| {
        let top = a[k] + (b[k] - a[k]) * fx;
        let bottom = c[k] + (d[k] - c[k]) * fx;
        top + (bottom - top) * fy
    }))
}

/// Rectifies `img` (seen by `camera` in `pose`) onto `region` of the sample plane as a
/// `size x size` texture, sampling with `filter`. Values are the image's, unconverted (see
/// [`crate::radiometry`] for the conversion to a radiance factor). Texels whose centre does
/// not project into the image are 0 and counted in [`Texture::texels_outside`]; sub-samples
/// of a supersampling filter that fall outside are left out of the average.
pub fn rectify<I: RgbSource + ?Sized>(
    img: &I,
    camera: &CameraModel,
    pose: &ScenePose,
    region: Region,
    size: usize,
    filter: Filter,
) -> Result<Texture, RectifyError> {
    rectify_with(img, camera, pose, region, size, filter, false).map(|(t, _)| t)
}

/// [`rectify`] and, from the same projections of the texel centres,
/// [`crate::radiometry::vignetting_map`] (equal to it): one pass instead of two.
pub fn rectify_vignetted<I: RgbSource + ?Sized>(
    img: &I,
    camera: &CameraModel,
    pose: &ScenePose,
    region: Region,
    size: usize,
    filter: Filter,
) -> Result<(Texture, Vec<f32>), RectifyError> {
    rectify_with(img, camera, pose, region, size, filter, true).map(|(t, v)| (t, v.unwrap_or_default()))
}

/// [`rectify`], with the vignetting map when `vignetting` is set.
fn rectify_with<I: RgbSource + ?Sized>(
    img: &I,
    camera: &CameraModel,
    pose: &ScenePose,
    region: Region,
    size: usize,
    filter: Filter,
    vignetting: bool,
) -> Result<(Texture, Option<Vec<f32>>), RectifyError> {
    check_image(img, camera)?;
    check_geometry(&region, size)?;
    match filter {
        Filter::Bilinear | Filter::Ewa => {}
        Filter::Supersample { n } | Filter::Footprint { max: n } => {
            if !(1..=16).contains(&n) {
                return Err(RectifyError::Filter(filter));
            }
        }
    }
    let to_cam = sample_to_camera(pose);
    let project = |col: f64, row: f64| -> Option<(f64, f64)> {
        let (x, y) = region.point(size, size, col, row);
        let p = to_cam.transform_point(&Point3::new(x, y, 0.0));
        camera.project(&p).map(|q| (q.x, q.y))
    };
    // Image positions of the texel corners, shared by neighbouring texels: the sub-sample
    // positions of the area filters are interpolated bilinearly between them (exact for an
    // affine map; over one texel the perspective and distortion terms move a position by far
    // less than 1e-3 px), which makes the filter cost n² lookups but only about one
    // projection per texel.
    let corners: Vec<Option<(f64, f64)>> = match filter {
        Filter::Bilinear => Vec::new(),
        _ => {
            let n = size + 1;
            let mut g = vec![None; n * n];
            g.par_chunks_mut(n).enumerate().for_each(|(row, out)| {
                for (col, q) in out.iter_mut().enumerate() {
                    *q = project(col as f64, row as f64);
                }
            });
            g
        }
    };
    let mut data = vec![[0.0f32; 3]; size * size];
    let mut vig = vec![0.0f32; if vignetting { size * size } else { 0 }];
    let mut vig_rows: Vec<&mut [f32]> =
        if vignetting { vig.chunks_mut(size).collect() } else { (0..size).map(|_| Default::default()).collect() };
    let outside: usize = data
        .par_chunks_mut(size)
        .zip(vig_rows.par_iter_mut())
        .enumerate()
        .map(|(row, (out, vig_row))| {
            let mut outside = 0;
            for (col, px) in out.iter_mut().enumerate() {
                let (c, r) = (col as f64 + 0.5, row as f64 + 0.5);
                let (x, y) = region.point(size, size, c, r);
                let p = to_cam.transform_point(&Point3::new(x, y, 0.0));
                let q = camera.project(&p);
                if vignetting {
                    // As `vignetting_map` computes it, from this same projection.
                    if let Some(q) = q.filter(|q| camera.in_image(*q)) {
                        vig_row[col] = camera.vignetting_of_point(&p, q) as f32;
                    }
                }
                let centre = q.and_then(|q| bilinear(img, q.x, q.y));
                if centre.is_none() {
                    outside += 1;
                    continue;
                }
                let quad = match filter {
                    Filter::Bilinear => None,
                    _ => {
                        let at = |dc: usize, dr: usize| corners[(row + dr) * (size + 1) + col + dc];
                        match (at(0, 0), at(1, 0), at(0, 1), at(1, 1)) {
                            (Some(a), Some(b), Some(c), Some(d)) => Some([a, b, c, d]),
                            _ => None,
                        }
                    }
                };
                let (nu, nv) = match (filter, quad) {
                    (Filter::Bilinear, _) => (1, 1),
                    (Filter::Supersample { n }, _) => (n, n),
                    (Filter::Footprint { max }, Some(q)) => footprint_counts(&q, max),
                    (Filter::Footprint { max }, None) => (max, max), // edge of the field: be safe
                    (Filter::Ewa, _) => (0, 0),
                };
                if filter == Filter::Ewa {
                    *px = quad.as_ref().and_then(|q| ewa(img, q)).or(centre).unwrap_or_default();
                    continue;
                }
                *px = if nu * nv == 1 {
                    centre.unwrap_or_default()
                } else {
                    box_average(img, &project, quad.as_ref(), col as f64, row as f64, nu, nv).unwrap_or_default()
                };
            }
            outside
        })
        .sum();
    let texture = Texture { width: size, height: size, region, data, texels_outside: outside };
    Ok((texture, vignetting.then_some(vig)))
}

/// The elliptical weighted average of the image over the texel with projected corners `q`
/// (see [`Filter::Ewa`]); `None` when no pixel of the ellipse is in the image.
fn ewa<I: RgbSource + ?Sized>(img: &I, q: &[(f64, f64); 4]) -> Option<[f32; 3]> {
    let [a, b, c, d] = *q;
    let centre = ((a.0 + b.0 + c.0 + d.0) / 4.0, (a.1 + b.1 + c.1 + d.1) / 4.0);
    // Jacobian columns (pixels per texel along u and v).
    let ju = ((b.0 - a.0 + d.0 - c.0) / 2.0, (b.1 - a.1 + d.1 - c.1) / 2.0);
    let jv = ((c.0 - a.0 + d.0 - b.0) / 2.0, (c.1 - a.1 + d.1 - b.1) / 2.0);
    const PIXEL_VAR: f64 = 0.25;
    let sxx = (ju.0 * ju.0 + jv.0 * jv.0) / 12.0 + PIXEL_VAR;
    let syy = (ju.1 * ju.1 + jv.1 * jv.1) / 12.0 + PIXEL_VAR;
    let sxy = (ju.0 * ju.1 + jv.0 * jv.1) / 12.0;
    let det = sxx * syy - sxy * sxy;
    // Inverse covariance, scaled by -1/2 for the exponent.
    let (ixx, iyy, ixy) = (syy / det, sxx / det, -sxy / det);
    let (hx, hy) = (3.0 * sxx.sqrt(), 3.0 * syy.sqrt());
    let x0 = (centre.0 - hx).ceil().max(0.0) as usize;
    let y0 = (centre.1 - hy).ceil().max(0.0) as usize;
    let x1 = (centre.0 + hx).floor().min(img.width() as f64 - 1.0);
    let y1 = (centre.1 + hy).floor().min(img.height() as f64 - 1.0);
    if x1 < 0.0 || y1 < 0.0 {
        return None;
    }
    let mut sum = [0.0f64; 3];
    let mut wsum = 0.0f64;
    for y in y0..=y1 as usize {
        let dy = y as f64 - centre.1;
        for x in x0..=x1 as usize {
            let dx = x as f64 - centre.0;
            let e = ixx * dx * dx + 2.0 * ixy * dx * dy + iyy * dy * dy;
            if e > 9.0 {
                continue;
            }
            let w = (-0.5 * e).exp();
            let v = img.rgb(x, y);
            for k in 0..3 {
                sum[k] += w * f64::from(v[k]);
            }
            wsum += w;
        }
    }
    (wsum > 0.0).then(|| sum.map(|s| (s / wsum) as f32))
}

/// Sub-samples per texel axis from the texel's footprint in the image: the pixel lengths of
/// the images of the texel's two centre lines (the columns of the local Jacobian, from the
/// projected corners `[top-left, top-right, bottom-left, bottom-right]`), rounded up, clamped
/// to `1..=max`.
fn footprint_counts(q: &[(f64, f64); 4], max: usize) -> (usize, usize) {
    let [a, b, c, d] = *q;
    let lu = ((b.0 - a.0 + d.0 - c.0) / 2.0).hypot((b.1 - a.1 + d.1 - c.1) / 2.0);
    let lv = ((c.0 - a.0 + d.0 - b.0) / 2.0).hypot((c.1 - a.1 + d.1 - b.1) / 2.0);
    let n = |l: f64| (l.ceil() as usize).clamp(1, max);
    (n(lu), n(lv))
}

/// Mean of `nu x nv` bilinear lookups at the centres of a regular sub-grid of texel
/// `(col, row)`; `None` when none of them lands in the image. Sub-sample positions come
/// from the projected corners `quad` when given, else from `project`.
fn box_average<I: RgbSource + ?Sized>(
    img: &I,
    project: &impl Fn(f64, f64) -> Option<(f64, f64)>,
    quad: Option<&[(f64, f64); 4]>,
    col: f64,
    row: f64,
    nu: usize,
    nv: usize,
) -> Option<[f32; 3]> {
    let mut sum = [0.0f32; 3];
    let mut count = 0u32;
    for j in 0..nv {
        let t = (j as f64 + 0.5) / nv as f64;
        for i in 0..nu {
            let s = (i as f64 + 0.5) / nu as f64;
            let pos = match quad {
                Some(&[a, b, c, d]) => {
                    let lerp = |p: (f64, f64), q: (f64, f64), w: f64| (p.0 + (q.0 - p.0) * w, p.1 + (q.1 - p.1) * w);
                    Some(lerp(lerp(a, b, s), lerp(c, d, s), t))
                }
                None => project(col + s, row + t),
            };
            if let Some(v) = pos.and_then(|(x, y)| bilinear(img, x, y)) {
                for k in 0..3 {
                    sum[k] += v[k];
                }
                count += 1;
            }
        }
    }
    (count > 0).then(|| sum.map(|s| s / count as f32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::Direction;

    fn ramp(w: usize, h: usize) -> LinearImage {
        let data = (0..h).flat_map(|y| (0..w).map(move |x| [x as f32, y as f32, 1.0])).collect();
        LinearImage { width: w, height: h, data }
    }

    #[test]
    fn bilinear_is_exact_on_a_linear_ramp_and_pins_pixel_centres() {
        let img = ramp(8, 6);
        assert_eq!(bilinear(&img, 3.0, 2.0), Some([3.0, 2.0, 1.0]));
        let v = bilinear(&img, 3.25, 4.5).unwrap();
        assert!((v[0] - 3.25).abs() < 1e-6 && (v[1] - 4.5).abs() < 1e-6);
        // The half pixel beyond the outer centres repeats the edge; beyond it is outside.
        assert_eq!(bilinear(&img, -0.5, 0.0), Some([0.0, 0.0, 1.0]));
        assert_eq!(bilinear(&img, 7.5, 5.5), Some([7.0, 5.0, 1.0]));
        assert_eq!(bilinear(&img, -0.51, 0.0), None);
        assert_eq!(bilinear(&img, 0.0, 5.51), None);
    }

    #[test]
    fn frontal_pinhole_rectification_reproduces_the_projected_ramp() {
        // Frontal pinhole: image x = cx + f X / d. With the image value equal to the pixel x
        // coordinate, each texel must hold the x pixel coordinate of its centre (bilinear is
        // exact on a linear ramp; the box average of a linear function is its centre value).
        let cam = CameraModel::pinhole(200, 150, 1000.0).unwrap();
        let pose =
            ScenePose::looking_at(Direction::from_degrees(30.0, 0.0), Direction::from_degrees(0.0, 0.0), 1.0, 2.0);
        let img = ramp(200, 150);
        let region = Region::centred_square(0.1);
        for filter in [Filter::Bilinear, Filter::Supersample { n: 3 }, Filter::Footprint { max: 4 }] {
            let t = rectify(&img, &cam, &pose, region, 16, filter).unwrap();
            assert_eq!(t.texels_outside, 0);
            for row in 0..16 {
                for col in 0..16 {
                    let (x, y) = region.point(16, 16, col as f64 + 0.5, row as f64 + 0.5);
                    let q = cam.project(&sample_to_camera(&pose).transform_point(&Point3::new(x, y, 0.0))).unwrap();
                    let v = t.data[row * 16 + col];
                    assert!((f64::from(v[0]) - q.x).abs() < 1e-3, "{filter:?} ({col},{row}) {} vs {}", v[0], q.x);
                    assert!((f64::from(v[1]) - q.y).abs() < 1e-3, "{filter:?} ({col},{row})");
                }
            }
            // Row 0 is the +y edge; looking_at puts image x along sample x for a frontal view,
            // so column order must follow image x.
            assert!(t.data[15][0] > t.data[0][0]);
        }
    }

    #[test]
    fn bad_inputs_are_refused_with_their_values() {
        let cam = CameraModel::pinhole(20, 10, 100.0).unwrap();
        let pose =
            ScenePose::looking_at(Direction::from_degrees(30.0, 0.0), Direction::from_degrees(0.0, 0.0), 1.0, 2.0);
        let img = ramp(20, 10);
        let r = Region::centred_square(0.1);
        assert_eq!(rectify(&img, &cam, &pose, r, 0, Filter::Bilinear), Err(RectifyError::Size(0)));
        let f = Filter::Supersample { n: 0 };
        assert_eq!(rectify(&img, &cam, &pose, r, 8, f), Err(RectifyError::Filter(f)));
        let bad = Region { x_min: 0.1, ..r };
        assert_eq!(rectify(&img, &cam, &pose, bad, 8, Filter::Bilinear), Err(RectifyError::Region(bad)));
        let small = ramp(10, 10);
        assert!(matches!(rectify(&small, &cam, &pose, r, 8, Filter::Bilinear), Err(RectifyError::CameraSize { .. })));
        // A region far off to the side does not project into the image: all texels outside.
        let off = Region { x_min: 5.0, x_max: 6.0, y_min: 5.0, y_max: 6.0 };
        let t = rectify(&img, &cam, &pose, off, 4, Filter::Bilinear).unwrap();
        assert_eq!(t.texels_outside, 16);
        assert!(t.data.iter().all(|v| *v == [0.0; 3]));
    }
}
