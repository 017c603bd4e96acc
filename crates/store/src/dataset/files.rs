//! Durable file I/O under a [`Storage`]: atomic writes, reading the manifest back, and
//! checking a journaled file against its record.

use crate::error::{io_err, StoreError};
use crate::hash::content_hash;
use crate::manifest::Manifest;
use crate::storage::{parent, Storage};
use crate::FileRecord;

use super::layout::MANIFEST_FILE;

/// Temporary name of `path` while it is written: `.name.tmp` in the same directory, so the
/// rename is atomic and a partial file never has a final name.
pub(super) fn tmp_name(path: &str) -> String {
    let dir = parent(path);
    let name = &path[if dir.is_empty() { 0 } else { dir.len() + 1 }..];
    if dir.is_empty() {
        format!(".{name}.tmp")
    } else {
        format!("{dir}/.{name}.tmp")
    }
}

/// Writes `bytes` durably under `path`: temporary file, fsync, rename, fsync of the directory.
pub(super) fn write_atomic<S: Storage + ?Sized>(s: &S, path: &str, bytes: &[u8]) -> Result<FileRecord, StoreError> {
    let tmp = tmp_name(path);
    s.create(&tmp).map_err(io_err(s, "create", &tmp))?;
    s.append(&tmp, bytes).map_err(io_err(s, "write", &tmp))?;
    s.fsync(&tmp).map_err(io_err(s, "fsync", &tmp))?;
    s.rename(&tmp, path).map_err(io_err(s, "rename", &tmp))?;
    s.fsync(parent(path)).map_err(io_err(s, "fsync", parent(path)))?;
    Ok(FileRecord { path: path.to_string(), size: bytes.len() as u64, hash: content_hash(bytes) })
}

/// The manifest, and its bytes as on disk (for [`manifest_hash`]).
pub(super) fn read_manifest<S: Storage + ?Sized>(s: &S) -> Result<(Manifest, Vec<u8>), StoreError> {
    let bytes = match s.size(MANIFEST_FILE).map_err(io_err(s, "stat", MANIFEST_FILE))? {
        None => return Err(StoreError::NotADataset { path: s.display("") }),
        Some(_) => s.read(MANIFEST_FILE).map_err(io_err(s, "read", MANIFEST_FILE))?,
    };
    let bad = |reason: String| StoreError::BadManifest { path: s.display(MANIFEST_FILE), reason };
    let m: Manifest = serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))?;
    let problems = m.problems();
    if !problems.is_empty() {
        return Err(bad(problems.join("; ")));
    }
    Ok((m, bytes))
}

/// What is wrong with a journaled file on disk (missing, another size, another content hash),
/// or `None` when it is as journaled.
pub(super) fn file_damage<S: Storage + ?Sized>(s: &S, file: &FileRecord) -> Result<Option<String>, StoreError> {
    let Some(size) = s.size(&file.path).map_err(io_err(s, "stat", &file.path))? else {
        return Ok(Some("missing".into()));
    };
    if size != file.size {
        return Ok(Some(format!("{size} bytes, journaled with {}", file.size)));
    }
    let found = content_hash(&s.read(&file.path).map_err(io_err(s, "read", &file.path))?);
    if found != file.hash {
        return Ok(Some(format!("content hash {found}, journaled {}", file.hash)));
    }
    Ok(None)
}
