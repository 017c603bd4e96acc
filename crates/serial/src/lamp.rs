//! The lamp over the lamp controller's line protocol ([`btfrig_protocols::lamp`]).
//!
//! One request line, one reply line. Replies carry no tag, so after a timeout or a lost
//! port the backend first sends `*IDN?` and discards everything before the `IDN` answer:
//! a late reply cannot be taken for the answer to a later request. A setting is answered
//! `OK` when accepted; the backend then polls `STAT?` on the rig clock (`ERR 6`, busy, while
//! the controller applies it) until the state shows it, so a setting returns once applied.
//! `wait_ready` polls `STAT?` and sleeps the warm-up time the controller reports.

use std::sync::Arc;
use std::time::{Duration, Instant};

use async_trait::async_trait;
use btfrig_hw::{
    Device, DeviceError, DeviceInfo, ErrorKind, Health, Lamp, LampCapabilities, LampStatus, SharedClock, WarmUp,
};
use btfrig_protocols::lamp::{error_kind, reply_decoder, LampState, Reply, Request, Warm};
use btfrig_protocols::line::LineDecoder;

use crate::transport::{Connector, Link, LinkError, Session};

/// Options of the lamp backend.
#[derive(Debug, Clone)]
pub struct SerialLampConfig {
    /// Device name (`lamp`).
    pub name: String,
    /// Poll interval while a setting is applied, rig-clock seconds.
    pub poll_s: f64,
    /// How long a request may wait for its reply, wall-clock.
    pub reply_timeout: Duration,
}

/// A lamp on the btfrig lamp controller.
pub struct SerialLamp {
    info: DeviceInfo,
    cfg: SerialLampConfig,
    caps: LampCapabilities,
    link: Link<LineDecoder<Reply>>,
    clock: SharedClock,
    resync: bool,
}

/// Reads replies until one decodes or `wait` passes. Undecodable lines are counted.
fn await_reply(
    s: &mut Session<LineDecoder<Reply>>,
    wait: Duration,
    mut pick: impl FnMut(&Reply) -> bool,
) -> Result<Reply, LinkError> {
    let deadline = Instant::now() + wait;
    loop {
        while let Some(r) = s.decoder.next() {
            match r {
                Ok(reply) if pick(&reply) => return Ok(reply),
                Ok(other) => tracing::debug!("lamp: dropped a stale reply {other:?}"),
                Err(e) => {
                    s.skipped += 1;
                    tracing::debug!("lamp: skipped a line: {e}");
                }
            }
        }
        if Instant::now() >= deadline {
            return Err(s.timeout(wait, "lamp reply"));
        }
        s.fill(deadline, |d, b| d.push(b))?;
    }
}

impl SerialLamp {
    /// Connects on `connector`, reads the controller's identity and capabilities.
    pub async fn open(
        cfg: SerialLampConfig,
        connector: Arc<dyn Connector>,
        clock: SharedClock,
    ) -> Result<Self, DeviceError> {
        let info = DeviceInfo {
            name: cfg.name.clone(),
            backend: "serial-lamp".into(),
            model: "btfrig lamp controller".into(),
            serial: None,
            firmware: None,
        };
        let caps = LampCapabilities { has_shutter: false, intensity_range: None, warm_up_s: 0.0 };
        let mut lamp = SerialLamp { info, cfg, caps, link: Link::new(connector, reply_decoder), clock, resync: true };
        if let Reply::Identity(f) = lamp.request(Request::Identify, "identify").await? {
            lamp.info.model = f.get(1).cloned().unwrap_or_default();
            lamp.info.serial = f.get(2).cloned();
            lamp.info.firmware = f.get(3).cloned();
        }
        match lamp.request(Request::Capabilities, "capabilities").await? {
            Reply::Capabilities(c) => {
                lamp.caps =
                    LampCapabilities { has_shutter: c.shutter, intensity_range: c.dim_range, warm_up_s: c.warm_up_s }
            }
            other => return Err(lamp.unexpected("capabilities", &other)),
        }
        Ok(lamp)
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

    fn unexpected(&self, what: &str, r: &Reply) -> DeviceError {
        self.err(ErrorKind::CorruptData, format!("{what}: unexpected reply {r:?}"))
    }

    /// One request and its reply; `ERR` becomes the mapped error.
    async fn request(&mut self, req: Request, what: &str) -> Result<Reply, DeviceError> {
        let bytes = req.encode().map_err(|e| self.err(ErrorKind::OutOfRange, format!("{what}: {e}")))?;
        let wait = self.cfg.reply_timeout;
        let resync = std::mem::take(&mut self.resync);
        let r = self
            .link
            .run(move |s| {
                if resync {
                    s.decoder.clear();
                    s.send(&Request::Identify.encode().unwrap_or_default())?;
                    await_reply(s, wait, |r| matches!(r, Reply::Identity(_)))?;
                }
                s.send(&bytes)?;
                await_reply(s, wait, |_| true)
            })
            .await;
        let reply = match r {
            Ok(r) => r,
            Err(e) => {
                self.resync = true;
                return Err(e.into_device_error(&self.cfg.name));
            }
        };
        match reply {
            Reply::Error { code, message } => {
                Err(self.err(error_kind(code), format!("{what}: controller ERR {code}: {message}")))
            }
            other => Ok(other),
        }
    }

    async fn state(&mut self) -> Result<LampState, DeviceError> {
        match self.request(Request::Status, "status").await? {
            Reply::Status(s) => Ok(s),
            other => Err(self.unexpected("status", &other)),
        }
    }

    /// The state once the controller has applied the last setting (polls while `ERR 6`).
    async fn settled_state(&mut self, what: &str) -> Result<LampState, DeviceError> {
        let start = self.clock.now_s();
        loop {
            match self.state().await {
                Err(e) if e.kind() == ErrorKind::Busy && self.clock.now_s() - start < 60.0 => {
                    self.clock.sleep_s(self.cfg.poll_s).await
                }
                Err(e) => return Err(self.err(e.kind(), format!("{what}: {}", e.message()))),
                Ok(s) => return Ok(s),
            }
        }
    }

    /// A setting, then the state once applied.
    async fn set(&mut self, req: Request, what: &str) -> Result<LampState, DeviceError> {
        self.request(req, what).await?;
        self.settled_state(what).await
    }

    /// Burner hours the controller counts.
    pub async fn hours(&mut self) -> Result<f64, DeviceError> {
        match self.request(Request::QueryHours, "hours").await? {
            Reply::Hours(h) => Ok(h),
            other => Err(self.unexpected("hours", &other)),
        }
    }
}

fn status_of(s: LampState) -> LampStatus {
    LampStatus {
        on: s.on,
        shutter_open: s.shutter_open,
        intensity: s.intensity,
        warm_up: match s.warm {
            Warm::Off => WarmUp::Off,
            Warm::Warming(remaining_s) => WarmUp::WarmingUp { remaining_s },
            Warm::Ready => WarmUp::Ready,
        },
    }
}

#[async_trait]
impl Device for SerialLamp {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    async fn health(&mut self) -> Result<Health, DeviceError> {
        Ok(match self.settled_state("health").await?.warm {
            Warm::Warming(left) => Health::Warning(format!("warming up, {left:.0} s left")),
            _ => Health::Ok,
        })
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        self.link.drop_session();
        self.resync = true;
        self.request(Request::Identify, "reconnect").await.map(|_| ())
    }
}

#[async_trait]
impl Lamp for SerialLamp {
    fn capabilities(&self) -> LampCapabilities {
        self.caps.clone()
    }

    async fn set_on(&mut self, on: bool) -> Result<(), DeviceError> {
        self.set(Request::SetOn(on), "set_on").await.map(|_| ())
    }

    async fn status(&mut self) -> Result<LampStatus, DeviceError> {
        self.settled_state("status").await.map(status_of)
    }

    async fn wait_ready(&mut self, timeout_s: f64) -> Result<(), DeviceError> {
        let start = self.clock.now_s();
        loop {
            let s = self.settled_state("wait_ready").await?;
            let elapsed = self.clock.now_s() - start;
            match s.warm {
                Warm::Off => return Err(self.err(ErrorKind::Other, "wait_ready: the lamp is off")),
                Warm::Ready => return Ok(()),
                Warm::Warming(left) if elapsed + left > timeout_s => {
                    self.clock.sleep_s((timeout_s - elapsed).max(0.0)).await;
                    let left = left - (timeout_s - elapsed).max(0.0);
                    return Err(self.err(
                        ErrorKind::Timeout,
                        format!("wait_ready: still warming up after {timeout_s} s ({left:.0} s left)"),
                    ));
                }
                Warm::Warming(left) => self.clock.sleep_s(left).await,
            }
        }
    }

    async fn set_shutter_open(&mut self, open: bool) -> Result<(), DeviceError> {
        if !self.caps.has_shutter {
            return Err(DeviceError::unsupported(&self.cfg.name, "shutter"));
        }
        self.set(Request::SetShutterOpen(open), "set_shutter_open").await.map(|_| ())
    }

    async fn set_intensity(&mut self, fraction: f64) -> Result<(), DeviceError> {
        match self.caps.intensity_range {
            None => Err(DeviceError::unsupported(&self.cfg.name, "intensity control")),
            Some((lo, hi)) if !(lo..=hi).contains(&fraction) => {
                Err(DeviceError::out_of_range(&self.cfg.name, "intensity", fraction, format!("[{lo}, {hi}]")))
            }
            Some(_) => self.set(Request::SetIntensity(fraction), "set_intensity").await.map(|_| ()),
        }
    }
}
