//! The LED dome controller ([`btfrig_protocols::led`]) emulated over a pseudo-terminal,
//! driving a `LedArray` device (in tests: the simulator's).
//!
//! `SetPattern` stages integer intensities `0..steps`; `Trigger` is answered `Ack` at once
//! and then lights the staged pattern on the device (its switch time on the rig clock),
//! `staged` staying set in `Status` until it is lit; other requests meanwhile are
//! `Nack 8` (busy). The device is commanded `n / (steps - 1)`, which it quantises back to
//! exactly `n`, so the serial path lights the same pattern as the direct one.

use std::path::{Path, PathBuf};

use btfrig_hw::{DeviceError, LedArray, LedPattern};
use btfrig_protocols::led::{codes, request_decoder, Decoder, LedStatus, Reply, Request};
use btfrig_protocols::DecodeError;
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
    /// Driver board over temperature: LEDs forced off, patterns refused (`Nack 6`) until
    /// [`Fault::Cooled`].
    OverTemperature,
    /// The board has cooled down.
    Cooled,
    /// A driver channel fault: `Status` reports it (no request is refused).
    DriverFault,
    /// Apply the fault right after the next `Trigger` is acknowledged.
    OnNextTrigger(Box<Fault>),
}

type Event = super::Event<Fault>;

/// Handle on a running LED controller emulator; dropping it stops it.
pub struct LedFirmware {
    handle: Handle<Fault>,
}

impl LedFirmware {
    /// Serves `device` on a new pseudo-terminal behind `link` (call inside a tokio runtime).
    pub fn spawn(device: Box<dyn LedArray>, link: &Path) -> std::io::Result<LedFirmware> {
        let (tx, rx) = mpsc::unbounded_channel();
        let caps = device.capabilities();
        let count = caps.count.min(btfrig_protocols::led::MAX_LEDS);
        let emu = Emulator {
            device: Some(device),
            count,
            steps: caps.intensity_steps,
            staged: None,
            lit: vec![0; count],
            job: None,
            latched: None,
            over_temperature: false,
            driver_fault: false,
            wire: Wire::open(link, 0, forwarder(&tx))?,
            decoder: request_decoder(),
            armed: Vec::new(),
            tx: tx.clone(),
            link: link.to_path_buf(),
        };
        Ok(LedFirmware { handle: Handle::new(tx, tokio::spawn(emu.run(rx))) })
    }

    /// Injects a fault.
    pub fn inject(&self, fault: Fault) {
        self.handle.inject(fault);
    }
}

type Job = JoinHandle<(Box<dyn LedArray>, Vec<u16>, Result<(), DeviceError>)>;

struct Emulator {
    device: Option<Box<dyn LedArray>>,
    count: usize,
    steps: u32,
    staged: Option<Vec<u16>>,
    lit: Vec<u16>,
    job: Option<Job>,
    latched: Option<u8>,
    over_temperature: bool,
    driver_fault: bool,
    wire: Wire,
    decoder: Decoder<Request>,
    armed: Vec<Fault>,
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
                            self.handle(r).await;
                        }
                    }
                    Some(Event::Bytes(..)) => {}
                    Some(Event::Fault(f)) => self.inject(f).await,
                },
                done = async { self.job.as_mut().expect("guarded by is_some").await }, if self.job.is_some() => {
                    self.job = None;
                    let Ok((dev, values, r)) = done else { return };
                    self.device = Some(dev);
                    match r {
                        Ok(()) => self.lit = values,
                        Err(e) => {
                            tracing::warn!("emulated LED controller: device failed: {e}");
                            self.driver_fault = true;
                            self.latched = Some(codes::DRIVER_FAULT);
                        }
                    }
                }
            }
        }
    }

    fn send(&mut self, seq: u8, r: Reply) {
        if let Ok(b) = r.encode(seq) {
            self.wire.write(&b);
        }
    }

    async fn handle(&mut self, r: Result<(u8, Request), DecodeError>) {
        let (seq, req) = match r {
            Ok(x) => x,
            Err(DecodeError::Checksum { .. }) => return self.send(0, Reply::Nack(codes::BAD_CRC)),
            Err(DecodeError::Malformed { .. }) => return self.send(0, Reply::Nack(codes::BAD_LENGTH)),
            Err(_) => return, // garbage before a sync, or an oversized length: nothing to answer
        };
        let busy = self.job.is_some();
        match req {
            Request::GetInfo => {
                self.send(seq, Reply::Info { count: self.count as u16, steps: self.steps, firmware: (1, 0) })
            }
            Request::GetStatus => {
                let lit = self.lit.iter().filter(|&&v| v > 0).count() as u16;
                let s = LedStatus {
                    staged: self.staged.is_some() || busy,
                    over_temperature: self.over_temperature,
                    driver_fault: self.driver_fault,
                    lit,
                };
                self.send(seq, Reply::Status(s))
            }
            Request::GetTemperature => {
                let t = match self.device.as_mut() {
                    Some(d) => d.temperature_c().await.ok().flatten().unwrap_or(25.0),
                    None => 25.0,
                };
                let t = if self.over_temperature { 85.0 } else { t };
                self.send(seq, Reply::Temperature((t * 100.0).round().clamp(-32768.0, 32767.0) as i16))
            }
            Request::SetPattern(_) | Request::Trigger if self.over_temperature => {
                self.send(seq, Reply::Nack(codes::OVER_TEMPERATURE))
            }
            _ if busy => self.send(seq, Reply::Nack(codes::BUSY)),
            _ if self.latched.is_some() => {
                let code = self.latched.take().unwrap_or(codes::UNKNOWN_KIND);
                self.send(seq, Reply::Nack(code))
            }
            Request::GetPattern => self.send(seq, Reply::Pattern(self.lit.clone())),
            Request::SetPattern(v) => {
                if v.len() != self.count {
                    self.send(seq, Reply::Nack(codes::WRONG_COUNT))
                } else if v.iter().any(|&x| u32::from(x) >= self.steps) {
                    self.send(seq, Reply::Nack(codes::VALUE_TOO_HIGH))
                } else {
                    self.staged = Some(v);
                    self.send(seq, Reply::Ack)
                }
            }
            Request::Trigger => {
                let Some(values) = self.staged.take() else {
                    return self.send(seq, Reply::Nack(codes::NOTHING_STAGED));
                };
                self.light(values);
                self.send(seq, Reply::Ack);
                for f in std::mem::take(&mut self.armed) {
                    self.inject(f).await;
                }
            }
        }
    }

    fn light(&mut self, values: Vec<u16>) {
        let Some(mut dev) = self.device.take() else { return };
        let top = f64::from(self.steps.max(2) - 1);
        self.job = Some(tokio::spawn(async move {
            let p = LedPattern { intensities: values.iter().map(|&v| f64::from(v) / top).collect() };
            let r = dev.set_pattern(&p).await;
            (dev, values, r)
        }));
    }

    async fn inject(&mut self, f: Fault) {
        match f {
            Fault::Garbage(b) => self.wire.write(&b),
            Fault::OverTemperature => {
                self.over_temperature = true;
                self.staged = None;
                if self.job.is_none() {
                    self.light(vec![0; self.count]);
                }
            }
            Fault::Cooled => self.over_temperature = false,
            Fault::DriverFault => self.driver_fault = true,
            Fault::OnNextTrigger(f) => self.armed.push(*f),
            Fault::Unplug => {
                if self.wire.replug(&self.link, &self.tx, "emulated LED controller") {
                    self.decoder = request_decoder();
                }
            }
        }
    }
}
