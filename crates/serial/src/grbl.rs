//! Rail and turntable over a GRBL-style controller ([`btfrig_protocols::grbl`]).
//!
//! A move is `G0 X<deg>` (answered `ok` when planned), then status polls (`?`) on the rig
//! clock until the report says `Idle`; the reported `MPos` is the result. `ALARM:N` and
//! `error:N` become the kinds `btfrig_protocols::grbl` maps them to; after a soft-limit
//! alarm (position kept) the backend unlocks with `$X` so the next request can run. A lost
//! port is `Disconnected`; `reconnect` reopens it and resynchronises by discarding input up
//! to a fresh status report (GRBL replies carry no tag, so a late `ok` must not be taken
//! for the answer to a later line).

use std::sync::Arc;
use std::time::{Duration, Instant};

use async_trait::async_trait;
use btfrig_hw::{
    AxisLimits, Device, DeviceError, DeviceInfo, ErrorKind, Health, MoveOptions, Rail, SharedClock, Turntable,
};
use btfrig_protocols::grbl::{
    alarm_kind, alarm_text, error_kind, error_text, Axis, Command, Response, ResponseDecoder, State, Status,
};

use crate::transport::{Connector, Link, LinkError, Session};

/// What one controller unit of the axis is. GRBL itself is unit-agnostic (its `$100`
/// steps per unit decide); a rotary axis is commonly set up in degrees. Set up in radians,
/// targets cross the line bit for bit (numbers are the shortest decimal that parses back),
/// while `rad.to_degrees().to_radians()` is not always the same `f64`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AxisUnits {
    /// One unit = one degree.
    #[default]
    Degrees,
    /// One unit = one radian.
    Radians,
}

impl AxisUnits {
    /// Radians to controller units.
    pub fn to_wire(self, rad: f64) -> f64 {
        match self {
            AxisUnits::Degrees => rad.to_degrees(),
            AxisUnits::Radians => rad,
        }
    }

    /// Controller units to radians.
    pub fn from_wire(self, v: f64) -> f64 {
        match self {
            AxisUnits::Degrees => v.to_radians(),
            AxisUnits::Radians => v,
        }
    }
}

/// Options of a GRBL axis backend.
#[derive(Debug, Clone)]
pub struct GrblAxisConfig {
    /// Device name in the rig config (`rail`, `turntable`).
    pub name: String,
    /// Model for [`DeviceInfo`].
    pub model: String,
    /// The axis letter the controller drives.
    pub axis: Axis,
    /// Travel and speed (the controller's `$130` and `$110`, in radians).
    pub limits: AxisLimits,
    /// Status poll interval while moving, rig-clock seconds.
    pub poll_s: f64,
    /// How long a line may wait for its answer, wall-clock (link latency is physical).
    pub reply_timeout: Duration,
    /// The controller's unit (as its emulator or `$100` is set up).
    pub units: AxisUnits,
}

/// A rail or turntable on a GRBL-style controller.
pub struct GrblAxis {
    info: DeviceInfo,
    cfg: GrblAxisConfig,
    link: Link<ResponseDecoder>,
    clock: SharedClock,
    /// Discard input up to a fresh status report before the next exchange.
    resync: bool,
}

/// The answer that ends a line: `ok`, `error:N` or `ALARM:N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LineEnd {
    Ok,
    Error(u16),
    Alarm(u16),
}

/// Reads responses until `pick` takes one or `wait` passes (`None`). Undecodable lines are
/// skipped and counted; alarms met on the way are collected.
fn await_response<T>(
    s: &mut Session<ResponseDecoder>,
    wait: Duration,
    alarms: &mut Vec<u16>,
    mut pick: impl FnMut(&Response) -> Option<T>,
) -> Result<Option<T>, LinkError> {
    let deadline = Instant::now() + wait;
    loop {
        while let Some(r) = s.decoder.next() {
            match r {
                Ok(r) => {
                    if let Some(t) = pick(&r) {
                        return Ok(Some(t));
                    }
                    if let Response::Alarm(n) = r {
                        alarms.push(n);
                    }
                }
                Err(e) => {
                    s.skipped += 1;
                    tracing::debug!("grbl: skipped a line: {e}");
                }
            }
        }
        if Instant::now() >= deadline {
            return Ok(None);
        }
        s.fill(deadline, |d, b| d.push(b))?;
    }
}

fn status_of(r: &Response) -> Option<Status> {
    match r {
        Response::Status(s) => Some(s.clone()),
        _ => None,
    }
}

/// Sends `?` and returns the next status report, with alarms seen before it.
fn query_status(s: &mut Session<ResponseDecoder>, wait: Duration) -> Result<(Status, Vec<u16>), LinkError> {
    s.send(&[btfrig_protocols::grbl::REALTIME_STATUS])?;
    let mut alarms = Vec::new();
    match await_response(s, wait, &mut alarms, status_of)? {
        Some(st) => Ok((st, alarms)),
        None => Err(s.timeout(wait, "status report")),
    }
}

impl GrblAxis {
    /// A backend on `connector` (connects on first use), waiting on `clock`.
    pub fn new(cfg: GrblAxisConfig, connector: Arc<dyn Connector>, clock: SharedClock) -> Self {
        let info = DeviceInfo {
            name: cfg.name.clone(),
            backend: "grbl".into(),
            model: cfg.model.clone(),
            serial: None,
            firmware: None,
        };
        GrblAxis { info, cfg, link: Link::new(connector, ResponseDecoder::new), clock, resync: true }
    }

    /// Times the port was (re)opened.
    pub fn connects(&self) -> u64 {
        self.link.connects
    }

    /// Undecodable lines skipped in the current session (garbage on the line).
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

    fn link_err(&mut self, e: LinkError) -> DeviceError {
        self.resync = true;
        e.into_device_error(&self.cfg.name)
    }

    fn alarm_err(&self, code: u16, during: &str) -> DeviceError {
        self.err(alarm_kind(code), format!("{during}: controller ALARM:{code}: {}", alarm_text(code)))
    }

    /// Sends a line and waits (up to `clock_timeout_s` of rig time, at least the reply
    /// timeout) for the answer that ends it.
    async fn line(&mut self, cmd: Command, clock_timeout_s: f64) -> Result<LineEnd, DeviceError> {
        let bytes = cmd.encode().map_err(|e| self.err(ErrorKind::OutOfRange, e.to_string()))?;
        let wait = self.cfg.reply_timeout;
        let resync = std::mem::take(&mut self.resync);
        let sent = self
            .link
            .run(move |s| {
                if resync {
                    // Anything before a fresh status report belongs to an older exchange.
                    query_status(s, wait)?;
                }
                s.send(&bytes)
            })
            .await;
        sent.map_err(|e| self.link_err(e))?;
        let start = self.clock.now_s();
        let wall_deadline = Instant::now() + wait;
        // The first wait covers a prompt answer; a line answered only when done (`$H`) is
        // then awaited in short slices with rig-clock sleeps between, so a virtual rig clock
        // can advance (tokio does not advance paused time while a blocking read runs).
        let mut slice = Duration::from_millis(50);
        let mut first = true;
        loop {
            if !std::mem::take(&mut first) {
                self.clock.sleep_s(self.cfg.poll_s).await;
                slice = Duration::from_millis(1);
            }
            let got = self
                .link
                .run(move |s| {
                    let mut alarms = Vec::new();
                    await_response(s, slice, &mut alarms, |r| match r {
                        Response::Ok => Some(LineEnd::Ok),
                        Response::Error(n) => Some(LineEnd::Error(*n)),
                        Response::Alarm(n) => Some(LineEnd::Alarm(*n)),
                        _ => None,
                    })
                })
                .await
                .map_err(|e| self.link_err(e))?;
            if let Some(end) = got {
                return Ok(end);
            }
            if Instant::now() >= wall_deadline && self.clock.now_s() - start >= clock_timeout_s {
                self.resync = true;
                return Err(self.err(ErrorKind::Timeout, format!("no answer to {cmd:?} from {}", self.link.describe())));
            }
        }
    }

    async fn status(&mut self) -> Result<(Status, Vec<u16>), DeviceError> {
        let wait = self.cfg.reply_timeout;
        let resync = std::mem::take(&mut self.resync);
        self.link
            .run(move |s| {
                if resync {
                    query_status(s, wait)?;
                }
                query_status(s, wait)
            })
            .await
            .map_err(|e| self.link_err(e))
    }

    /// Maps a line's end to a result; unlocks after a soft-limit alarm (position kept).
    async fn check_end(&mut self, end: LineEnd, what: &str) -> Result<(), DeviceError> {
        match end {
            LineEnd::Ok => Ok(()),
            LineEnd::Error(n) => {
                Err(self.err(error_kind(n), format!("{what}: controller error:{n}: {}", error_text(n))))
            }
            LineEnd::Alarm(n) => {
                let e = self.alarm_err(n, what);
                if n == 2 {
                    let _ = self.line(Command::Unlock, 0.0).await;
                }
                Err(e)
            }
        }
    }

    async fn do_home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        let end = self.line(Command::Home, opts.timeout_s).await?;
        self.check_end(end, "home").await
    }

    async fn do_move(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError> {
        let start = self.clock.now_s();
        let cmd =
            Command::Move { rapid: true, axis: self.cfg.axis, target: self.cfg.units.to_wire(angle_rad), feed: None };
        let end = self.line(cmd, 0.0).await?;
        self.check_end(end, "move_to_rad").await?;
        loop {
            let (st, alarms) = self.status().await?;
            if let Some(&n) = alarms.first() {
                return Err(self.alarm_err(n, "move_to_rad"));
            }
            match st.state {
                State::Idle => {
                    return Ok(self
                        .cfg
                        .units
                        .from_wire(st.mpos.get(self.cfg.axis.index()).copied().unwrap_or(f64::NAN)))
                }
                State::Alarm => return Err(self.err(ErrorKind::Other, "move_to_rad: controller in alarm state")),
                _ => {}
            }
            if self.clock.now_s() - start > opts.timeout_s {
                return Err(
                    self.err(ErrorKind::Timeout, format!("move_to_rad: not settled within {} s", opts.timeout_s))
                );
            }
            self.clock.sleep_s(self.cfg.poll_s).await;
        }
    }

    async fn do_position(&mut self) -> Result<f64, DeviceError> {
        let (st, _) = self.status().await?;
        if st.state == State::Alarm {
            return Err(self.err(ErrorKind::NotHomed, "position_rad: controller locked (alarm); home first"));
        }
        Ok(self.cfg.units.from_wire(st.mpos.get(self.cfg.axis.index()).copied().unwrap_or(f64::NAN)))
    }

    async fn do_stop(&mut self) -> Result<(), DeviceError> {
        // Feed hold, then soft reset flushes the rest of the move (GRBL's documented stop).
        self.link
            .run(|s| s.send(&[btfrig_protocols::grbl::REALTIME_FEED_HOLD, btfrig_protocols::grbl::REALTIME_SOFT_RESET]))
            .await
            .map_err(|e| self.link_err(e))?;
        self.resync = true;
        Ok(())
    }
}

#[async_trait]
impl Device for GrblAxis {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    async fn health(&mut self) -> Result<Health, DeviceError> {
        let (st, _) = self.status().await?;
        Ok(match st.state {
            State::Alarm => Health::Fault("controller in alarm state ($H or $X needed)".into()),
            State::Door(_) => Health::Fault("safety door open".into()),
            _ => Health::Ok,
        })
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        self.link.drop_session();
        self.resync = true;
        self.status().await.map(|_| ())
    }
}

#[async_trait]
impl Rail for GrblAxis {
    fn limits(&self) -> AxisLimits {
        self.cfg.limits
    }
    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        self.do_home(opts).await
    }
    async fn move_to_rad(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError> {
        self.do_move(angle_rad, opts).await
    }
    async fn position_rad(&mut self) -> Result<f64, DeviceError> {
        self.do_position().await
    }
    async fn stop(&mut self) -> Result<(), DeviceError> {
        self.do_stop().await
    }
}

#[async_trait]
impl Turntable for GrblAxis {
    fn limits(&self) -> AxisLimits {
        self.cfg.limits
    }
    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        self.do_home(opts).await
    }
    async fn move_to_rad(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError> {
        self.do_move(angle_rad, opts).await
    }
    async fn position_rad(&mut self) -> Result<f64, DeviceError> {
        self.do_position().await
    }
    async fn stop(&mut self) -> Result<(), DeviceError> {
        self.do_stop().await
    }
}
