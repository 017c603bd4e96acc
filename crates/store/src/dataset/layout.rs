//! Where things live in a dataset directory: file and directory names, the paths of a
//! step's files, and which files a done step must have written.

use crate::error::{io_err, StoreError};
use crate::manifest::Manifest;
use crate::storage::Storage;
use crate::StepId;

/// The manifest's file name.
pub const MANIFEST_FILE: &str = "manifest.json";
/// The journal's file name.
pub const JOURNAL_FILE: &str = "journal.btfj";
/// The run report's file name.
pub const REPORT_FILE: &str = "report.json";
/// Directory of the rectified textures.
pub const TEXTURES_DIR: &str = "textures";
/// Directory of the raw frames.
pub const RAW_DIR: &str = "raw";
/// Directory of the 8-bit sRGB texture previews.
pub const PREVIEWS_DIR: &str = "previews";
/// The live preview (8-bit sRGB PNG of the latest processed capture): not data, never
/// journaled, replaced atomically by [`Dataset::write_preview`].
pub const PREVIEW_FILE: &str = "preview.png";

/// The files a done step of `manifest` must have written (a journal record naming fewer is
/// refused by [`Dataset::commit_step`] and reported by [`verify`]).
pub(super) fn required_files(manifest: &Manifest, step: StepId) -> Vec<String> {
    let mut out = Vec::new();
    if manifest.textures {
        out.push(texture_path(step));
    }
    if manifest.raw_frames {
        out.push(raw_path(step));
    }
    if manifest.texture_previews {
        out.push(texture_preview_path(step));
    }
    out
}

pub(super) fn texture_preview_path(step: StepId) -> String {
    format!("{PREVIEWS_DIR}/{}.png", step.stem())
}

pub(super) fn texture_path(step: StepId) -> String {
    format!("{TEXTURES_DIR}/{}.exr", step.stem())
}

pub(super) fn raw_path(step: StepId) -> String {
    format!("{RAW_DIR}/{}.exr", step.stem())
}

/// Frame `pattern` of view `view`'s group of raw frames (a dome's pattern frames):
/// `raw/v003_p007.exr`.
pub(super) fn group_frame_path(view: u32, pattern: usize) -> String {
    format!("{RAW_DIR}/v{view:03}_p{pattern:03}.exr")
}

/// Exposure `k >= 1` of an HDR bracket (exposure 0 is [`raw_path`]).
pub(super) fn raw_exposure_path(step: StepId, k: usize) -> String {
    format!("{RAW_DIR}/{}_e{k}.exr", step.stem())
}

pub(super) fn list_names<S: Storage + ?Sized>(s: &S, dir: &str) -> Result<Vec<crate::Entry>, StoreError> {
    s.list(dir).map_err(io_err(s, "list", dir))
}

/// Files under the data directories (`textures/`, `raw/`), as dataset-relative paths.
pub(super) fn data_files<S: Storage + ?Sized>(s: &S) -> Result<Vec<String>, StoreError> {
    let root = list_names(s, "")?;
    let mut out = Vec::new();
    for dir in [TEXTURES_DIR, RAW_DIR, PREVIEWS_DIR] {
        if root.iter().any(|e| e.name == dir && e.is_dir) {
            for e in list_names(s, dir)? {
                out.push(format!("{dir}/{}", e.name));
            }
        }
    }
    Ok(out)
}
