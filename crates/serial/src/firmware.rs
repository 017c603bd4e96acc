//! Firmware emulators: a device-trait object (in tests, a simulated device) served over a
//! pseudo-terminal in a real protocol, with hooks to inject link faults.

pub mod grbl;
pub mod lamp;
pub mod led;
pub mod robot;

use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use crate::pty::PtyPort;

/// What an emulator's task receives. Bytes from the tty (tagged with their plug generation)
/// and injected faults share one channel, so a fault injected before a request is handled
/// before it.
pub(crate) enum Event<F> {
    Bytes(u64, Vec<u8>),
    Fault(F),
}

/// The reader thread's sink: forwards the tty's bytes into the emulator's channel.
pub(crate) fn forwarder<F: Send + 'static>(
    tx: &mpsc::UnboundedSender<Event<F>>,
) -> impl Fn(u64, Vec<u8>) -> bool + Send + 'static {
    let tx = tx.clone();
    move |g, b| tx.send(Event::Bytes(g, b)).is_ok()
}

/// The outside of a running emulator: injects faults; dropping it stops the emulator.
pub(crate) struct Handle<F> {
    tx: mpsc::UnboundedSender<Event<F>>,
    task: JoinHandle<()>,
}

impl<F> Handle<F> {
    pub(crate) fn new(tx: mpsc::UnboundedSender<Event<F>>, task: JoinHandle<()>) -> Handle<F> {
        Handle { tx, task }
    }

    pub(crate) fn inject(&self, fault: F) {
        let _ = self.tx.send(Event::Fault(fault));
    }
}

impl<F> Drop for Handle<F> {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// One plugged-in pty: the writer, and a reader thread that forwards what the host sends
/// (tagged with the plug generation, so bytes from an unplugged tty are told apart).
pub(crate) struct Wire {
    pub(crate) port: PtyPort,
    writer: std::fs::File,
    stop: Arc<AtomicBool>,
    pub(crate) generation: u64,
}

impl Wire {
    pub(crate) fn open(
        link: &Path,
        generation: u64,
        forward: impl Fn(u64, Vec<u8>) -> bool + Send + 'static,
    ) -> std::io::Result<Wire> {
        let port = PtyPort::open(link)?;
        let writer = port.master_file()?;
        let mut reader = port.master_file()?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 512];
            while !stop2.load(Ordering::Relaxed) {
                let ready = {
                    let mut fds = [PollFd::new(reader.as_fd(), PollFlags::POLLIN)];
                    poll(&mut fds, PollTimeout::from(10u8)).unwrap_or(0) > 0
                        && fds[0].revents().is_some_and(|r| r.contains(PollFlags::POLLIN))
                };
                if !ready {
                    // Nothing, or no host has the slave open (POLLHUP): wait and look again.
                    std::thread::sleep(std::time::Duration::from_millis(2));
                    continue;
                }
                match reader.read(&mut buf) {
                    Ok(n) if n > 0 => {
                        if !forward(generation, buf[..n].to_vec()) {
                            return;
                        }
                    }
                    // EIO while the host has the slave closed: not an error for a controller.
                    _ => std::thread::sleep(std::time::Duration::from_millis(2)),
                }
            }
        });
        Ok(Wire { port, writer, stop, generation })
    }

    /// Unplugs and replugs the adapter: a new tty behind the same `link`, the old one dropped
    /// (the host's port fails). The controller keeps its state; false if the replug failed.
    pub(crate) fn replug<F: Send + 'static>(
        &mut self,
        link: &Path,
        tx: &mpsc::UnboundedSender<Event<F>>,
        who: &str,
    ) -> bool {
        match Wire::open(link, self.generation + 1, forwarder(tx)) {
            Ok(w) => {
                tracing::info!("{who} replugged as {}", w.port.slave_path());
                *self = w;
                true
            }
            Err(e) => {
                tracing::warn!("{who}: replug failed: {e}");
                false
            }
        }
    }

    pub(crate) fn write(&mut self, bytes: &[u8]) {
        // A write with no host attached may fail; a controller would just drop it.
        let _ = self.writer.write_all(bytes);
    }
}

impl Drop for Wire {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}
