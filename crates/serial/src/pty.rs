//! Pseudo-terminals for emulated firmware: the emulator holds the master side, the
//! backend opens the slave by a stable symlink, as it would `/dev/serial/by-id/...`.

use std::fs::File;
use std::io;
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};

use nix::fcntl::OFlag;
use nix::pty::{grantpt, posix_openpt, ptsname_r, unlockpt, PtyMaster};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

/// The master side of one pseudo-terminal and the symlink that names its slave.
pub struct PtyPort {
    master: PtyMaster,
    slave_path: String,
    link: PathBuf,
}

fn nix_err(e: nix::Error) -> io::Error {
    io::Error::from_raw_os_error(e as i32)
}

impl PtyPort {
    /// Opens a new pseudo-terminal (raw mode: no echo, no line editing) and points `link`
    /// at its slave, replacing an older link.
    pub fn open(link: &Path) -> io::Result<PtyPort> {
        let master = posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY).map_err(nix_err)?;
        grantpt(&master).map_err(nix_err)?;
        unlockpt(&master).map_err(nix_err)?;
        let slave_path = ptsname_r(&master).map_err(nix_err)?;
        // Raw mode on the master's termios too, so nothing is echoed before the host opens
        // the slave (serialport sets raw mode on its side when it opens).
        let mut t = tcgetattr(master.as_fd()).map_err(nix_err)?;
        cfmakeraw(&mut t);
        tcsetattr(master.as_fd(), SetArg::TCSANOW, &t).map_err(nix_err)?;
        let tmp = link.with_extension("new");
        let _ = std::fs::remove_file(&tmp);
        std::os::unix::fs::symlink(&slave_path, &tmp)?;
        std::fs::rename(&tmp, link)?;
        Ok(PtyPort { master, slave_path, link: link.to_path_buf() })
    }

    /// The stable path the host opens.
    pub fn link(&self) -> &Path {
        &self.link
    }

    /// The slave's own path (`/dev/pts/N`).
    pub fn slave_path(&self) -> &str {
        &self.slave_path
    }

    /// A separate file handle on the master (for a reader thread and a writer).
    pub fn master_file(&self) -> io::Result<File> {
        let fd: OwnedFd = self.master.as_fd().try_clone_to_owned()?;
        Ok(File::from(fd))
    }
}
