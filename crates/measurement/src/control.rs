//! Steering a run from any thread: pause, resume, abort, interrupt, through a bounded queue.

use std::sync::{Arc, Mutex};

use tokio::sync::mpsc;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Command {
    Pause,
    Resume,
    Abort,
    Interrupt(Signal),
}

/// The signal that interrupted a run ([`RunControl::interrupt`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Signal {
    /// SIGINT (Ctrl-C).
    Int,
    /// SIGTERM (a service manager, `kill`, the daemon's shutdown).
    Term,
}

impl Signal {
    /// The signal's name, e.g. `SIGTERM`.
    pub fn name(self) -> &'static str {
        match self {
            Signal::Int => "SIGINT",
            Signal::Term => "SIGTERM",
        }
    }

    /// The exit code of a process this signal stopped: 128 + its number (the shell's
    /// convention): 130 for SIGINT, 143 for SIGTERM.
    pub fn exit_code(self) -> u8 {
        match self {
            Signal::Int => 128 + 2,
            Signal::Term => 128 + 15,
        }
    }
}

/// Commands a [`RunControl`] holds before the session reads them. Commands are tiny and
/// rare (an operator's pause, resume or abort, a signal); the session forwards them to the
/// engine as they come, so a full queue means a caller floods a run: the command fails with
/// [`ControlError::Full`] instead of waiting or growing the queue.
pub const CONTROL_CAPACITY: usize = 16;

/// Why a command did not reach the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ControlError {
    /// [`CONTROL_CAPACITY`] commands are waiting unread.
    #[error("the run already holds {CONTROL_CAPACITY} unread commands; wait for it to act on them")]
    Full,
    /// The session has ended; there is nothing to steer.
    #[error("the run has ended")]
    Ended,
}

/// Steers a run from outside, from any thread: clone it, hand one clone to [`run`].
/// Commands sent before the engine starts take effect when it does (at most
/// [`CONTROL_CAPACITY`] of them wait).
#[derive(Debug, Clone)]
pub struct RunControl {
    tx: mpsc::Sender<Command>,
    rx: Arc<Mutex<Option<mpsc::Receiver<Command>>>>,
    /// Set by [`RunControl::interrupt`]: stops the planning, which runs before the engine
    /// reads commands.
    pub(crate) cancel: btfrig_planner::Cancel,
    signal: Arc<Mutex<Option<Signal>>>,
}

impl Default for RunControl {
    fn default() -> Self {
        Self::new()
    }
}

impl RunControl {
    /// A new control, not yet attached to a run.
    pub fn new() -> RunControl {
        let (tx, rx) = mpsc::channel(CONTROL_CAPACITY);
        RunControl {
            tx,
            rx: Arc::new(Mutex::new(Some(rx))),
            cancel: btfrig_planner::Cancel::new(),
            signal: Arc::new(Mutex::new(None)),
        }
    }

    fn send(&self, c: Command) -> Result<(), ControlError> {
        self.tx.try_send(c).map_err(|e| match e {
            mpsc::error::TrySendError::Full(_) => ControlError::Full,
            mpsc::error::TrySendError::Closed(_) => ControlError::Ended,
        })
    }

    /// Pause after the step under way; the session waits for resume or abort.
    pub fn pause(&self) -> Result<(), ControlError> {
        self.send(Command::Pause)
    }

    /// Resume a paused run (a failed step is tried again).
    pub fn resume(&self) -> Result<(), ControlError> {
        self.send(Command::Resume)
    }

    /// End the session after the step under way; report status `aborted`, resumable.
    pub fn abort(&self) -> Result<(), ControlError> {
        self.send(Command::Abort)
    }

    /// As [`RunControl::abort`], reported as `interrupted` by `signal`. During planning
    /// (before the dataset is created) the run stops at once with
    /// [`RunError::Interrupted`], leaving nothing behind (that part cannot fail).
    pub fn interrupt(&self, signal: Signal) -> Result<(), ControlError> {
        self.signal.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(signal);
        self.cancel.cancel();
        self.send(Command::Interrupt(signal))
    }

    /// The first signal [`RunControl::interrupt`] was called with.
    pub(crate) fn signal(&self) -> Option<Signal> {
        *self.signal.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The command queue's receiving end, once: the run that takes it is the one it steers.
    pub(crate) fn take(&self) -> Option<mpsc::Receiver<Command>> {
        self.rx.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}
