//! Frame file formats: which a file is (its extension, checked against its first bytes), its
//! size from the header alone, its DNs, and writing a frame in each format an export offers.
//!
//! Every format holds the sensor's mosaic as it came off the sensor: one sample per
//! photosite, no demosaic, no black subtraction. PNG and TIFF: 8- or 16-bit greyscale (a
//! colour image is a demosaiced frame, not raw, and is refused). OpenEXR: one channel `Y`
//! holding integer DNs (btfrig's raw frame format, `btfrig_imageio::read_raw_exr_dn`). DNG and
//! camera raw files: through `rawler`, with the cargo feature `raw` (docs/recorded-camera.md).

use std::io::Read;
use std::path::Path;

/// A frame file's format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameFormat {
    /// PNG, 8- or 16-bit greyscale.
    Png,
    /// TIFF, 8- or 16-bit greyscale.
    Tiff,
    /// OpenEXR, channel `Y` of integer DNs.
    Exr,
    /// DNG or a camera raw file (`raw` feature).
    CameraRaw,
}

/// Extensions of camera raw files `rawler` decodes (besides DNG), lower case.
pub const CAMERA_RAW_EXTENSIONS: &[&str] = &["dng", "cr2", "cr3", "nef", "arw", "raf", "orf", "rw2", "pef", "srw"];

/// What `file` may end in, for messages.
pub fn allowed_extensions() -> String {
    let raw = if cfg!(feature = "raw") {
        format!(
            "{} (camera raw, through rawler)",
            CAMERA_RAW_EXTENSIONS.iter().map(|e| format!(".{e}")).collect::<Vec<_>>().join(", ")
        )
    } else {
        format!(
            "and, in a build with the cargo feature `raw` of btfrig-recorded, {}",
            CAMERA_RAW_EXTENSIONS.iter().map(|e| format!(".{e}")).collect::<Vec<_>>().join(", ")
        )
    };
    format!(".png, .tif/.tiff (8- or 16-bit greyscale), .exr (channel Y), {raw}")
}

impl FrameFormat {
    /// The format a file name says (its extension, any case); `None`: not a frame format.
    pub fn from_name(name: &Path) -> Option<FrameFormat> {
        let ext = name.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "png" => Some(FrameFormat::Png),
            "tif" | "tiff" => Some(FrameFormat::Tiff),
            "exr" => Some(FrameFormat::Exr),
            e if CAMERA_RAW_EXTENSIONS.contains(&e) => Some(FrameFormat::CameraRaw),
            _ => None,
        }
    }

    /// Its name in messages and `btfrig hw probe`.
    pub fn name(self) -> &'static str {
        match self {
            FrameFormat::Png => "PNG",
            FrameFormat::Tiff => "TIFF",
            FrameFormat::Exr => "OpenEXR",
            FrameFormat::CameraRaw => "camera raw",
        }
    }

    /// Whether `head` (a file's first bytes) is this format's signature.
    fn signature_matches(self, head: &[u8]) -> bool {
        let tiff = head.starts_with(b"II*\0") || head.starts_with(b"MM\0*");
        match self {
            FrameFormat::Png => head.starts_with(b"\x89PNG\r\n\x1a\n"),
            FrameFormat::Tiff => tiff,
            FrameFormat::Exr => head.starts_with(&[0x76, 0x2f, 0x31, 0x01]),
            // DNG and most camera raws are TIFF containers; the others (CR3, RAF, ...) have
            // their own, which rawler recognises.
            FrameFormat::CameraRaw => true,
        }
    }
}

/// Checks that `path`'s content is `format` (its first bytes); the message says what it is not.
pub fn check_signature(path: &Path, format: FrameFormat) -> Result<(), String> {
    let mut head = [0u8; 8];
    let mut f = std::fs::File::open(path).map_err(|e| format!("cannot open it: {e}"))?;
    let n = f.read(&mut head).map_err(|e| format!("cannot read it: {e}"))?;
    if format.signature_matches(&head[..n]) {
        Ok(())
    } else {
        Err(format!(
            "its extension says {} but its content is not (first bytes {:02x?}): allowed {}",
            format.name(),
            &head[..n],
            allowed_extensions()
        ))
    }
}

/// The frame's width and height, from the header only.
pub fn dimensions(path: &Path, format: FrameFormat) -> Result<(usize, usize), String> {
    match format {
        FrameFormat::Png | FrameFormat::Tiff => image::ImageReader::open(path)
            .map_err(|e| e.to_string())?
            .with_guessed_format()
            .map_err(|e| e.to_string())?
            .into_dimensions()
            .map(|(w, h)| (w as usize, h as usize))
            .map_err(|e| e.to_string()),
        FrameFormat::Exr => {
            let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| e.to_string())?;
            let header = meta.headers.first().ok_or("no layer")?;
            Ok((header.layer_size.0, header.layer_size.1))
        }
        FrameFormat::CameraRaw => camera_raw::dimensions(path),
    }
}

/// The frame's DNs, row-major, with its width and height.
pub fn read_dn(path: &Path, format: FrameFormat) -> Result<(usize, usize, Vec<u16>), String> {
    match format {
        FrameFormat::Png | FrameFormat::Tiff => {
            let img = image::ImageReader::open(path)
                .map_err(|e| e.to_string())?
                .with_guessed_format()
                .map_err(|e| e.to_string())?
                .decode()
                .map_err(|e| e.to_string())?;
            let (w, h) = (img.width() as usize, img.height() as usize);
            match img {
                image::DynamicImage::ImageLuma16(b) => Ok((w, h, b.into_raw())),
                image::DynamicImage::ImageLuma8(b) => Ok((w, h, b.into_raw().into_iter().map(u16::from).collect())),
                other => Err(format!(
                    "its pixels are {:?}: a raw frame is one greyscale sample (8 or 16 bits) per photosite, the colour \
                     filter mosaic as is (a colour image is already demosaiced)",
                    other.color()
                )),
            }
        }
        FrameFormat::Exr => btfrig_imageio::read_raw_exr_dn(path).map_err(|e| e.to_string()),
        FrameFormat::CameraRaw => camera_raw::read_dn(path),
    }
}

/// The formats an export writes frames in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportFormat {
    /// 16-bit greyscale PNG.
    Png,
    /// 16-bit greyscale TIFF.
    Tiff,
    /// btfrig's raw OpenEXR (with the frame's metadata in its header as well).
    Exr,
}

impl ExportFormat {
    /// The file extension.
    pub fn extension(self) -> &'static str {
        match self {
            ExportFormat::Png => "png",
            ExportFormat::Tiff => "tif",
            ExportFormat::Exr => "exr",
        }
    }

    /// Parses `png`, `tiff` (or `tif`), `exr`.
    pub fn parse(s: &str) -> Result<ExportFormat, String> {
        match s {
            "png" => Ok(ExportFormat::Png),
            "tif" | "tiff" => Ok(ExportFormat::Tiff),
            "exr" => Ok(ExportFormat::Exr),
            other => Err(format!("frame format {other:?} is not one an export writes: allowed png, tiff, exr")),
        }
    }
}

/// Writes `frame` to `path` in `format`.
pub fn write(path: &Path, frame: &btfrig_core::frame::RawFrame, format: ExportFormat) -> Result<(), String> {
    let image_format = match format {
        ExportFormat::Exr => return btfrig_imageio::write_raw_exr(path, frame).map_err(|e| e.to_string()),
        ExportFormat::Png => image::ImageFormat::Png,
        ExportFormat::Tiff => image::ImageFormat::Tiff,
    };
    let buf = image::ImageBuffer::<image::Luma<u16>, &[u16]>::from_raw(
        frame.width as u32,
        frame.height as u32,
        frame.data.as_slice(),
    )
    .ok_or_else(|| format!("{}x{} frame with {} samples", frame.width, frame.height, frame.data.len()))?;
    buf.save_with_format(path, image_format).map_err(|e| e.to_string())
}

#[cfg(feature = "raw")]
mod camera_raw {
    //! DNG and camera raw files through rawler: the CFA samples as the file stores them.
    use std::path::Path;

    fn decode(path: &Path) -> Result<rawler::RawImage, String> {
        rawler::decode_file(path).map_err(|e| format!("rawler cannot decode it: {e}"))
    }

    pub(super) fn dimensions(path: &Path) -> Result<(usize, usize), String> {
        let raw = decode(path)?;
        Ok((raw.width, raw.height))
    }

    pub(super) fn read_dn(path: &Path) -> Result<(usize, usize, Vec<u16>), String> {
        let raw = decode(path)?;
        if raw.cpp != 1 {
            return Err(format!(
                "it holds {} samples per pixel (a demosaiced or linear DNG): a raw frame is one sample per photosite",
                raw.cpp
            ));
        }
        match raw.data {
            rawler::RawImageData::Integer(v) => Ok((raw.width, raw.height, v)),
            rawler::RawImageData::Float(_) => {
                Err("it holds floating-point samples (a linear DNG): a raw frame is integer DNs".into())
            }
        }
    }
}

#[cfg(not(feature = "raw"))]
mod camera_raw {
    //! Without the `raw` feature: camera raw files are named but not decoded.
    use std::path::Path;

    const MISSING: &str = "camera raw files (DNG, CR2, NEF, ...) need a build with the cargo feature `raw` of \
                           btfrig-recorded (cargo build --release -p btfrig-cli --features btfrig-recorded/raw)";

    pub(super) fn dimensions(_: &Path) -> Result<(usize, usize), String> {
        Err(MISSING.into())
    }

    pub(super) fn read_dn(_: &Path) -> Result<(usize, usize, Vec<u16>), String> {
        Err(MISSING.into())
    }
}
