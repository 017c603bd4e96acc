//! The sample robot's controller ([`btfrig_protocols::robot`]) emulated over a
//! pseudo-terminal, driving a `Robot` device (in tests: the simulator's). `MOVE` and
//! `HOME` are answered `OK` at once; `STATUS` shows `MOVING`/`HOMING` until the device has
//! settled. A device failure latches `FAULT` (drive fault) until `RESET`.

use std::path::{Path, PathBuf};

use btfrig_hw::{AxisLimits, DeviceError, MoveOptions, Robot};
use btfrig_protocols::robot::{
    codes, request_decoder, Reply, Request, RequestDecoder, RobotState, RobotStatus, Tagged, UNATTRIBUTED_TAG,
};
use btfrig_protocols::{robot::JointLimit, DecodeError};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::{forwarder, Handle, Wire};

/// Faults a test injects.
#[derive(Debug, Clone)]
pub enum Fault {
    /// Bytes written to the host as noise.
    Garbage(Vec<u8>),
    /// Unplug and replug (the controller keeps state).
    Unplug,
    /// A drive fault: latched `FAULT`, moves refused until `RESET`.
    DriveFault,
    /// Apply the fault right after the next `MOVE` is accepted.
    OnNextMove(Box<Fault>),
}

type Event = super::Event<Fault>;

/// Handle on a running robot controller emulator; dropping it stops it.
pub struct RobotFirmware {
    handle: Handle<Fault>,
}

impl RobotFirmware {
    /// Serves `device` on a new pseudo-terminal behind `link` (call inside a tokio runtime).
    pub fn spawn(device: Box<dyn Robot>, link: &Path) -> std::io::Result<RobotFirmware> {
        let (tx, rx) = mpsc::unbounded_channel();
        let limits = device.joint_limits();
        let emu = Emulator {
            device: Some(device),
            limits,
            job: None,
            homing: false,
            wire: Wire::open(link, 0, forwarder(&tx))?,
            decoder: request_decoder(),
            joints: [0.0; 3],
            homed: false,
            fault: false,
            armed: Vec::new(),
            tx: tx.clone(),
            link: link.to_path_buf(),
        };
        Ok(RobotFirmware { handle: Handle::new(tx, tokio::spawn(emu.run(rx))) })
    }

    /// Injects a fault.
    pub fn inject(&self, fault: Fault) {
        self.handle.inject(fault);
    }
}

type JobResult = (Box<dyn Robot>, Option<[f64; 3]>, Result<(), DeviceError>);

struct Emulator {
    device: Option<Box<dyn Robot>>,
    limits: [AxisLimits; 3],
    job: Option<JoinHandle<JobResult>>,
    homing: bool,
    wire: Wire,
    decoder: RequestDecoder,
    joints: [f64; 3],
    homed: bool,
    fault: bool,
    armed: Vec<Fault>,
    tx: mpsc::UnboundedSender<Event>,
    link: PathBuf,
}

const NO_TIMEOUT: MoveOptions = MoveOptions { timeout_s: 1e9 };

impl Emulator {
    async fn run(mut self, mut rx: mpsc::UnboundedReceiver<Event>) {
        loop {
            tokio::select! {
                ev = rx.recv() => match ev {
                    None => return,
                    Some(Event::Bytes(g, b)) if g == self.wire.generation => {
                        self.decoder.push(&b);
                        while let Some(r) = self.decoder.next() {
                            self.handle(r);
                        }
                    }
                    Some(Event::Bytes(..)) => {}
                    Some(Event::Fault(f)) => self.inject(f),
                },
                done = async { self.job.as_mut().expect("guarded by is_some").await }, if self.job.is_some() => {
                    self.job = None;
                    let Ok((dev, target, r)) = done else { return };
                    self.device = Some(dev);
                    self.homing = false;
                    match (target, r) {
                        (Some(j), Ok(())) => self.joints = j,
                        (None, Ok(())) => {
                            self.homed = true;
                            self.joints = std::array::from_fn(|i| 0f64.clamp(self.limits[i].min_rad, self.limits[i].max_rad));
                        }
                        (_, Err(e)) => {
                            tracing::warn!("emulated robot controller: device failed: {e}");
                            self.fault = true;
                        }
                    }
                }
            }
        }
    }

    fn send(&mut self, tag: u16, body: Reply) {
        if let Ok(b) = (Tagged { tag, body }).encode() {
            self.wire.write(&b);
        }
    }

    fn err(&mut self, tag: u16, code: u16, message: String) {
        self.send(tag, Reply::Error { code, message });
    }

    fn handle(&mut self, r: Result<Tagged<Request>, DecodeError>) {
        let Tagged { tag, body } = match r {
            Ok(t) => t,
            Err(DecodeError::Checksum { .. }) => {
                return self.err(UNATTRIBUTED_TAG, codes::BAD_CHECKSUM, "checksum mismatch".into())
            }
            Err(_) => return self.err(UNATTRIBUTED_TAG, codes::PARSE, "unreadable line".into()),
        };
        match body {
            Request::Id => self.send(
                tag,
                Reply::Id { model: "emulated-robot".into(), serial: "EMU-1".into(), firmware: "1.0".into() },
            ),
            Request::Limits => {
                let l = self.limits.map(|a| JointLimit {
                    min_rad: a.min_rad,
                    max_rad: a.max_rad,
                    max_speed_rad_per_s: a.max_speed_rad_per_s,
                });
                self.send(tag, Reply::Limits(l));
            }
            Request::Status => {
                let state = if self.fault {
                    RobotState::Fault
                } else if self.homing {
                    RobotState::Homing
                } else if self.job.is_some() {
                    RobotState::Moving
                } else {
                    RobotState::Idle
                };
                self.send(tag, Reply::Status(RobotStatus { state, homed: self.homed, joints_rad: self.joints }));
            }
            Request::Stop => self.send(tag, Reply::Ok),
            Request::Reset => {
                self.fault = false;
                self.send(tag, Reply::Ok);
            }
            Request::Home | Request::Move(_) if self.fault => {
                self.err(tag, codes::DRIVE_FAULT, "drive fault latched; RESET after fixing the cause".into())
            }
            Request::Home | Request::Move(_) if self.job.is_some() => self.err(tag, codes::BUSY, "still moving".into()),
            Request::Home => {
                self.start(None);
                self.send(tag, Reply::Ok);
            }
            Request::Move(j) => {
                if !self.homed {
                    return self.err(tag, codes::NOT_HOMED, "home first".into());
                }
                if let Some(i) = (0..3).find(|&i| !self.limits[i].contains(j[i])) {
                    let l = self.limits[i];
                    return self.err(
                        tag,
                        codes::OUT_OF_RANGE,
                        format!(
                            "joint {i} target {:.4} deg outside [{:.4}, {:.4}] deg",
                            j[i].to_degrees(),
                            l.min_rad.to_degrees(),
                            l.max_rad.to_degrees()
                        ),
                    );
                }
                self.start(Some(j));
                self.send(tag, Reply::Ok);
                for f in std::mem::take(&mut self.armed) {
                    self.inject(f);
                }
            }
        }
    }

    fn start(&mut self, target: Option<[f64; 3]>) {
        let Some(mut dev) = self.device.take() else { return };
        self.homing = target.is_none();
        self.job = Some(tokio::spawn(async move {
            let r = match target {
                Some(j) => dev.move_to_rad(j, NO_TIMEOUT).await.map(|_| ()),
                None => dev.home(NO_TIMEOUT).await,
            };
            (dev, target, r)
        }));
    }

    fn inject(&mut self, f: Fault) {
        match f {
            Fault::Garbage(b) => self.wire.write(&b),
            Fault::DriveFault => self.fault = true,
            Fault::OnNextMove(f) => self.armed.push(*f),
            Fault::Unplug => {
                if self.wire.replug(&self.link, &self.tx, "emulated robot controller") {
                    self.decoder = request_decoder();
                }
            }
        }
    }
}
