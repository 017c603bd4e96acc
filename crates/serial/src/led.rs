//! The LED array over the LED dome controller's binary protocol ([`btfrig_protocols::led`]).
//!
//! Requests carry a sequence number (1..=255, 0 skipped) that replies echo; replies with
//! another number (late answers to abandoned requests) are dropped, so no resynchronisation
//! step is needed. A `Nack` with `seq` 0 (the controller could not read a frame) fails the
//! call as `CorruptData`, retryable. `set_pattern` quantises each fraction to
//! `round(v * (steps - 1))`, stages it, triggers, polls `GetStatus` on the rig clock until
//! `staged` clears and reads the lit pattern back, so it returns once the pattern is lit.

use std::sync::Arc;
use std::time::{Duration, Instant};

use async_trait::async_trait;
use btfrig_hw::{
    Device, DeviceError, DeviceInfo, ErrorKind, Health, LedArray, LedCapabilities, LedPattern, SharedClock,
};
use btfrig_protocols::led::{nack_kind, reply_decoder, Decoder, LedStatus, Reply, Request};

use crate::transport::{Connector, Link, LinkError};

/// Options of the LED backend.
#[derive(Debug, Clone)]
pub struct SerialLedConfig {
    /// Device name (`led_array`).
    pub name: String,
    /// Status poll interval while a pattern is being lit, rig-clock seconds.
    pub poll_s: f64,
    /// How long a request may wait for its reply, wall-clock.
    pub reply_timeout: Duration,
}

/// An LED array on the btfrig LED dome controller.
pub struct SerialLedArray {
    info: DeviceInfo,
    cfg: SerialLedConfig,
    caps: LedCapabilities,
    link: Link<Decoder<Reply>>,
    clock: SharedClock,
    seq: u8,
}

impl SerialLedArray {
    /// Connects on `connector` and reads the controller's LED count and steps.
    pub async fn open(
        cfg: SerialLedConfig,
        connector: Arc<dyn Connector>,
        clock: SharedClock,
    ) -> Result<Self, DeviceError> {
        let info = DeviceInfo {
            name: cfg.name.clone(),
            backend: "serial-led".into(),
            model: "btfrig LED dome controller".into(),
            serial: None,
            firmware: None,
        };
        let caps = LedCapabilities { count: 0, intensity_steps: 2 };
        let mut led = SerialLedArray { info, cfg, caps, link: Link::new(connector, reply_decoder), clock, seq: 0 };
        match led.request(Request::GetInfo, "info").await? {
            Reply::Info { count, steps, firmware } => {
                led.caps = LedCapabilities { count: usize::from(count), intensity_steps: steps.max(2) };
                led.info.firmware = Some(format!("{}.{}", firmware.0, firmware.1));
            }
            other => return Err(led.unexpected("info", &other)),
        }
        Ok(led)
    }

    /// Times the port was (re)opened.
    pub fn connects(&self) -> u64 {
        self.link.connects
    }

    /// Undecodable frames and garbage runs skipped in the current session.
    pub fn skipped_frames(&mut self) -> u64 {
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

    /// One request and its reply; a `Nack` becomes the mapped error.
    async fn request(&mut self, req: Request, what: &str) -> Result<Reply, DeviceError> {
        self.seq = self.seq.checked_add(1).unwrap_or(1);
        let seq = self.seq;
        let bytes = req.encode(seq).map_err(|e| self.err(ErrorKind::OutOfRange, format!("{what}: {e}")))?;
        let wait = self.cfg.reply_timeout;
        let (rseq, reply) = self
            .link
            .run(move |s| {
                s.send(&bytes)?;
                let deadline = Instant::now() + wait;
                loop {
                    while let Some(r) = s.decoder.next() {
                        match r {
                            Ok((q, reply)) if q == seq || q == 0 => return Ok((q, reply)),
                            Ok(_) => {} // a late reply to an abandoned request
                            Err(e) => {
                                s.skipped += 1;
                                tracing::debug!("led: skipped: {e}");
                            }
                        }
                    }
                    if Instant::now() >= deadline {
                        return Err(s.timeout(wait, "LED controller reply"));
                    }
                    s.fill(deadline, |d, b| d.push(b))?;
                }
            })
            .await
            .map_err(|e: LinkError| e.into_device_error(&self.cfg.name))?;
        match reply {
            Reply::Nack(code) => {
                let who = if rseq == 0 { " (request damaged on the line)" } else { "" };
                Err(self.err(nack_kind(code), format!("{what}: controller NACK {code}{who}: {}", nack_text(code))))
            }
            other => Ok(other),
        }
    }

    async fn status(&mut self) -> Result<LedStatus, DeviceError> {
        match self.request(Request::GetStatus, "status").await? {
            Reply::Status(s) => Ok(s),
            other => Err(self.unexpected("status", &other)),
        }
    }
}

fn nack_text(code: u8) -> &'static str {
    use btfrig_protocols::led::codes::*;
    match code {
        BAD_CRC => "bad CRC",
        BAD_LENGTH => "bad length",
        UNKNOWN_KIND => "unknown kind",
        WRONG_COUNT => "pattern length is not the LED count",
        VALUE_TOO_HIGH => "an intensity is at or above the step count",
        OVER_TEMPERATURE => "over temperature, LEDs off until the board cools",
        NOTHING_STAGED => "trigger with nothing staged",
        BUSY => "busy lighting the previous pattern",
        DRIVER_FAULT => "lighting failed: driver fault",
        _ => "unknown code",
    }
}

#[async_trait]
impl Device for SerialLedArray {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    async fn health(&mut self) -> Result<Health, DeviceError> {
        let s = self.status().await?;
        Ok(if s.driver_fault {
            Health::Fault("LED driver fault".into())
        } else if s.over_temperature {
            Health::Warning("LED driver board over temperature".into())
        } else {
            Health::Ok
        })
    }

    async fn temperature_c(&mut self) -> Result<Option<f64>, DeviceError> {
        match self.request(Request::GetTemperature, "temperature").await? {
            Reply::Temperature(c) => Ok(Some(f64::from(c) / 100.0)),
            other => Err(self.unexpected("temperature", &other)),
        }
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        self.link.drop_session();
        self.status().await.map(|_| ())
    }
}

#[async_trait]
impl LedArray for SerialLedArray {
    fn capabilities(&self) -> LedCapabilities {
        self.caps.clone()
    }

    async fn set_pattern(&mut self, pattern: &LedPattern) -> Result<(), DeviceError> {
        let n = self.caps.count;
        if pattern.intensities.len() != n {
            return Err(DeviceError::out_of_range(&self.cfg.name, "pattern length", pattern.intensities.len(), n));
        }
        if let Some((i, v)) = pattern.intensities.iter().enumerate().find(|(_, v)| !(0.0..=1.0).contains(*v)) {
            return Err(DeviceError::out_of_range(&self.cfg.name, &format!("intensity of LED {i}"), v, "[0, 1]"));
        }
        let top = f64::from(self.caps.intensity_steps - 1);
        let values: Vec<u16> =
            pattern.intensities.iter().map(|v| (v * top).round().min(f64::from(u16::MAX)) as u16).collect();
        self.request(Request::SetPattern(values.clone()), "set_pattern").await?;
        self.request(Request::Trigger, "set_pattern (trigger)").await?;
        let start = self.clock.now_s();
        loop {
            let s = self.status().await?;
            if !s.staged {
                // Read back: a failure while lighting is latched and answers this request.
                return match self.request(Request::GetPattern, "set_pattern (read back)").await? {
                    Reply::Pattern(lit) if lit == values => Ok(()),
                    Reply::Pattern(_) => {
                        Err(self
                            .err(ErrorKind::CorruptData, "set_pattern: the controller lit another pattern than sent"))
                    }
                    other => Err(self.unexpected("set_pattern (read back)", &other)),
                };
            }
            if self.clock.now_s() - start > 10.0 {
                return Err(self.err(ErrorKind::Timeout, "set_pattern: not lit within 10 s"));
            }
            self.clock.sleep_s(self.cfg.poll_s).await;
        }
    }

    async fn pattern(&mut self) -> Result<LedPattern, DeviceError> {
        let top = f64::from(self.caps.intensity_steps - 1);
        match self.request(Request::GetPattern, "pattern").await? {
            Reply::Pattern(v) => Ok(LedPattern { intensities: v.iter().map(|&x| f64::from(x) / top).collect() }),
            other => Err(self.unexpected("pattern", &other)),
        }
    }
}
