//! Byte transports and the link a backend keeps to its controller.

use std::io;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A bidirectional byte stream to one controller.
pub trait Transport: Send {
    /// Writes all of `bytes`.
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads what is available, waiting at most `timeout`; `Ok(0)` when nothing came.
    /// An error means the link is gone.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
}

/// Opens transports to one controller (again after a loss).
pub trait Connector: Send + Sync {
    /// Opens a new transport.
    fn connect(&self) -> io::Result<Box<dyn Transport>>;
    /// What is being connected to, for messages (`/dev/ttyUSB0 at 115200 baud`).
    fn describe(&self) -> String;
}

/// A serial port opened by path with the `serialport` crate (8N1, no flow control).
#[derive(Debug, Clone)]
pub struct SerialConnector {
    /// Device path (a stable symlink such as `/dev/serial/by-id/...` survives replugging).
    pub path: String,
    /// Baud rate.
    pub baud: u32,
}

struct SerialTransport(Box<dyn serialport::SerialPort>);

impl Transport for SerialTransport {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        io::Write::write_all(&mut self.0, bytes)?;
        io::Write::flush(&mut self.0)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.0.set_timeout(timeout).map_err(io::Error::from)?;
        match io::Read::read(&mut self.0, buf) {
            Ok(0) => Err(io::Error::new(io::ErrorKind::UnexpectedEof, "port closed")),
            Ok(n) => Ok(n),
            Err(e) if e.kind() == io::ErrorKind::TimedOut => Ok(0),
            Err(e) => Err(e),
        }
    }
}

impl Connector for SerialConnector {
    fn connect(&self) -> io::Result<Box<dyn Transport>> {
        let port = serialport::new(&self.path, self.baud)
            .timeout(Duration::from_millis(10))
            .open()
            .map_err(io::Error::from)?;
        Ok(Box::new(SerialTransport(port)))
    }

    fn describe(&self) -> String {
        format!("{} at {} baud", self.path, self.baud)
    }
}

/// Why an exchange with the controller failed at the link level.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The port could not be opened, or failed while in use.
    #[error("link to {target} lost: {source}")]
    Lost {
        /// [`Connector::describe`].
        target: String,
        /// The I/O error.
        source: io::Error,
    },
    /// No complete answer within the reply timeout.
    #[error("no answer from {target} within {timeout_s} s ({what})")]
    Timeout {
        /// [`Connector::describe`].
        target: String,
        /// The reply timeout.
        timeout_s: f64,
        /// What was awaited.
        what: String,
    },
}

impl LinkError {
    /// The trait-level kind: `Disconnected` or `Timeout`, both retryable.
    pub fn kind(&self) -> btfrig_hw::ErrorKind {
        match self {
            LinkError::Lost { .. } => btfrig_hw::ErrorKind::Disconnected,
            LinkError::Timeout { .. } => btfrig_hw::ErrorKind::Timeout,
        }
    }

    /// As a device error of `device`.
    pub fn into_device_error(self, device: &str) -> btfrig_hw::DeviceError {
        btfrig_hw::DeviceError::new(device, self.kind(), self.to_string())
    }
}

/// What a link has done over all its sessions: the cost of talking to the controller over
/// a line instead of calling a device in-process (the run report's `links`). Shared as an
/// `Arc` so it stays readable after the backend is boxed behind a device trait.
#[derive(Debug, Default)]
pub struct LinkStats {
    exchanges: AtomicU64,
    bytes_out: AtomicU64,
    bytes_in: AtomicU64,
    exchange_ns: AtomicU64,
    skipped: AtomicU64,
}

/// A snapshot of [`LinkStats`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LinkTotals {
    /// Blocking exchanges (command and answer, or a status poll).
    pub exchanges: u64,
    /// Bytes written to the controller.
    pub bytes_out: u64,
    /// Bytes read from the controller (garbage included).
    pub bytes_in: u64,
    /// Wall-clock seconds the caller waited on exchanges (thread hand-off, write, the
    /// controller's answer, decoding); the rig clock's own waits between polls are not in it.
    pub exchange_wall_s: f64,
    /// Lines or frames skipped as undecodable.
    pub skipped: u64,
}

impl LinkTotals {
    /// Seconds the bytes take on a line of `baud` (8N1: 10 bits a byte), both directions in
    /// turn as a half-duplex exchange does: what a real port adds to rig time.
    pub fn wire_s(&self, baud: u32) -> f64 {
        (self.bytes_out + self.bytes_in) as f64 * 10.0 / f64::from(baud.max(1))
    }
}

impl LinkStats {
    /// The counters now.
    pub fn totals(&self) -> LinkTotals {
        LinkTotals {
            exchanges: self.exchanges.load(Ordering::Relaxed),
            bytes_out: self.bytes_out.load(Ordering::Relaxed),
            bytes_in: self.bytes_in.load(Ordering::Relaxed),
            exchange_wall_s: self.exchange_ns.load(Ordering::Relaxed) as f64 * 1e-9,
            skipped: self.skipped.load(Ordering::Relaxed),
        }
    }
}

/// An open transport with its protocol decoder `D` and counters.
pub struct Session<D> {
    io: Box<dyn Transport>,
    /// The protocol's decoder (survives between exchanges; cleared on reconnect).
    pub decoder: D,
    /// Lines or frames skipped as undecodable since connecting.
    pub skipped: u64,
    target: String,
    stats: Arc<LinkStats>,
}

impl<D> Session<D> {
    /// Writes `bytes`.
    pub fn send(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        self.stats.bytes_out.fetch_add(bytes.len() as u64, Ordering::Relaxed);
        self.io.write_all(bytes).map_err(|source| LinkError::Lost { target: self.target.clone(), source })
    }

    /// Reads more bytes into `push` until `deadline`; returns whether any came.
    pub fn fill(&mut self, deadline: Instant, push: impl FnOnce(&mut D, &[u8])) -> Result<bool, LinkError> {
        let mut buf = [0u8; 1024];
        let wait = deadline.saturating_duration_since(Instant::now()).min(Duration::from_millis(20));
        let n = self
            .io
            .read(&mut buf, wait.max(Duration::from_millis(1)))
            .map_err(|source| LinkError::Lost { target: self.target.clone(), source })?;
        self.stats.bytes_in.fetch_add(n as u64, Ordering::Relaxed);
        push(&mut self.decoder, &buf[..n]);
        Ok(n > 0)
    }

    /// A timeout error for `what`.
    pub fn timeout(&self, timeout: Duration, what: &str) -> LinkError {
        LinkError::Timeout { target: self.target.clone(), timeout_s: timeout.as_secs_f64(), what: what.to_string() }
    }
}

/// A backend's link: the connector and, while connected, the session.
pub struct Link<D> {
    connector: Arc<dyn Connector>,
    /// A mutex only to make the link `Sync` (device traits require it; serial ports are
    /// `Send` only); it is never contended, access goes through `&mut self`.
    session: std::sync::Mutex<Option<Session<D>>>,
    new_decoder: fn() -> D,
    /// Times the link was (re)opened.
    pub connects: u64,
    stats: Arc<LinkStats>,
}

impl<D: Send + 'static> Link<D> {
    /// A link that connects on first use.
    pub fn new(connector: Arc<dyn Connector>, new_decoder: fn() -> D) -> Self {
        Link { connector, session: std::sync::Mutex::new(None), new_decoder, connects: 0, stats: Arc::default() }
    }

    /// What the link connects to.
    pub fn describe(&self) -> String {
        self.connector.describe()
    }

    /// Drops the session (the next exchange reconnects).
    pub fn drop_session(&mut self) {
        *self.slot() = None;
    }

    /// Lines or frames skipped as undecodable in the current session.
    pub fn skipped(&mut self) -> u64 {
        self.slot().as_ref().map_or(0, |s| s.skipped)
    }

    /// The link's counters over all sessions (skipped input, bytes, exchange time).
    pub fn stats(&self) -> Arc<LinkStats> {
        self.stats.clone()
    }

    fn slot(&mut self) -> &mut Option<Session<D>> {
        self.session.get_mut().unwrap_or_else(|p| p.into_inner())
    }

    /// Runs the blocking exchange `f` on the blocking pool, connecting first if needed. A
    /// lost link drops the session; a timeout keeps it (a late answer is then skipped by
    /// tag or state, see the backends).
    pub async fn run<R: Send + 'static>(
        &mut self,
        f: impl FnOnce(&mut Session<D>) -> Result<R, LinkError> + Send + 'static,
    ) -> Result<R, LinkError> {
        let session = self.slot().take();
        let connector = self.connector.clone();
        let new_decoder = self.new_decoder;
        let fresh = session.is_none();
        let stats = self.stats.clone();
        let started = Instant::now();
        let joined = tokio::task::spawn_blocking(move || {
            let mut s = match session {
                Some(s) => s,
                None => {
                    let target = connector.describe();
                    let io =
                        connector.connect().map_err(|source| LinkError::Lost { target: target.clone(), source })?;
                    Session { io, decoder: new_decoder(), skipped: 0, target, stats: stats.clone() }
                }
            };
            let before = s.skipped;
            let r = f(&mut s);
            stats.skipped.fetch_add(s.skipped.saturating_sub(before), Ordering::Relaxed);
            Ok::<_, LinkError>((s, r))
        })
        .await;
        self.stats.exchanges.fetch_add(1, Ordering::Relaxed);
        self.stats.exchange_ns.fetch_add(started.elapsed().as_nanos() as u64, Ordering::Relaxed);
        let (s, r) = match joined {
            Ok(Ok(pair)) => pair,
            Ok(Err(e)) => return Err(e),
            Err(join) => {
                return Err(LinkError::Lost {
                    target: self.connector.describe(),
                    source: io::Error::other(format!("exchange task failed: {join}")),
                })
            }
        };
        if fresh {
            self.connects += 1;
        }
        if !matches!(r, Err(LinkError::Lost { .. })) {
            *self.slot() = Some(s);
        }
        r
    }
}
