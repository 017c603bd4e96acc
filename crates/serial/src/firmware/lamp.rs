//! The lamp controller ([`btfrig_protocols::lamp`]) emulated over a pseudo-terminal, driving
//! a `Lamp` device (in tests: the simulator's).
//!
//! A setting (`OUTP`, `SHUT`, `INT`) is checked, answered `OK` at once and then applied to
//! the device, which takes its switch time on the rig clock; until it is applied every
//! query but `*IDN?` answers `ERR 6` (busy, retry later), so the host polls on its clock.
//! (Answering only when done would stall a host that waits in a blocking read while the
//! rig clock is virtual: tokio does not advance paused time while a blocking task runs.)
//! A device failure while applying is latched and is the answer to the next request.
//! Burner hours are counted by the controller from its on-time on the rig clock.

use std::path::{Path, PathBuf};

use btfrig_hw::{DeviceError, ErrorKind, Lamp, LampCapabilities, LampStatus, SharedClock, WarmUp};
use btfrig_protocols::lamp::{codes, request_decoder, LampCaps, LampState, Reply, Request, Warm};
use btfrig_protocols::line::LineDecoder;
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
    /// Refuse the next setting with `ERR code text` (4 = ignition failed, 6 = restrike lockout).
    Refuse(u16, String),
    /// Read the next request and never answer it (the host times out).
    Swallow,
    /// Apply the fault right after the next setting is answered `OK`.
    OnNextSetting(Box<Fault>),
}

type Event = super::Event<Fault>;

/// Options of the emulated controller.
#[derive(Debug, Clone)]
pub struct LampFirmwareConfig {
    /// Burner hours at start.
    pub hours: f64,
    /// `*IDN?` fields: maker, model, serial, firmware.
    pub identity: [String; 4],
}

impl Default for LampFirmwareConfig {
    fn default() -> Self {
        LampFirmwareConfig {
            hours: 100.0,
            identity: ["btfrig".into(), "emulated-lamp".into(), "EMU-L1".into(), "1.0".into()],
        }
    }
}

/// Handle on a running lamp controller emulator; dropping it stops it.
pub struct LampFirmware {
    handle: Handle<Fault>,
}

impl LampFirmware {
    /// Serves `device` on a new pseudo-terminal behind `link` (call inside a tokio runtime);
    /// `clock` is the rig clock burner hours are counted on.
    pub fn spawn(
        device: Box<dyn Lamp>,
        cfg: LampFirmwareConfig,
        clock: SharedClock,
        link: &Path,
    ) -> std::io::Result<LampFirmware> {
        let (tx, rx) = mpsc::unbounded_channel();
        let emu = Emulator {
            caps: device.capabilities(),
            device: Some(device),
            job: None,
            wire: Wire::open(link, 0, forwarder(&tx))?,
            decoder: request_decoder(),
            latched: None,
            refuse: None,
            swallow: false,
            armed: Vec::new(),
            hours_base: cfg.hours,
            on_since: None,
            cfg,
            clock,
            tx: tx.clone(),
            link: link.to_path_buf(),
        };
        Ok(LampFirmware { handle: Handle::new(tx, tokio::spawn(emu.run(rx))) })
    }

    /// Injects a fault.
    pub fn inject(&self, fault: Fault) {
        self.handle.inject(fault);
    }
}

/// The ERR code for a device error met while applying a setting.
fn code_of(e: &DeviceError) -> u16 {
    match e.kind() {
        ErrorKind::OutOfRange => codes::OUT_OF_RANGE,
        ErrorKind::Unsupported => codes::UNSUPPORTED,
        ErrorKind::Busy => codes::RESTRIKE_LOCKOUT,
        _ => codes::IGNITION_FAILED,
    }
}

type Job = JoinHandle<(Box<dyn Lamp>, Result<(), DeviceError>)>;

struct Emulator {
    device: Option<Box<dyn Lamp>>,
    caps: LampCapabilities,
    job: Option<Job>,
    wire: Wire,
    decoder: LineDecoder<Request>,
    latched: Option<(u16, String)>,
    refuse: Option<(u16, String)>,
    swallow: bool,
    armed: Vec<Fault>,
    hours_base: f64,
    on_since: Option<f64>,
    cfg: LampFirmwareConfig,
    clock: SharedClock,
    tx: mpsc::UnboundedSender<Event>,
    link: PathBuf,
}

impl Emulator {
    async fn run(mut self, mut rx: mpsc::UnboundedReceiver<Event>) {
        loop {
            tokio::select! {
                ev = rx.recv() => match ev {
                    None => return,
                    Some(Event::Bytes(g, b)) if g == self.wire.generation => {
                        self.decoder.push(&b);
                        while let Some(r) = self.decoder.next() {
                            match r {
                                Ok(req) => self.handle(req).await,
                                Err(_) => self.send(Reply::Error { code: codes::SYNTAX, message: "unreadable line".into() }),
                            }
                        }
                    }
                    Some(Event::Bytes(..)) => {}
                    Some(Event::Fault(f)) => self.inject(f),
                },
                done = async { self.job.as_mut().expect("guarded by is_some").await }, if self.job.is_some() => {
                    self.job = None;
                    let Ok((dev, r)) = done else { return };
                    self.device = Some(dev);
                    if let Err(e) = r {
                        tracing::warn!("emulated lamp controller: device failed: {e}");
                        self.latched = Some((code_of(&e), e.message().to_string()));
                    }
                    self.track_hours().await;
                }
            }
        }
    }

    fn send(&mut self, r: Reply) {
        if let Ok(b) = r.encode() {
            self.wire.write(&b);
        }
    }

    fn err(&mut self, code: u16, message: impl Into<String>) {
        self.send(Reply::Error { code, message: message.into() });
    }

    fn hours(&self) -> f64 {
        self.hours_base + self.on_since.map_or(0.0, |t| (self.clock.now_s() - t) / 3600.0)
    }

    /// Starts or stops the hour counter from the device's on state.
    async fn track_hours(&mut self) {
        let on = match self.device.as_mut() {
            Some(d) => d.status().await.map(|s| s.on).unwrap_or(false),
            None => return,
        };
        match (on, self.on_since) {
            (true, None) => self.on_since = Some(self.clock.now_s()),
            (false, Some(_)) => {
                self.hours_base = self.hours();
                self.on_since = None;
            }
            _ => {}
        }
    }

    async fn status(&mut self) -> Result<LampStatus, DeviceError> {
        self.device.as_mut().expect("no job running").status().await
    }

    async fn handle(&mut self, req: Request) {
        if std::mem::take(&mut self.swallow) {
            return;
        }
        if req == Request::Identify {
            let f = self.cfg.identity.to_vec();
            return self.send(Reply::Identity(f));
        }
        if self.job.is_some() {
            return self.err(codes::RESTRIKE_LOCKOUT, "busy: applying the previous setting");
        }
        if let Some((code, message)) = self.latched.take() {
            return self.err(code, message);
        }
        match req {
            Request::Identify => unreachable!("answered above"),
            Request::Capabilities => {
                let c = &self.caps;
                self.send(Reply::Capabilities(LampCaps {
                    shutter: c.has_shutter,
                    dim_range: c.intensity_range,
                    warm_up_s: c.warm_up_s,
                }))
            }
            Request::QueryHours => {
                let h = self.hours();
                self.send(Reply::Hours(h))
            }
            Request::QueryOn | Request::QueryShutter | Request::QueryIntensity | Request::Status => {
                match self.status().await {
                    Ok(s) => self.send(match req {
                        Request::QueryOn => Reply::On(s.on),
                        Request::QueryShutter => Reply::ShutterOpen(s.shutter_open),
                        Request::QueryIntensity => Reply::Intensity(s.intensity),
                        _ => Reply::Status(LampState {
                            on: s.on,
                            shutter_open: s.shutter_open,
                            intensity: s.intensity,
                            warm: match s.warm_up {
                                WarmUp::Off => Warm::Off,
                                WarmUp::WarmingUp { remaining_s } => Warm::Warming(remaining_s),
                                WarmUp::Ready => Warm::Ready,
                            },
                        }),
                    }),
                    Err(e) => self.err(code_of(&e), e.message().to_string()),
                }
            }
            Request::SetOn(_) | Request::SetShutterOpen(_) | Request::SetIntensity(_) => self.setting(req),
        }
    }

    fn setting(&mut self, req: Request) {
        if let Some((code, message)) = self.refuse.take() {
            return self.err(code, message);
        }
        match req {
            Request::SetShutterOpen(_) if !self.caps.has_shutter => return self.err(codes::UNSUPPORTED, "no shutter"),
            Request::SetIntensity(_) if self.caps.intensity_range.is_none() => {
                return self.err(codes::UNSUPPORTED, "fixed output")
            }
            Request::SetIntensity(f) => {
                let (lo, hi) = self.caps.intensity_range.unwrap_or((1.0, 1.0));
                if !(lo..=hi).contains(&f) {
                    return self.err(codes::OUT_OF_RANGE, format!("intensity {f} outside [{lo}, {hi}]"));
                }
            }
            _ => {}
        }
        let Some(mut dev) = self.device.take() else { return };
        self.job = Some(tokio::spawn(async move {
            let r = match req {
                Request::SetOn(on) => dev.set_on(on).await,
                Request::SetShutterOpen(open) => dev.set_shutter_open(open).await,
                Request::SetIntensity(f) => dev.set_intensity(f).await,
                _ => Ok(()),
            };
            (dev, r)
        }));
        self.send(Reply::Ok);
        for f in std::mem::take(&mut self.armed) {
            self.inject(f);
        }
    }

    fn inject(&mut self, f: Fault) {
        match f {
            Fault::Garbage(b) => self.wire.write(&b),
            Fault::Refuse(code, text) => self.refuse = Some((code, text)),
            Fault::Swallow => self.swallow = true,
            Fault::OnNextSetting(f) => self.armed.push(*f),
            Fault::Unplug => {
                if self.wire.replug(&self.link, &self.tx, "emulated lamp controller") {
                    self.decoder = request_decoder();
                }
            }
        }
    }
}
