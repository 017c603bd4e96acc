//! The storage layer under the journal and the dataset: a few file-system operations on
//! paths relative to the dataset directory, with explicit `fsync`.
//!
//! Paths are `/`-separated and relative; `""` is the dataset directory itself. Durability
//! follows POSIX: a file's bytes are durable after [`Storage::fsync`] of the file, a name
//! (created, renamed, removed) after `fsync` of its parent directory. [`FsStorage`] is the
//! real file system; [`MemStorage`] keeps the durable and the volatile state apart so that a
//! test can cut the power ([`MemStorage::crash`]) and keep a torn prefix of the last append.

use std::collections::{BTreeMap, HashMap};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

/// One entry of a directory listing.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Entry {
    /// The entry's name (no directory part).
    pub name: String,
    /// True for a directory.
    pub is_dir: bool,
}

/// File-system operations the journal and the dataset use. All methods take `&self` so a
/// dataset can be shared between threads; implementations synchronise inside.
pub trait Storage: Send + Sync {
    /// Creates the directory `path` (its parent must exist); succeeds if it already exists.
    fn create_dir(&self, path: &str) -> io::Result<()>;
    /// Creates the empty file `path`, replacing any file of that name.
    fn create(&self, path: &str) -> io::Result<()>;
    /// Appends `data` to the file `path`.
    fn append(&self, path: &str, data: &[u8]) -> io::Result<()>;
    /// Makes the contents of file `path`, or the entries of directory `path`, durable.
    fn fsync(&self, path: &str) -> io::Result<()>;
    /// Renames file `from` to `to`, atomically replacing `to`.
    fn rename(&self, from: &str, to: &str) -> io::Result<()>;
    /// Cuts the file `path` to `len` bytes.
    fn truncate(&self, path: &str, len: u64) -> io::Result<()>;
    /// Reads the whole file `path`.
    fn read(&self, path: &str) -> io::Result<Vec<u8>>;
    /// Lists the directory `path`, sorted by name.
    fn list(&self, dir: &str) -> io::Result<Vec<Entry>>;
    /// The size of file `path`, or `None` if there is no such file.
    fn size(&self, path: &str) -> io::Result<Option<u64>>;
    /// Removes the file `path`.
    fn remove(&self, path: &str) -> io::Result<()>;
    /// How to name `path` in messages (e.g. the absolute file name).
    fn display(&self, path: &str) -> String;
}

/// The parent directory of a relative path (`""` for a top-level name).
pub fn parent(path: &str) -> &str {
    path.rfind('/').map_or("", |i| &path[..i])
}

/// The real file system under a root directory.
#[derive(Debug, Clone)]
pub struct FsStorage {
    root: PathBuf,
}

impl FsStorage {
    /// Storage rooted at `root` (which should exist).
    pub fn new(root: impl Into<PathBuf>) -> Self {
        FsStorage { root: root.into() }
    }
    /// The root directory.
    pub fn root(&self) -> &Path {
        &self.root
    }
    fn path(&self, rel: &str) -> PathBuf {
        if rel.is_empty() {
            self.root.clone()
        } else {
            self.root.join(rel)
        }
    }
}

impl Storage for FsStorage {
    fn create_dir(&self, path: &str) -> io::Result<()> {
        match std::fs::create_dir(self.path(path)) {
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists && self.path(path).is_dir() => Ok(()),
            other => other,
        }
    }
    fn create(&self, path: &str) -> io::Result<()> {
        std::fs::File::create(self.path(path)).map(drop)
    }
    fn append(&self, path: &str, data: &[u8]) -> io::Result<()> {
        std::fs::OpenOptions::new().append(true).open(self.path(path))?.write_all(data)
    }
    fn fsync(&self, path: &str) -> io::Result<()> {
        // Linux accepts fsync on a read-only descriptor, for files and directories alike.
        std::fs::File::open(self.path(path))?.sync_all()
    }
    fn rename(&self, from: &str, to: &str) -> io::Result<()> {
        std::fs::rename(self.path(from), self.path(to))
    }
    fn truncate(&self, path: &str, len: u64) -> io::Result<()> {
        std::fs::OpenOptions::new().write(true).open(self.path(path))?.set_len(len)
    }
    fn read(&self, path: &str) -> io::Result<Vec<u8>> {
        std::fs::read(self.path(path))
    }
    fn list(&self, dir: &str) -> io::Result<Vec<Entry>> {
        let mut out = Vec::new();
        for e in std::fs::read_dir(self.path(dir))? {
            let e = e?;
            out.push(Entry { name: e.file_name().to_string_lossy().into_owned(), is_dir: e.file_type()?.is_dir() });
        }
        out.sort();
        Ok(out)
    }
    fn size(&self, path: &str) -> io::Result<Option<u64>> {
        match std::fs::metadata(self.path(path)) {
            Ok(m) if m.is_file() => Ok(Some(m.len())),
            Ok(_) => Ok(None),
            Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(e),
        }
    }
    fn remove(&self, path: &str) -> io::Result<()> {
        std::fs::remove_file(self.path(path))
    }
    fn display(&self, path: &str) -> String {
        self.path(path).display().to_string()
    }
}

/// What [`MemStorage::crash`] kept of the last unsynced append.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TornAppend {
    /// Bytes of that append that survived.
    pub kept: usize,
    /// Bytes the append had.
    pub len: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Node {
    Dir,
    File(u64),
}

#[derive(Debug, Default)]
struct MemFile {
    data: Vec<u8>,
    synced: Vec<u8>,
}

#[derive(Debug, Default)]
struct MemState {
    names: BTreeMap<String, Node>,
    durable_names: BTreeMap<String, Node>,
    files: HashMap<u64, MemFile>,
    next_id: u64,
    /// Mutating operations left before the simulated power loss; `Some(0)`: power is off.
    fail_after: Option<usize>,
    /// (file, offset, length) of the last append not yet followed by an fsync of that file.
    last_append: Option<(u64, usize, usize)>,
}

/// In-memory storage for tests that keeps what is durable apart from what is not.
///
/// Clones share the same state, so a test keeps one handle while a dataset owns another.
#[derive(Debug, Clone, Default)]
pub struct MemStorage {
    state: Arc<Mutex<MemState>>,
}

fn not_found(path: &str) -> io::Error {
    io::Error::new(io::ErrorKind::NotFound, format!("{path}: no such file or directory"))
}

impl MemStorage {
    /// An empty storage (just the root directory).
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> MutexGuard<'_, MemState> {
        // A test thread that panicked leaves consistent data: every operation is one step.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// After `ops` more successful mutating operations, every operation fails as if the power
    /// had gone, until [`MemStorage::crash`].
    pub fn fail_after(&self, ops: usize) {
        self.lock().fail_after = Some(ops);
    }

    /// Cancels a pending [`MemStorage::fail_after`] (the power stays on).
    pub fn disarm(&self) {
        self.lock().fail_after = None;
    }

    /// Cuts the power: every name and every byte not made durable by `fsync` is lost. With
    /// `torn_keep = Some(k)`, the last append that was not fsync'd keeps its first `k` bytes
    /// (at most all of them), as a disk may persist part of a write. Returns what was kept of
    /// that append, if there was one.
    pub fn crash(&self, torn_keep: Option<usize>) -> Option<TornAppend> {
        let mut st = self.lock();
        let mut torn = None;
        let last = st.last_append.take();
        for (id, f) in st.files.iter_mut() {
            let mut keep = f.synced.clone();
            if let (Some(k), Some((lid, off, len))) = (torn_keep, last) {
                if lid == *id && f.data.starts_with(&f.synced) && off >= f.synced.len() && off + len <= f.data.len() {
                    // Unsynced bytes before this append (none for the journal) survive too.
                    let kept = k.min(len);
                    keep = f.data[..off + kept].to_vec();
                    torn = Some(TornAppend { kept, len });
                }
            }
            f.data = keep.clone();
            f.synced = keep;
        }
        st.names = st.durable_names.clone();
        let live: std::collections::HashSet<u64> =
            st.names.values().filter_map(|n| if let Node::File(id) = n { Some(*id) } else { None }).collect();
        st.files.retain(|id, _| live.contains(id));
        st.fail_after = None;
        torn
    }

    /// Flips one bit of byte `offset` of file `path` (current and durable contents): media
    /// damage for tests.
    pub fn corrupt_byte(&self, path: &str, offset: usize) -> io::Result<()> {
        let mut st = self.lock();
        let id = st.file_id(path)?;
        let f = st.files.get_mut(&id).ok_or_else(|| not_found(path))?;
        if offset >= f.data.len() {
            return Err(io::Error::new(io::ErrorKind::InvalidInput, format!("{path}: offset {offset} beyond end")));
        }
        f.data[offset] ^= 0x10;
        if offset < f.synced.len() {
            f.synced[offset] ^= 0x10;
        }
        Ok(())
    }

    /// Every file path (not directories), sorted.
    pub fn files(&self) -> Vec<String> {
        let st = self.lock();
        st.names.iter().filter(|(_, n)| matches!(n, Node::File(_))).map(|(p, _)| p.clone()).collect()
    }
}

impl MemState {
    fn tick(&mut self) -> io::Result<()> {
        match self.fail_after {
            Some(0) => Err(io::Error::other("injected power loss")),
            Some(n) => {
                self.fail_after = Some(n - 1);
                Ok(())
            }
            None => Ok(()),
        }
    }
    fn powered(&self) -> io::Result<()> {
        if self.fail_after == Some(0) {
            Err(io::Error::other("injected power loss"))
        } else {
            Ok(())
        }
    }
    fn is_dir(&self, path: &str) -> bool {
        path.is_empty() || self.names.get(path) == Some(&Node::Dir)
    }
    fn need_parent(&self, path: &str) -> io::Result<()> {
        if self.is_dir(parent(path)) {
            Ok(())
        } else {
            Err(not_found(parent(path)))
        }
    }
    fn file_id(&self, path: &str) -> io::Result<u64> {
        match self.names.get(path) {
            Some(Node::File(id)) => Ok(*id),
            Some(Node::Dir) => Err(io::Error::new(io::ErrorKind::IsADirectory, format!("{path}: is a directory"))),
            None => Err(not_found(path)),
        }
    }
}

fn children<'a>(names: &'a BTreeMap<String, Node>, dir: &'a str) -> impl Iterator<Item = (&'a String, &'a Node)> + 'a {
    names.iter().filter(move |(p, _)| !p.is_empty() && parent(p) == dir)
}

impl Storage for MemStorage {
    fn create_dir(&self, path: &str) -> io::Result<()> {
        let mut st = self.lock();
        st.tick()?;
        st.need_parent(path)?;
        match st.names.get(path) {
            Some(Node::Dir) => Ok(()),
            Some(Node::File(_)) => Err(io::Error::new(io::ErrorKind::AlreadyExists, format!("{path}: is a file"))),
            None => {
                st.names.insert(path.to_string(), Node::Dir);
                Ok(())
            }
        }
    }
    fn create(&self, path: &str) -> io::Result<()> {
        let mut st = self.lock();
        st.tick()?;
        st.need_parent(path)?;
        if st.is_dir(path) {
            return Err(io::Error::new(io::ErrorKind::IsADirectory, format!("{path}: is a directory")));
        }
        let id = st.next_id;
        st.next_id += 1;
        st.files.insert(id, MemFile::default());
        st.names.insert(path.to_string(), Node::File(id));
        Ok(())
    }
    fn append(&self, path: &str, data: &[u8]) -> io::Result<()> {
        let mut st = self.lock();
        st.tick()?;
        let id = st.file_id(path)?;
        let f = st.files.get_mut(&id).ok_or_else(|| not_found(path))?;
        let off = f.data.len();
        f.data.extend_from_slice(data);
        st.last_append = Some((id, off, data.len()));
        Ok(())
    }
    fn fsync(&self, path: &str) -> io::Result<()> {
        let mut st = self.lock();
        st.tick()?;
        if st.is_dir(path) {
            let st = &mut *st;
            let old: Vec<String> = children(&st.durable_names, path).map(|(p, _)| p.clone()).collect();
            for p in old {
                st.durable_names.remove(&p);
            }
            let new: Vec<(String, Node)> = children(&st.names, path).map(|(p, n)| (p.clone(), *n)).collect();
            st.durable_names.extend(new);
            return Ok(());
        }
        let id = st.file_id(path)?;
        let f = st.files.get_mut(&id).ok_or_else(|| not_found(path))?;
        f.synced = f.data.clone();
        if st.last_append.is_some_and(|(lid, _, _)| lid == id) {
            st.last_append = None;
        }
        Ok(())
    }
    fn rename(&self, from: &str, to: &str) -> io::Result<()> {
        let mut st = self.lock();
        st.tick()?;
        let id = st.file_id(from)?;
        st.need_parent(to)?;
        if st.is_dir(to) {
            return Err(io::Error::new(io::ErrorKind::IsADirectory, format!("{to}: is a directory")));
        }
        st.names.remove(from);
        st.names.insert(to.to_string(), Node::File(id));
        Ok(())
    }
    fn truncate(&self, path: &str, len: u64) -> io::Result<()> {
        let mut st = self.lock();
        st.tick()?;
        let id = st.file_id(path)?;
        let f = st.files.get_mut(&id).ok_or_else(|| not_found(path))?;
        f.data.truncate(len as usize);
        Ok(())
    }
    fn read(&self, path: &str) -> io::Result<Vec<u8>> {
        let st = self.lock();
        st.powered()?;
        let id = st.file_id(path)?;
        Ok(st.files[&id].data.clone())
    }
    fn list(&self, dir: &str) -> io::Result<Vec<Entry>> {
        let st = self.lock();
        st.powered()?;
        if !st.is_dir(dir) {
            return Err(not_found(dir));
        }
        let start = if dir.is_empty() { 0 } else { dir.len() + 1 };
        Ok(children(&st.names, dir)
            .map(|(p, n)| Entry { name: p[start..].to_string(), is_dir: *n == Node::Dir })
            .collect())
    }
    fn size(&self, path: &str) -> io::Result<Option<u64>> {
        let st = self.lock();
        st.powered()?;
        Ok(match st.names.get(path) {
            Some(Node::File(id)) => Some(st.files[id].data.len() as u64),
            _ => None,
        })
    }
    fn remove(&self, path: &str) -> io::Result<()> {
        let mut st = self.lock();
        st.tick()?;
        st.file_id(path)?;
        st.names.remove(path);
        Ok(())
    }
    fn display(&self, path: &str) -> String {
        format!("mem:/{path}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crash_keeps_only_what_was_synced() {
        let s = MemStorage::new();
        s.create_dir("d").unwrap();
        s.fsync("").unwrap();
        s.create("d/a").unwrap();
        s.append("d/a", b"hello").unwrap();
        s.fsync("d/a").unwrap();
        // Name not yet durable: the file vanishes although its bytes were synced.
        s.crash(None);
        assert_eq!(s.files(), Vec::<String>::new());
        s.create("d/a").unwrap();
        s.append("d/a", b"hello").unwrap();
        s.fsync("d/a").unwrap();
        s.fsync("d").unwrap();
        s.append("d/a", b" world").unwrap();
        assert_eq!(s.crash(Some(3)), Some(TornAppend { kept: 3, len: 6 }));
        assert_eq!(s.read("d/a").unwrap(), b"hello wo");
        s.append("d/a", b"!").unwrap();
        s.crash(None);
        assert_eq!(s.read("d/a").unwrap(), b"hello wo");
    }

    #[test]
    fn rename_is_durable_only_after_directory_fsync() {
        let s = MemStorage::new();
        s.create("t").unwrap();
        s.append("t", b"x").unwrap();
        s.fsync("t").unwrap();
        s.fsync("").unwrap();
        s.rename("t", "f").unwrap();
        s.crash(None);
        assert_eq!(s.files(), vec!["t".to_string()]);
        s.rename("t", "f").unwrap();
        s.fsync("").unwrap();
        s.crash(None);
        assert_eq!(s.files(), vec!["f".to_string()]);
        assert_eq!(s.read("f").unwrap(), b"x");
    }

    #[test]
    fn power_loss_fails_every_later_operation() {
        let s = MemStorage::new();
        s.fail_after(1);
        s.create("a").unwrap();
        assert!(s.append("a", b"1").is_err());
        assert!(s.read("a").is_err());
        s.crash(None);
        assert!(s.files().is_empty());
        s.create("a").unwrap();
    }

    #[test]
    fn fs_storage_does_the_same_operations() {
        let dir = std::env::temp_dir().join(format!("btfrig-store-fs-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let s = FsStorage::new(&dir);
        s.create_dir("d").unwrap();
        s.create_dir("d").unwrap();
        s.create("d/t").unwrap();
        s.append("d/t", b"abc").unwrap();
        s.append("d/t", b"def").unwrap();
        s.fsync("d/t").unwrap();
        s.rename("d/t", "d/f").unwrap();
        s.fsync("d").unwrap();
        assert_eq!(s.size("d/f").unwrap(), Some(6));
        assert_eq!(s.size("d/t").unwrap(), None);
        s.truncate("d/f", 4).unwrap();
        assert_eq!(s.read("d/f").unwrap(), b"abcd");
        assert_eq!(s.list("").unwrap(), vec![Entry { name: "d".into(), is_dir: true }]);
        s.remove("d/f").unwrap();
        assert!(s.list("d").unwrap().is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
