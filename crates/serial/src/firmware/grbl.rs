//! A GRBL 1.1 style controller emulated over a pseudo-terminal, driving a rail or
//! turntable device (in tests: the simulator's). `ok` when a line is planned, status
//! reports from the emulator's own state, `$H` answered when homing is done (as GRBL).
//!
//! Simplifications, documented in `docs/protocols/grbl.md`: moves run one at a time
//! (a line while moving is queued); `MPos` jumps to the target when a move ends instead of
//! being interpolated; feed hold only freezes the reported state (the device finishes
//! its move underneath and the report shows it after `~`).

use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};

use btfrig_hw::{AxisLimits, DeviceError, MoveOptions, Rail, Turntable};
use btfrig_protocols::grbl::{Command, CommandDecoder, Response, State, Status};
use btfrig_protocols::DecodeError;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::{forwarder, Handle, Wire};
use crate::grbl::AxisUnits;

/// The device behind the controller.
pub enum AxisDevice {
    /// A camera rail.
    Rail(Box<dyn Rail>),
    /// A turntable.
    Turntable(Box<dyn Turntable>),
}

/// Controller time bound for a device call: the controller itself never gives up.
const NO_TIMEOUT: MoveOptions = MoveOptions { timeout_s: 1e9 };

impl AxisDevice {
    fn limits(&self) -> AxisLimits {
        match self {
            AxisDevice::Rail(d) => d.limits(),
            AxisDevice::Turntable(d) => d.limits(),
        }
    }

    async fn home(&mut self) -> Result<(), DeviceError> {
        match self {
            AxisDevice::Rail(d) => d.home(NO_TIMEOUT).await,
            AxisDevice::Turntable(d) => d.home(NO_TIMEOUT).await,
        }
    }

    async fn move_to(&mut self, rad: f64) -> Result<f64, DeviceError> {
        match self {
            AxisDevice::Rail(d) => d.move_to_rad(rad, NO_TIMEOUT).await,
            AxisDevice::Turntable(d) => d.move_to_rad(rad, NO_TIMEOUT).await,
        }
    }
}

/// Faults a test injects on the link or in the controller.
#[derive(Debug, Clone)]
pub enum Fault {
    /// Write these bytes to the host as if noise hit the line.
    Garbage(Vec<u8>),
    /// Raise `ALARM:N` now (1 = hard limit: motion stops, position lost).
    Alarm(u16),
    /// Unplug and replug the adapter: the old tty goes away (the host's port fails), a new
    /// one appears behind the same symlink. The controller keeps power and state.
    Unplug,
    /// Apply the fault right after accepting the next move line (`ok` sent, motion
    /// started): deterministic "mid-move" faults without timing.
    OnNextMove(Box<Fault>),
}

type Event = super::Event<Fault>;

/// Handle on a running emulator; dropping it stops the emulator.
pub struct GrblFirmware {
    handle: Handle<Fault>,
    link: PathBuf,
}

impl GrblFirmware {
    /// Serves `device` on a new pseudo-terminal behind the symlink `link`. Call inside a
    /// tokio runtime (the emulator is a task on it).
    pub fn spawn(device: AxisDevice, link: &Path) -> std::io::Result<GrblFirmware> {
        Self::spawn_with_units(device, link, AxisUnits::Degrees)
    }

    /// [`GrblFirmware::spawn`] with the axis set up in `units` (the backend must agree).
    pub fn spawn_with_units(device: AxisDevice, link: &Path, units: AxisUnits) -> std::io::Result<GrblFirmware> {
        let (tx, rx) = mpsc::unbounded_channel();
        let limits = device.limits();
        let wire = Wire::open(link, 0, forwarder(&tx))?;
        let emu = Emulator {
            device: Some(device),
            limits,
            job: None,
            homing: false,
            wire,
            decoder: CommandDecoder::new(),
            pos_deg: 0.0,
            units,
            homed: false,
            alarm: None,
            hold: false,
            queue: VecDeque::new(),
            settings: BTreeMap::from([(20, 1.0), (22, 1.0)]),
            tx: tx.clone(),
            link: link.to_path_buf(),
            armed: Vec::new(),
        };
        let task = tokio::spawn(emu.run(rx));
        Ok(GrblFirmware { handle: Handle::new(tx, task), link: link.to_path_buf() })
    }

    /// The path the host opens.
    pub fn link(&self) -> &Path {
        &self.link
    }

    /// Injects a fault.
    pub fn inject(&self, fault: Fault) {
        self.handle.inject(fault);
    }
}

enum Job {
    Home,
    Move(f64),
}

type JobResult = (AxisDevice, Job, Result<(), DeviceError>);

struct Emulator {
    device: Option<AxisDevice>,
    limits: AxisLimits,
    job: Option<JoinHandle<JobResult>>,
    /// The running job is the homing cycle.
    homing: bool,
    wire: Wire,
    decoder: CommandDecoder,
    pos_deg: f64,
    /// Controller units of `pos_deg` and targets (degrees unless set up otherwise).
    units: AxisUnits,
    homed: bool,
    alarm: Option<u16>,
    hold: bool,
    queue: VecDeque<f64>,
    settings: BTreeMap<u16, f64>,
    tx: mpsc::UnboundedSender<Event>,
    link: PathBuf,
    /// Faults to apply after the next accepted move.
    armed: Vec<Fault>,
}

impl Emulator {
    async fn run(mut self, mut rx: mpsc::UnboundedReceiver<Event>) {
        loop {
            tokio::select! {
                ev = rx.recv() => match ev {
                    None => return,
                    Some(Event::Bytes(g, b)) if g == self.wire.generation => {
                        self.decoder.push(&b);
                        while let Some(c) = self.decoder.next() {
                            self.handle(c);
                        }
                    }
                    Some(Event::Bytes(..)) => {} // from an unplugged tty
                    Some(Event::Fault(f)) => self.fault(f),
                },
                done = async { self.job.as_mut().expect("guarded by is_some").await }, if self.job.is_some() => {
                    self.job = None;
                    match done {
                        Ok(r) => self.finished(r),
                        Err(_) => return, // the runtime is shutting down
                    }
                }
            }
        }
    }

    fn reply(&mut self, r: Response) {
        if let Ok(b) = r.encode() {
            self.wire.write(&b);
        }
    }

    fn state(&self) -> State {
        if self.alarm.is_some() {
            State::Alarm
        } else if self.hold {
            State::Hold(0)
        } else if self.homing {
            State::Home
        } else if self.job.is_some() || !self.queue.is_empty() {
            State::Run
        } else {
            State::Idle
        }
    }

    fn start(&mut self, job: Job) {
        let Some(mut dev) = self.device.take() else { return };
        self.homing = matches!(job, Job::Home);
        let units = self.units;
        self.job = Some(tokio::spawn(async move {
            let r = match job {
                Job::Home => dev.home().await,
                Job::Move(deg) => dev.move_to(units.from_wire(deg)).await.map(|_| ()),
            };
            (dev, job, r)
        }));
    }

    fn finished(&mut self, (dev, job, r): JobResult) {
        self.device = Some(dev);
        self.homing = false;
        match (job, r) {
            (Job::Home, Ok(())) => {
                self.homed = true;
                self.alarm = None;
                self.pos_deg = self.units.to_wire(0f64.clamp(self.limits.min_rad, self.limits.max_rad));
                self.reply(Response::Ok);
            }
            (Job::Move(deg), Ok(())) => self.pos_deg = deg,
            (_, Err(e)) => {
                // The device failed under the controller: a hard fault, like a hard limit.
                tracing::warn!("emulated controller: device failed: {e}");
                self.raise(1);
            }
        }
        if self.job.is_none() && self.alarm.is_none() {
            if let Some(next) = self.queue.pop_front() {
                self.start(Job::Move(next));
            }
        }
    }

    fn raise(&mut self, code: u16) {
        self.alarm = Some(code);
        self.queue.clear();
        if code == 1 || code == 3 {
            self.homed = false;
        }
        self.reply(Response::Alarm(code));
    }

    fn handle(&mut self, c: Result<Command, DecodeError>) {
        let c = match c {
            Ok(c) => c,
            Err(DecodeError::Oversized { .. }) => return self.reply(Response::Error(11)),
            Err(_) => return self.reply(Response::Error(2)),
        };
        match c {
            Command::StatusQuery => {
                let s = Status {
                    state: self.state(),
                    mpos: vec![self.pos_deg, 0.0, 0.0],
                    feed: Some(0.0),
                    pins: String::new(),
                };
                self.reply(Response::Status(s));
            }
            Command::FeedHold => self.hold = self.job.is_some() || !self.queue.is_empty(),
            Command::Resume => self.hold = false,
            Command::SoftReset => {
                if self.job.is_some() || !self.queue.is_empty() {
                    self.raise(3);
                }
                self.queue.clear();
                self.hold = false;
                self.reply(Response::Welcome { version: "1.1h".into() });
            }
            Command::Unlock => {
                self.alarm = None;
                self.homed = true; // GRBL lets an unlocked machine move
                self.reply(Response::Message("MSG:Caution: Unlocked".into()));
                self.reply(Response::Ok);
            }
            Command::Home => {
                if self.job.is_some() {
                    return self.reply(Response::Error(8));
                }
                self.start(Job::Home); // ok when done
            }
            Command::Setting { id, value } => {
                if self.job.is_some() {
                    return self.reply(Response::Error(8));
                }
                self.settings.insert(id, value);
                self.reply(Response::Ok);
            }
            Command::ListSettings => {
                let list: Vec<(u16, f64)> = self.settings.iter().map(|(k, v)| (*k, *v)).collect();
                for (id, value) in list {
                    self.reply(Response::Setting { id, value });
                }
                self.reply(Response::Ok);
            }
            Command::Move { target, .. } => {
                if self.alarm.is_some() || !self.homed {
                    return self.reply(Response::Error(9));
                }
                let soft_limits = self.settings.get(&20).copied().unwrap_or(0.0) != 0.0;
                if soft_limits && !self.limits.contains(self.units.from_wire(target)) {
                    return self.raise(2);
                }
                self.queue.push_back(target);
                if self.job.is_none() {
                    let next = self.queue.pop_front().unwrap_or(target);
                    self.start(Job::Move(next));
                }
                self.reply(Response::Ok);
                for f in std::mem::take(&mut self.armed) {
                    self.fault(f);
                }
            }
        }
    }

    fn fault(&mut self, f: Fault) {
        match f {
            Fault::Garbage(b) => self.wire.write(&b),
            Fault::Alarm(code) => self.raise(code),
            Fault::OnNextMove(f) => self.armed.push(*f),
            Fault::Unplug => {
                if self.wire.replug(&self.link, &self.tx, "emulated GRBL controller") {
                    self.decoder = CommandDecoder::new();
                }
            }
        }
    }
}
