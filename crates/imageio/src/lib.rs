//! Image files of btfrig: raw sensor frames and linear RGB images as OpenEXR and PNG.
//!
//! Brief overview: a [`RawFrame`] is written either as a 16-bit greyscale PNG holding the
//! digital numbers as they are ([`write_raw_png`], [`read_raw_png`]) or as a single-channel
//! OpenEXR file ([`write_raw_exr`], [`read_raw_exr`]) whose channel `Y` holds the DN as
//! 32-bit floats (exact: every u16 is a float) and whose header carries the frame's metadata
//! as JSON in the text attribute `btfrig.frame_meta`, so an EXR round trip restores the whole
//! frame. [`write_raw_frame`] picks the format from the extension. Linear RGB images (the
//! renderer's ground truth, demosaiced frames) are OpenEXR with float channels `R`, `G`, `B`
//! and sRGB / Rec. 709 chromaticities in the header ([`write_rgb_exr`], [`read_rgb_exr`]);
//! previews are 8-bit sRGB PNG ([`write_srgb8_png`]). Every error names the file.
//!
//! ```no_run
//! # fn demo(frame: &btfrig_core::frame::RawFrame) -> Result<(), btfrig_imageio::ImageIoError> {
//! btfrig_imageio::write_raw_frame("capture.exr".as_ref(), frame)?;
//! let back = btfrig_imageio::read_raw_exr("capture.exr".as_ref())?;
//! assert_eq!(&back, frame);
//! # Ok(()) }
//! ```
#![warn(missing_docs)]

// The files, one job each:
// - lib:      raw frames and linear RGB images as OpenEXR and PNG

use std::path::{Path, PathBuf};

use btfrig_core::frame::{FrameMeta, RawFrame};
use exr::prelude::{
    AnyChannel, AnyChannels, AttributeValue, Encoding, FlatSamples, Image, Layer, LayerAttributes, ReadChannels,
    ReadLayers, SmallVec, Text, WritableImage,
};

/// Name of the EXR header attribute holding a raw frame's metadata (JSON).
pub const META_ATTRIBUTE: &str = "btfrig.frame_meta";
/// Name of the channel of a raw-frame EXR.
pub const RAW_CHANNEL: &str = "Y";

/// A failure to write or read an image file. Every variant names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImageIoError {
    /// The OpenEXR library failed (I/O or format).
    #[error("{}: OpenEXR: {message}", path.display())]
    Exr {
        /// The file.
        path: PathBuf,
        /// The library's message.
        message: String,
    },
    /// The PNG library failed (I/O or format).
    #[error("{}: PNG: {message}", path.display())]
    Png {
        /// The file.
        path: PathBuf,
        /// The library's message.
        message: String,
    },
    /// The file is readable but not what this function expects.
    #[error("{}: {message}", path.display())]
    Content {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The in-memory image is inconsistent (sizes, extension), so nothing was written.
    #[error("{}: cannot write: {message}", path.display())]
    BadInput {
        /// The file that was to be written.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

fn exr_err(path: &Path, e: impl std::fmt::Display) -> ImageIoError {
    ImageIoError::Exr { path: path.to_path_buf(), message: e.to_string() }
}
fn png_err(path: &Path, e: impl std::fmt::Display) -> ImageIoError {
    ImageIoError::Png { path: path.to_path_buf(), message: e.to_string() }
}
fn content(path: &Path, message: impl Into<String>) -> ImageIoError {
    ImageIoError::Content { path: path.to_path_buf(), message: message.into() }
}
fn bad_input(path: &Path, message: impl Into<String>) -> ImageIoError {
    ImageIoError::BadInput { path: path.to_path_buf(), message: message.into() }
}

fn check_len(path: &Path, width: usize, height: usize, len: usize) -> Result<(), ImageIoError> {
    if width == 0 || height == 0 || width * height != len {
        return Err(bad_input(path, format!("{width}x{height} image with {len} values")));
    }
    if width > u32::MAX as usize || height > u32::MAX as usize {
        return Err(bad_input(path, format!("{width}x{height} is too large")));
    }
    Ok(())
}

/// Writes `frame` with the format chosen by the extension: `.exr` ([`write_raw_exr`]) or
/// `.png` ([`write_raw_png`]).
pub fn write_raw_frame(path: &Path, frame: &RawFrame) -> Result<(), ImageIoError> {
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("exr") => write_raw_exr(path, frame),
        Some("png") => write_raw_png(path, frame),
        _ => Err(bad_input(path, "unknown extension for a raw frame: use .exr or .png")),
    }
}

/// Writes the frame's DN values as a 16-bit greyscale PNG (values as they are, not scaled).
/// The metadata is not stored: keep it elsewhere (or use EXR).
pub fn write_raw_png(path: &Path, frame: &RawFrame) -> Result<(), ImageIoError> {
    check_len(path, frame.width, frame.height, frame.data.len())?;
    let buf = image::ImageBuffer::<image::Luma<u16>, &[u16]>::from_raw(
        frame.width as u32,
        frame.height as u32,
        frame.data.as_slice(),
    )
    .ok_or_else(|| bad_input(path, "buffer size mismatch"))?;
    buf.save_with_format(path, image::ImageFormat::Png).map_err(|e| png_err(path, e))
}

/// Reads a 16-bit greyscale PNG as a raw frame with the given metadata (PNG does not carry
/// it). Any other pixel format is an error: converting would change the DN values.
pub fn read_raw_png(path: &Path, meta: FrameMeta) -> Result<RawFrame, ImageIoError> {
    let img = image::ImageReader::open(path)
        .map_err(|e| png_err(path, e))?
        .with_guessed_format()
        .map_err(|e| png_err(path, e))?
        .decode()
        .map_err(|e| png_err(path, e))?;
    let color = img.color();
    let image::DynamicImage::ImageLuma16(buf) = img else {
        return Err(content(path, format!("expected 16-bit greyscale, found {color:?}")));
    };
    let (w, h) = (buf.width() as usize, buf.height() as usize);
    Ok(RawFrame { width: w, height: h, data: buf.into_raw(), meta })
}

/// Writes the frame as single-channel OpenEXR (channel [`RAW_CHANNEL`], 32-bit float DN,
/// lossless RLE compression) with its metadata as JSON in the attribute [`META_ATTRIBUTE`].
pub fn write_raw_exr(path: &Path, frame: &RawFrame) -> Result<(), ImageIoError> {
    raw_exr_image(path, frame)?.write().to_file(path).map_err(|e| exr_err(path, e))
}

/// Encodes the frame exactly as [`write_raw_exr`] would write it, into memory (for stores
/// that write through their own storage layer). `name` only labels errors.
pub fn encode_raw_exr(name: &Path, frame: &RawFrame) -> Result<Vec<u8>, ImageIoError> {
    let mut out = std::io::Cursor::new(Vec::new());
    raw_exr_image(name, frame)?.write().to_buffered(&mut out).map_err(|e| exr_err(name, e))?;
    Ok(out.into_inner())
}

fn raw_exr_image(path: &Path, frame: &RawFrame) -> Result<Image<Layer<AnyChannels<FlatSamples>>>, ImageIoError> {
    check_len(path, frame.width, frame.height, frame.data.len())?;
    let samples: Vec<f32> = frame.data.iter().map(|&v| f32::from(v)).collect();
    let channel = AnyChannel::new(RAW_CHANNEL, FlatSamples::F32(samples));
    let mut attrs = LayerAttributes::named("raw");
    let meta = serde_json::to_string(&frame.meta).map_err(|e| bad_input(path, e.to_string()))?;
    let text = Text::new_or_none(&meta).ok_or_else(|| bad_input(path, "metadata is not representable as EXR text"))?;
    attrs.other.insert(Text::from(META_ATTRIBUTE), AttributeValue::Text(text));
    let layer = Layer::new(
        (frame.width, frame.height),
        attrs,
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(vec![channel])),
    );
    Ok(Image::from_layer(layer))
}

type FlatLayer = Layer<AnyChannels<FlatSamples>>;

fn read_flat_layer(path: &Path) -> Result<FlatLayer, ImageIoError> {
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| exr_err(path, e))?;
    Ok(image.layer_data)
}

fn decode_flat_layer(name: &Path, bytes: &[u8]) -> Result<FlatLayer, ImageIoError> {
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| exr_err(name, e))?;
    Ok(image.layer_data)
}

fn channel<'a>(path: &Path, layer: &'a FlatLayer, name: &str) -> Result<&'a FlatSamples, ImageIoError> {
    layer.channel_data.list.iter().find(|c| c.name == *name).map(|c| &c.sample_data).ok_or_else(|| {
        let names: Vec<String> = layer.channel_data.list.iter().map(|c| c.name.to_string()).collect();
        content(path, format!("no channel {name:?} (channels: {})", names.join(", ")))
    })
}

/// Reads a raw frame written by [`write_raw_exr`]: the DN values (channel [`RAW_CHANNEL`],
/// float or u32, each an integer in 0..=65535) and the metadata.
pub fn read_raw_exr(path: &Path) -> Result<RawFrame, ImageIoError> {
    raw_from_layer(path, read_flat_layer(path)?)
}

/// Decodes a raw frame held in memory, as [`read_raw_exr`] reads one from a file (e.g. from a
/// store's storage layer). `name` only labels errors.
pub fn decode_raw_exr(name: &Path, bytes: &[u8]) -> Result<RawFrame, ImageIoError> {
    raw_from_layer(name, decode_flat_layer(name, bytes)?)
}

/// Reads the DN values of a single-channel raw OpenEXR file (channel [`RAW_CHANNEL`], as
/// [`read_raw_exr`] reads them) without needing btfrig's metadata attribute: frames recorded
/// by other software (`btfrig-recorded`), whose metadata is kept elsewhere. Width, height, DNs.
pub fn read_raw_exr_dn(path: &Path) -> Result<(usize, usize, Vec<u16>), ImageIoError> {
    let layer = read_flat_layer(path)?;
    Ok((layer.size.0, layer.size.1, dn_samples(path, &layer)?))
}

fn raw_from_layer(path: &Path, layer: FlatLayer) -> Result<RawFrame, ImageIoError> {
    let (w, h) = (layer.size.0, layer.size.1);
    let meta = match layer.attributes.other.get(&Text::from(META_ATTRIBUTE)) {
        Some(AttributeValue::Text(t)) => serde_json::from_str::<FrameMeta>(&t.to_string())
            .map_err(|e| content(path, format!("attribute {META_ATTRIBUTE}: {e}")))?,
        _ => return Err(content(path, format!("no text attribute {META_ATTRIBUTE}: not a btfrig raw frame"))),
    };
    Ok(RawFrame { width: w, height: h, data: dn_samples(path, &layer)?, meta })
}

fn dn_samples(path: &Path, layer: &FlatLayer) -> Result<Vec<u16>, ImageIoError> {
    let samples = channel(path, layer, RAW_CHANNEL)?;
    let data = match samples {
        FlatSamples::U32(v) => v
            .iter()
            .enumerate()
            .map(|(i, &s)| u16::try_from(s).map_err(|_| content(path, format!("sample {i} = {s} exceeds 65535"))))
            .collect::<Result<Vec<u16>, _>>()?,
        other => other
            .values_as_f32()
            .enumerate()
            .map(|(i, s)| {
                if s.fract() == 0.0 && (0.0..=65535.0).contains(&s) {
                    Ok(s as u16)
                } else {
                    Err(content(path, format!("sample {i} = {s} is not a DN in 0..=65535")))
                }
            })
            .collect::<Result<Vec<u16>, _>>()?,
    };
    Ok(data)
}

/// Sample type of the channels of an RGB OpenEXR file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExrPrecision {
    /// 16-bit half floats: half the size, relative precision 2^-11, largest value 65504.
    Half,
    /// 32-bit floats.
    Float,
}

/// Writes a linear RGB float image as OpenEXR: float channels `R`, `G`, `B`, sRGB / Rec. 709
/// primaries and D65 white in the chromaticities attribute, lossless compression.
pub fn write_rgb_exr(path: &Path, width: usize, height: usize, data: &[[f32; 3]]) -> Result<(), ImageIoError> {
    rgb_exr_image(path, width, height, data, ExrPrecision::Float)?.write().to_file(path).map_err(|e| exr_err(path, e))
}

/// Encodes a linear RGB image like [`write_rgb_exr`] into memory, with `precision` channels
/// (half values are rounded to nearest). `name` only labels errors.
pub fn encode_rgb_exr(
    name: &Path,
    width: usize,
    height: usize,
    data: &[[f32; 3]],
    precision: ExrPrecision,
) -> Result<Vec<u8>, ImageIoError> {
    let mut out = std::io::Cursor::new(Vec::new());
    rgb_exr_image(name, width, height, data, precision)?.write().to_buffered(&mut out).map_err(|e| exr_err(name, e))?;
    Ok(out.into_inner())
}

fn rgb_exr_image(
    path: &Path,
    width: usize,
    height: usize,
    data: &[[f32; 3]],
    precision: ExrPrecision,
) -> Result<Image<Layer<AnyChannels<FlatSamples>>>, ImageIoError> {
    check_len(path, width, height, data.len())?;
    let chan = |name: &str, i: usize| {
        let samples = match precision {
            ExrPrecision::Float => FlatSamples::F32(data.iter().map(|p| p[i]).collect()),
            ExrPrecision::Half => FlatSamples::F16(data.iter().map(|p| exr::prelude::f16::from_f32(p[i])).collect()),
        };
        AnyChannel::new(name, samples)
    };
    let layer = Layer::new(
        (width, height),
        LayerAttributes::named("rgb"),
        Encoding::SMALL_FAST_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(vec![chan("R", 0), chan("G", 1), chan("B", 2)])),
    );
    let mut image = Image::from_layer(layer);
    image.attributes.chromaticities = Some(exr::meta::attribute::Chromaticities {
        red: exr::math::Vec2(0.64, 0.33),
        green: exr::math::Vec2(0.30, 0.60),
        blue: exr::math::Vec2(0.15, 0.06),
        white: exr::math::Vec2(0.3127, 0.3290),
    });
    Ok(image)
}

/// Reads the `R`, `G`, `B` channels of an OpenEXR file as linear floats:
/// `(width, height, row-major pixels)`.
pub fn read_rgb_exr(path: &Path) -> Result<(usize, usize, Vec<[f32; 3]>), ImageIoError> {
    rgb_from_layer(path, read_flat_layer(path)?)
}

/// Decodes an RGB OpenEXR image held in memory, as [`read_rgb_exr`] reads one from a file
/// (e.g. a calibration embedded in the binary). `name` only labels errors.
pub fn decode_rgb_exr(name: &Path, bytes: &[u8]) -> Result<(usize, usize, Vec<[f32; 3]>), ImageIoError> {
    rgb_from_layer(name, decode_flat_layer(name, bytes)?)
}

fn rgb_from_layer(path: &Path, layer: FlatLayer) -> Result<(usize, usize, Vec<[f32; 3]>), ImageIoError> {
    let (w, h) = (layer.size.0, layer.size.1);
    let [r, g, b] = ["R", "G", "B"].map(|n| channel(path, &layer, n).map(|s| s.values_as_f32().collect::<Vec<f32>>()));
    let (r, g, b) = (r?, g?, b?);
    Ok((w, h, (0..w * h).map(|i| [r[i], g[i], b[i]]).collect()))
}

/// Writes an 8-bit sRGB preview (`RGBRGB...`, row-major) as PNG.
pub fn write_srgb8_png(path: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<(), ImageIoError> {
    check_len(path, width, height, rgb.len() / 3)?;
    if rgb.len() % 3 != 0 {
        return Err(bad_input(path, format!("{} bytes is not a whole number of RGB pixels", rgb.len())));
    }
    image::save_buffer_with_format(
        path,
        rgb,
        width as u32,
        height as u32,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| png_err(path, e))
}

/// Encodes an 8-bit sRGB image like [`write_srgb8_png`] into memory (for stores that write
/// through their own storage layer, and for serving a preview). `name` only labels errors.
pub fn encode_srgb8_png(name: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<Vec<u8>, ImageIoError> {
    check_len(name, width, height, rgb.len() / 3)?;
    if rgb.len() % 3 != 0 {
        return Err(bad_input(name, format!("{} bytes is not a whole number of RGB pixels", rgb.len())));
    }
    let mut out = std::io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        rgb,
        width as u32,
        height as u32,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| png_err(name, e))?;
    Ok(out.into_inner())
}

/// A linear RGB image (`width x height`, row-major, e.g. a rectified texture in linear sRGB)
/// as 8-bit sRGB (`RGBRGB...`): `scale` multiplies the linear values first (1 maps linear 1.0
/// to 255), values beyond 1 clip. No tone mapping, so previews of one dataset compare.
pub fn linear_to_srgb8(data: &[[f32; 3]], scale: f32) -> Vec<u8> {
    // The transfer function does not clip: NaN to 0, the rest to [0, 1] first.
    let enc = |c: f32| {
        let v = if c.is_nan() { 0.0 } else { f64::from(c).clamp(0.0, 1.0) };
        (btfrig_color::space::srgb_encode(v) * 255.0 + 0.5) as u8
    };
    data.iter().flat_map(|p| p.map(|c| enc(c * scale))).collect()
}

/// Decodes an 8-bit RGB PNG held in memory (`(width, height, RGBRGB...)`); `name` only
/// labels errors.
pub fn decode_srgb8_png(name: &Path, bytes: &[u8]) -> Result<(usize, usize, Vec<u8>), ImageIoError> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png).map_err(|e| png_err(name, e))?;
    let color = img.color();
    let image::DynamicImage::ImageRgb8(buf) = img else {
        return Err(content(name, format!("expected 8-bit RGB, found {color:?}")));
    };
    Ok((buf.width() as usize, buf.height() as usize, buf.into_raw()))
}

/// Reads an 8-bit RGB PNG (`(width, height, RGBRGB...)`), e.g. a preview, for checks.
pub fn read_srgb8_png(path: &Path) -> Result<(usize, usize, Vec<u8>), ImageIoError> {
    let img = image::ImageReader::open(path)
        .map_err(|e| png_err(path, e))?
        .with_guessed_format()
        .map_err(|e| png_err(path, e))?
        .decode()
        .map_err(|e| png_err(path, e))?;
    let color = img.color();
    let image::DynamicImage::ImageRgb8(buf) = img else {
        return Err(content(path, format!("expected 8-bit RGB, found {color:?}")));
    };
    Ok((buf.width() as usize, buf.height() as usize, buf.into_raw()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::frame::BayerPattern;

    struct TempDir(PathBuf);
    impl TempDir {
        fn new(tag: &str) -> Self {
            let p = std::env::temp_dir().join(format!("btfrig-imageio-{tag}-{}", std::process::id()));
            std::fs::create_dir_all(&p).unwrap();
            TempDir(p)
        }
        fn file(&self, name: &str) -> PathBuf {
            self.0.join(name)
        }
    }
    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    #[test]
    fn srgb_encoding_matches_the_standard_and_clips() {
        // Published sRGB anchors: linear 0.18 (mid grey) -> 0.4613 (118 of 255), 1 -> 255;
        // below 0, beyond 1 and NaN clip (the curve itself is btfrig_color::space's, tested there).
        assert_eq!(
            linear_to_srgb8(&[[0.0, 0.18, 1.0], [2.0, -1.0, f32::INFINITY], [-0.5, 7.0, f32::NAN]], 1.0),
            vec![0, 118, 255, 255, 0, 255, 0, 255, 0]
        );
        // Monotonic over the 8-bit range.
        let codes: Vec<u8> = (0..=1000).map(|i| linear_to_srgb8(&[[i as f32 / 1000.0; 3]], 1.0)[0]).collect();
        assert!(codes.windows(2).all(|w| w[0] <= w[1]));
    }

    fn frame(w: usize, h: usize) -> RawFrame {
        // Every value 0..=65535 appears somewhere across the two test sizes; include the ends.
        let mut data: Vec<u16> = (0..w * h).map(|i| (i as u64 * 2_654_435_761 % 65_536) as u16).collect();
        data[0] = 0;
        if let Some(v) = data.get_mut(1) {
            *v = 65535;
        }
        RawFrame {
            width: w,
            height: h,
            data,
            meta: FrameMeta {
                sequence: 17,
                exposure_s: 0.0125,
                gain: 2.0,
                f_number: Some(8.0),
                black_level: 256,
                white_level: 16251,
                bit_depth: 14,
                bayer: Some(BayerPattern::Grbg),
                timestamp_s: 1234.5,
                temperature_c: None,
            },
        }
    }

    #[test]
    fn raw_png_round_trip_keeps_every_value() {
        let dir = TempDir::new("png");
        for (w, h) in [(1, 1), (37, 23), (320, 240)] {
            let f = frame(w, h);
            let p = dir.file(&format!("raw_{w}x{h}.png"));
            write_raw_frame(&p, &f).unwrap();
            assert_eq!(read_raw_png(&p, f.meta.clone()).unwrap(), f);
        }
    }

    #[test]
    fn raw_exr_round_trip_keeps_values_and_metadata() {
        let dir = TempDir::new("exr");
        for (w, h) in [(1, 1), (37, 23), (320, 240)] {
            let f = frame(w, h);
            let p = dir.file(&format!("raw_{w}x{h}.exr"));
            write_raw_frame(&p, &f).unwrap();
            assert_eq!(read_raw_exr(&p).unwrap(), f);
        }
        let mut mono = frame(8, 8);
        mono.meta.bayer = None;
        mono.meta.f_number = None;
        let p = dir.file("mono.exr");
        write_raw_exr(&p, &mono).unwrap();
        assert_eq!(read_raw_exr(&p).unwrap(), mono);
        assert_eq!(decode_raw_exr(&p, &encode_raw_exr(&p, &mono).unwrap()).unwrap(), mono);
    }

    #[test]
    fn rgb_exr_round_trip_is_exact_including_negative_and_large_values() {
        let dir = TempDir::new("rgb");
        let (w, h) = (33, 17);
        let data: Vec<[f32; 3]> =
            (0..w * h).map(|i| [i as f32 * 0.001, -0.25 + i as f32 * 1e-5, 1e6 / (1.0 + i as f32)]).collect();
        let p = dir.file("rgb.exr");
        write_rgb_exr(&p, w, h, &data).unwrap();
        let (rw, rh, back) = read_rgb_exr(&p).unwrap();
        assert_eq!((rw, rh), (w, h));
        assert_eq!(back, data);
        // An RGB file is not a raw frame, and says why.
        let e = read_raw_exr(&p).unwrap_err().to_string();
        assert!(e.contains("rgb.exr") && e.contains(META_ATTRIBUTE), "{e}");
    }

    #[test]
    fn preview_png_round_trip() {
        let dir = TempDir::new("preview");
        let rgb: Vec<u8> = (0..20 * 10 * 3).map(|i| (i * 7 % 256) as u8).collect();
        let p = dir.file("preview.png");
        write_srgb8_png(&p, 20, 10, &rgb).unwrap();
        assert_eq!(read_srgb8_png(&p).unwrap(), (20, 10, rgb.clone()));
        let bytes = encode_srgb8_png(&p, 20, 10, &rgb).unwrap();
        assert_eq!(bytes, std::fs::read(&p).unwrap());
        assert_eq!(decode_srgb8_png(&p, &bytes).unwrap(), (20, 10, rgb));
        // A preview is not a 16-bit raw frame.
        let e = read_raw_png(&p, frame(1, 1).meta).unwrap_err().to_string();
        assert!(e.contains("preview.png") && e.contains("16-bit"), "{e}");
    }

    #[test]
    fn errors_name_the_path() {
        let dir = TempDir::new("errors");
        let missing = dir.file("nope.exr");
        assert!(read_raw_exr(&missing).unwrap_err().to_string().contains("nope.exr"));
        assert!(read_rgb_exr(&missing).unwrap_err().to_string().contains("nope.exr"));
        let missing_png = dir.file("nope.png");
        assert!(read_raw_png(&missing_png, frame(1, 1).meta).unwrap_err().to_string().contains("nope.png"));
        let f = frame(4, 4);
        let e = write_raw_frame(&dir.file("x.tiff"), &f).unwrap_err().to_string();
        assert!(e.contains("x.tiff") && e.contains(".exr"), "{e}");
        let mut bad = f.clone();
        bad.data.pop();
        let e = write_raw_png(&dir.file("bad.png"), &bad).unwrap_err().to_string();
        assert!(e.contains("bad.png") && e.contains("15 values"), "{e}");
        let e = write_rgb_exr(&dir.file("no/such/dir/x.exr"), 1, 1, &[[0.0; 3]]).unwrap_err().to_string();
        assert!(e.contains("x.exr"), "{e}");
        // Garbage in a .exr file.
        let junk = dir.file("junk.exr");
        std::fs::write(&junk, b"not an exr").unwrap();
        assert!(read_raw_exr(&junk).unwrap_err().to_string().contains("junk.exr"));
    }

    #[test]
    fn encoders_produce_the_files_the_writers_write_and_half_rounds_to_nearest() {
        let dir = TempDir::new("encode");
        let (w, h) = (5, 3);
        // Values exactly representable in half, and one that is not (1/3).
        let data: Vec<[f32; 3]> = (0..w * h).map(|i| [i as f32 * 0.25, 1.0 / 3.0, 1024.0 + i as f32 * 2.0]).collect();
        let path = dir.file("rgb.exr");
        write_rgb_exr(&path, w, h, &data).unwrap();
        let bytes = encode_rgb_exr(&path, w, h, &data, ExrPrecision::Float).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
        let frame = frame(7, 4);
        let raw_path = dir.file("raw.exr");
        write_raw_exr(&raw_path, &frame).unwrap();
        assert_eq!(std::fs::read(&raw_path).unwrap(), encode_raw_exr(&raw_path, &frame).unwrap());

        let half = encode_rgb_exr(&path, w, h, &data, ExrPrecision::Half).unwrap();
        let half_path = dir.file("half.exr");
        std::fs::write(&half_path, &half).unwrap();
        let (hw, hh, back) = read_rgb_exr(&half_path).unwrap();
        assert_eq!((hw, hh), (w, h));
        for (a, b) in data.iter().zip(&back) {
            assert_eq!(a[0], b[0]);
            assert_eq!(a[2], b[2]);
            // 1/3 in half: nearest of the 2^-12-spaced values in [0.25, 0.5).
            assert!((b[1] - 1.0 / 3.0).abs() <= 2f32.powi(-13), "{}", b[1]);
            assert_ne!(b[1], 1.0 / 3.0);
        }
        assert!(half.len() < bytes.len());
    }
}
