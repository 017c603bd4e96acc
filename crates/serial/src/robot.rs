//! The sample robot over its tagged line protocol ([`btfrig_protocols::robot`]).
//!
//! Each request carries a fresh tag; replies with another tag (late answers to abandoned
//! requests) are dropped, so no resynchronisation step is needed after a timeout. A reply
//! tagged 0 (`ERR 1`/`ERR 2`: the controller could not read a request) fails the call as
//! `CorruptData`, retryable. Moves: `MOVE`, then `STATUS` polls on the rig clock until
//! `IDLE`; the reported joints are the result.

use std::sync::Arc;
use std::time::{Duration, Instant};

use async_trait::async_trait;
use btfrig_hw::{AxisLimits, Device, DeviceError, DeviceInfo, ErrorKind, Health, MoveOptions, Robot, SharedClock};
use btfrig_protocols::robot::{
    error_kind, reply_decoder, Reply, ReplyDecoder, Request, RobotState, RobotStatus, Tagged, UNATTRIBUTED_TAG,
};

use crate::transport::{Connector, Link, LinkError};

/// Options of the robot backend.
#[derive(Debug, Clone)]
pub struct SerialRobotConfig {
    /// Device name (`robot`).
    pub name: String,
    /// Joint limits as configured (the controller's own are checked by it).
    pub joint_limits: [AxisLimits; 3],
    /// Status poll interval while moving, rig-clock seconds.
    pub poll_s: f64,
    /// How long a request may wait for its reply, wall-clock.
    pub reply_timeout: Duration,
}

/// A robot on the btfrig robot controller.
pub struct SerialRobot {
    info: DeviceInfo,
    cfg: SerialRobotConfig,
    link: Link<ReplyDecoder>,
    clock: SharedClock,
    tag: u16,
}

impl SerialRobot {
    /// A backend on `connector` (connects on first use), waiting on `clock`.
    pub fn new(cfg: SerialRobotConfig, connector: Arc<dyn Connector>, clock: SharedClock) -> Self {
        let info = DeviceInfo {
            name: cfg.name.clone(),
            backend: "serial-robot".into(),
            model: "btfrig robot controller".into(),
            serial: None,
            firmware: None,
        };
        SerialRobot { info, cfg, link: Link::new(connector, reply_decoder), clock, tag: 0 }
    }

    /// Asks the controller who it is (`ID`) and keeps it in [`Device::info`].
    pub async fn identify(&mut self) -> Result<(), DeviceError> {
        if let Reply::Id { model, serial, firmware } = self.request(Request::Id, "identify").await? {
            self.info.model = model;
            self.info.serial = Some(serial);
            self.info.firmware = Some(firmware);
        }
        Ok(())
    }

    /// Times the port was (re)opened.
    pub fn connects(&self) -> u64 {
        self.link.connects
    }

    /// Undecodable lines skipped in the current session.
    pub fn skipped_lines(&mut self) -> u64 {
        self.link.skipped()
    }

    /// The link's counters over all sessions (see [`crate::transport::LinkStats`]).
    pub fn link_stats(&self) -> std::sync::Arc<crate::transport::LinkStats> {
        self.link.stats()
    }

    fn err(&self, kind: ErrorKind, msg: impl Into<String>) -> DeviceError {
        DeviceError::new(&self.cfg.name, kind, msg)
    }

    /// One request, its reply (an `ERR` becomes the mapped error).
    async fn request(&mut self, body: Request, what: &str) -> Result<Reply, DeviceError> {
        self.tag = self.tag.checked_add(1).unwrap_or(1);
        let tag = self.tag;
        let bytes =
            Tagged { tag, body }.encode().map_err(|e| self.err(ErrorKind::OutOfRange, format!("{what}: {e}")))?;
        let wait = self.cfg.reply_timeout;
        let reply = self
            .link
            .run(move |s| {
                s.send(&bytes)?;
                let deadline = Instant::now() + wait;
                loop {
                    while let Some(r) = s.decoder.next() {
                        match r {
                            Ok(t) if t.tag == tag || t.tag == UNATTRIBUTED_TAG => return Ok(t),
                            Ok(_) => {} // a late reply to an abandoned request
                            Err(e) => {
                                s.skipped += 1;
                                tracing::debug!("robot: skipped a line: {e}");
                            }
                        }
                    }
                    if Instant::now() >= deadline {
                        return Err(s.timeout(wait, "robot reply"));
                    }
                    s.fill(deadline, |d, b| d.push(b))?;
                }
            })
            .await
            .map_err(|e: LinkError| e.into_device_error(&self.cfg.name))?;
        match reply.body {
            Reply::Error { code, message } => {
                let who = if reply.tag == UNATTRIBUTED_TAG { " (request damaged on the line)" } else { "" };
                Err(self.err(error_kind(code), format!("{what}: controller ERR {code}{who}: {message}")))
            }
            other => Ok(other),
        }
    }

    async fn status(&mut self) -> Result<RobotStatus, DeviceError> {
        match self.request(Request::Status, "status").await? {
            Reply::Status(s) => Ok(s),
            other => Err(self.err(ErrorKind::CorruptData, format!("status: unexpected reply {other:?}"))),
        }
    }

    /// Polls until the robot stands; its joints.
    async fn settle(&mut self, what: &str, opts: MoveOptions, start: f64) -> Result<[f64; 3], DeviceError> {
        loop {
            let s = self.status().await?;
            match s.state {
                RobotState::Idle => return Ok(s.joints_rad),
                RobotState::Fault => {
                    return Err(self.err(
                        ErrorKind::Other,
                        format!("{what}: controller reports a drive fault (RESET after fixing it)"),
                    ))
                }
                RobotState::Moving | RobotState::Homing => {}
            }
            if self.clock.now_s() - start > opts.timeout_s {
                return Err(self.err(ErrorKind::Timeout, format!("{what}: not settled within {} s", opts.timeout_s)));
            }
            self.clock.sleep_s(self.cfg.poll_s).await;
        }
    }
}

#[async_trait]
impl Device for SerialRobot {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    async fn health(&mut self) -> Result<Health, DeviceError> {
        Ok(match self.status().await?.state {
            RobotState::Fault => Health::Fault("drive fault latched".into()),
            _ => Health::Ok,
        })
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        self.link.drop_session();
        self.status().await.map(|_| ())
    }
}

#[async_trait]
impl Robot for SerialRobot {
    fn joint_limits(&self) -> [AxisLimits; 3] {
        self.cfg.joint_limits
    }

    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        let start = self.clock.now_s();
        self.request(Request::Home, "home").await?;
        self.settle("home", opts, start).await.map(|_| ())
    }

    async fn move_to_rad(&mut self, joints_rad: [f64; 3], opts: MoveOptions) -> Result<[f64; 3], DeviceError> {
        let start = self.clock.now_s();
        // A re-issued move after a lost link may find the first still running: Busy is
        // retryable, and the engine's retry then lands here again.
        self.request(Request::Move(joints_rad), "move_to_rad").await?;
        self.settle("move_to_rad", opts, start).await
    }

    async fn position_rad(&mut self) -> Result<[f64; 3], DeviceError> {
        let s = self.status().await?;
        if !s.homed {
            return Err(self.err(ErrorKind::NotHomed, "position_rad: position unknown before homing"));
        }
        Ok(s.joints_rad)
    }

    async fn is_homed(&mut self) -> Result<bool, DeviceError> {
        Ok(self.status().await?.homed)
    }

    async fn stop(&mut self) -> Result<(), DeviceError> {
        self.request(Request::Stop, "stop").await.map(|_| ())
    }
}
