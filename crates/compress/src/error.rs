//! The one error type of the crate.

use std::path::PathBuf;

/// Everything that can go wrong while building, reading, writing or exporting a model.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CompressError {
    /// A texel of an input texture is NaN or infinite.
    #[error(
        "capture (light {light}, view {view}): texel {texel} (column {col}, row {row}) channel {channel} is {value}: \
         every texel must be finite"
    )]
    NonFinite {
        /// Light index of the capture.
        light: u32,
        /// View index of the capture.
        view: u32,
        /// Texel index (row-major).
        texel: usize,
        /// Column of the texel.
        col: usize,
        /// Row of the texel.
        row: usize,
        /// Colour channel (0 = R, 1 = G, 2 = B).
        channel: usize,
        /// The value.
        value: f32,
    },
    /// A texture has the wrong number of texels.
    #[error("capture (light {light}, view {view}): texture has {got} texels, expected {expected} ({width}x{height})")]
    WrongTextureSize {
        /// Light index.
        light: u32,
        /// View index.
        view: u32,
        /// Texels received.
        got: usize,
        /// Texels expected.
        expected: usize,
        /// Expected width.
        width: usize,
        /// Expected height.
        height: usize,
    },
    /// A capture outside the layout (indices out of range, or a pair the layout does not expect).
    #[error("capture (light {light}, view {view}) is not part of this BTF: {why}")]
    UnknownCapture {
        /// Light index.
        light: u32,
        /// View index.
        view: u32,
        /// Why.
        why: String,
    },
    /// The same capture twice in one pass.
    #[error("capture (light {light}, view {view}) pushed twice in pass {pass}")]
    DuplicateCapture {
        /// Light index.
        light: u32,
        /// View index.
        view: u32,
        /// Pass number (from 1).
        pass: usize,
    },
    /// A pass ended before every expected capture was pushed.
    #[error("pass {pass} ended with {missing} of {expected} captures missing (first: {first})")]
    MissingCaptures {
        /// Pass number (from 1).
        pass: usize,
        /// Captures missing.
        missing: usize,
        /// Captures expected per pass.
        expected: usize,
        /// The first few missing, as `(light, view)` text.
        first: String,
    },
    /// A parameter is out of its range.
    #[error("{field} = {value} is out of range: allowed {allowed}")]
    BadParameter {
        /// The parameter, as named on the command line or in the params struct.
        field: &'static str,
        /// Its value.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// Building was driven in the wrong order (e.g. `finish` before the last pass).
    #[error("model builder: {0}")]
    State(String),
    /// An I/O error on a file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        #[source]
        source: std::io::Error,
    },
    /// A model or `.btf` file is not in the expected format.
    #[error("{path}: {what}")]
    Format {
        /// The file (or `<memory>`).
        path: PathBuf,
        /// What is wrong, with the offset where it applies.
        what: String,
    },
    /// A checksum of a model file does not match its content.
    #[error("{path}: checksum mismatch in {section}: the file is damaged")]
    Checksum {
        /// The file.
        path: PathBuf,
        /// Which section (`header` or the array's name).
        section: String,
    },
    /// A dataset cannot be read as a BTF.
    #[error("dataset {dir}: {what}")]
    Dataset {
        /// The dataset directory.
        dir: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// A file would be overwritten.
    #[error("{path} already exists: refusing to overwrite it (choose another --out, or remove it first)")]
    Exists {
        /// The file.
        path: PathBuf,
    },
    /// A model cannot be exported in the requested form.
    #[error("export: {0}")]
    Export(String),
}

/// Shorthand.
pub type Result<T, E = CompressError> = std::result::Result<T, E>;

pub(crate) fn bad(field: &'static str, value: impl std::fmt::Display, allowed: impl Into<String>) -> CompressError {
    CompressError::BadParameter { field, value: value.to_string(), allowed: allowed.into() }
}
