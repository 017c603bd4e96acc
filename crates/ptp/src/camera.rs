//! `PtpCamera`: the [`Camera`] trait over a [`PtpTransport`].
//!
//! `open`: GetDeviceInfo, OpenSession, and the current exposure, gain and f-number read
//! with GetDevicePropValue. Exposure and gain are set through the btfrig vendor properties
//! (an `f64`'s bits: HDR brackets are not rounded), the f-number through the standard
//! FNumber (x100, so rounded to 0.01). `trigger`: InitiateCapture, then the ObjectAdded
//! event of that transaction on the interrupt pipe, waited for on the rig clock within the
//! trigger's timeout (none: `Timeout`, retryable; the engine re-triggers, the camera
//! discards the unread frame). `read_frame`: GetObject, decoded and checked with
//! [`btfrig_protocols::ptp::raw`] (damaged: `CorruptData`), then DeleteObject. Containers of
//! other transactions (late answers to abandoned ones) are dropped. The camera's sensor
//! layout and ranges are not in the PTP subset; they come from the configuration
//! ([`PtpCameraConfig::capabilities`]).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use async_trait::async_trait;
use btfrig_core::frame::RawFrame;
use btfrig_hw::{Camera, CameraCapabilities, CaptureSettings, Device, DeviceError, DeviceInfo, ErrorKind, SharedClock};
use btfrig_protocols::ptp::{
    prop, raw, rc, response_kind, Container, ContainerDecoder, ContainerKind, DeviceInfo as PtpInfo, Event, Operation,
    PropValue, Response, FORMAT_BTFRIG_RAW,
};

use crate::transport::PtpTransport;

/// Options of the PTP camera backend.
#[derive(Debug, Clone)]
pub struct PtpCameraConfig {
    /// Device name (`camera`).
    pub name: String,
    /// Sensor layout and ranges (not part of the PTP subset).
    pub capabilities: CameraCapabilities,
    /// How long an operation without a capture or download may take, rig seconds.
    pub op_timeout_s: f64,
    /// Margin added to the caller's read-out timeout for the GetObject answer, rig seconds
    /// (the camera gives up on its own read-out first and says so).
    pub read_margin_s: f64,
}

/// What the backend moved and how long coding it took, over the camera's life (the run
/// report's `links`). Shared so it stays readable behind `dyn Camera`.
#[derive(Debug, Default)]
pub struct PtpStats {
    transactions: AtomicU64,
    bytes_out: AtomicU64,
    bytes_in: AtomicU64,
    codec_ns: AtomicU64,
}

/// A snapshot of [`PtpStats`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PtpTotals {
    /// Transactions started.
    pub transactions: u64,
    /// Bytes sent on bulk-out.
    pub bytes_out: u64,
    /// Bytes received on bulk-in and interrupt-in.
    pub bytes_in: u64,
    /// Wall seconds spent encoding commands, reassembling containers and decoding raw
    /// frames: the host-side work PTP adds over handing a frame over in memory. (Waiting for
    /// the camera is not in it; its transfer time is the rig timing model's.)
    pub codec_wall_s: f64,
}

impl PtpStats {
    /// The counters now.
    pub fn totals(&self) -> PtpTotals {
        PtpTotals {
            transactions: self.transactions.load(Ordering::Relaxed),
            bytes_out: self.bytes_out.load(Ordering::Relaxed),
            bytes_in: self.bytes_in.load(Ordering::Relaxed),
            codec_wall_s: self.codec_ns.load(Ordering::Relaxed) as f64 * 1e-9,
        }
    }

    fn codec(&self, since: Instant) {
        self.codec_ns.fetch_add(since.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }
}

/// A camera speaking the PTP subset.
pub struct PtpCamera {
    info: DeviceInfo,
    cfg: PtpCameraConfig,
    /// A mutex only to make the backend `Sync`; accessed through `&mut self`.
    transport: Mutex<Box<dyn PtpTransport>>,
    bulk: ContainerDecoder,
    events: ContainerDecoder,
    clock: SharedClock,
    tid: u32,
    settings: CaptureSettings,
    /// Handle announced by ObjectAdded and not yet downloaded.
    pending: Option<u32>,
    /// Captures whose ObjectAdded never came.
    missed_events: u64,
    stats: Arc<PtpStats>,
}

/// What a transaction returned: the data phase (if any) and the response.
struct Answer {
    data: Option<Vec<u8>>,
}

impl PtpCamera {
    /// Opens a session on `transport`.
    pub async fn open(
        cfg: PtpCameraConfig,
        transport: Box<dyn PtpTransport>,
        clock: SharedClock,
    ) -> Result<Self, DeviceError> {
        let info = DeviceInfo {
            name: cfg.name.clone(),
            backend: "ptp".into(),
            model: String::new(),
            serial: None,
            firmware: None,
        };
        let settings = CaptureSettings { exposure_s: 0.0, gain: 1.0, f_number: None };
        let mut cam = PtpCamera {
            info,
            cfg,
            transport: Mutex::new(transport),
            bulk: ContainerDecoder::default(),
            events: ContainerDecoder::default(),
            clock,
            tid: 0,
            settings,
            pending: None,
            missed_events: 0,
            stats: Arc::default(),
        };
        let a = cam.transact(Operation::GetDeviceInfo, None, cam.cfg.op_timeout_s, "device info").await?;
        let d = PtpInfo::decode(&a.data.unwrap_or_default())
            .map_err(|e| cam.err(ErrorKind::CorruptData, format!("device info: {e}")))?;
        cam.info.model = format!("{} {}", d.manufacturer, d.model);
        cam.info.serial = Some(d.serial_number);
        cam.info.firmware = Some(d.device_version);
        cam.open_session().await?;
        cam.settings.exposure_s = match cam.get_prop(prop::BTFRIG_EXPOSURE_S).await? {
            PropValue::ExposureS(v) => v,
            _ => cam.settings.exposure_s,
        };
        cam.settings.gain = match cam.get_prop(prop::BTFRIG_GAIN).await? {
            PropValue::Gain(v) => v,
            _ => cam.settings.gain,
        };
        cam.settings.f_number = match cam.get_prop(prop::F_NUMBER).await {
            Ok(PropValue::FNumber(f)) => Some(f64::from(f) / 100.0),
            Ok(_) => None,
            Err(e) if e.kind() == ErrorKind::Unsupported => None,
            Err(e) => return Err(e),
        };
        Ok(cam)
    }

    /// The backend's counters (bytes, transactions, coding time).
    pub fn stats(&self) -> Arc<PtpStats> {
        self.stats.clone()
    }

    /// Captures whose ObjectAdded event never arrived (each a `Timeout` of `trigger`).
    pub fn missed_events(&self) -> u64 {
        self.missed_events
    }

    fn err(&self, kind: ErrorKind, msg: impl Into<String>) -> DeviceError {
        DeviceError::new(&self.cfg.name, kind, msg)
    }

    fn lost(&self, what: &str, e: std::io::Error) -> DeviceError {
        self.err(ErrorKind::Disconnected, format!("{what}: link to the camera lost: {e}"))
    }

    async fn open_session(&mut self) -> Result<(), DeviceError> {
        match self.transact(Operation::OpenSession { session_id: 1 }, None, self.cfg.op_timeout_s, "open session").await
        {
            Ok(_) => Ok(()),
            Err(e) if e.message().contains(rc_text(rc::SESSION_ALREADY_OPEN)) => Ok(()),
            Err(e) => Err(e),
        }
    }

    async fn get_prop(&mut self, p: u16) -> Result<PropValue, DeviceError> {
        let a = self
            .transact(Operation::GetDevicePropValue { prop: p }, None, self.cfg.op_timeout_s, "get property")
            .await?;
        PropValue::decode(p, &a.data.unwrap_or_default())
            .map_err(|e| self.err(ErrorKind::CorruptData, format!("property {p:#06x}: {e}")))
    }

    async fn set_prop(&mut self, v: PropValue, what: &str) -> Result<(), DeviceError> {
        self.transact(Operation::SetDevicePropValue { prop: v.prop() }, Some(v.encode()), self.cfg.op_timeout_s, what)
            .await
            .map(|_| ())
    }

    /// One transaction: command (and data out), then data in and the response of this
    /// transaction within `timeout_s` on the rig clock. A non-OK response is the mapped error.
    async fn transact(
        &mut self,
        opn: Operation,
        data_out: Option<Vec<u8>>,
        timeout_s: f64,
        what: &str,
    ) -> Result<Answer, DeviceError> {
        self.tid = self.tid.checked_add(1).unwrap_or(1);
        let tid = self.tid;
        let stats = self.stats.clone();
        stats.transactions.fetch_add(1, Ordering::Relaxed);
        let coding = Instant::now();
        let send = |c: Container| {
            c.encode().map_err(|e| DeviceError::new(&self.cfg.name, ErrorKind::OutOfRange, format!("{what}: {e}")))
        };
        let mut bytes = send(opn.to_container(tid))?;
        if let Some(d) = data_out {
            bytes.extend(send(Container {
                kind: ContainerKind::Data,
                code: opn.code(),
                transaction_id: tid,
                payload: d,
            })?);
        }
        stats.codec(coding);
        stats.bytes_out.fetch_add(bytes.len() as u64, Ordering::Relaxed);
        let t = self.transport.get_mut().unwrap_or_else(|p| p.into_inner());
        if let Err(e) = t.bulk_out(bytes).await {
            return Err(self.lost(what, e));
        }
        let deadline = self.clock.now_s() + timeout_s;
        let mut data = None;
        loop {
            let coding = Instant::now();
            let next = self.bulk.next();
            stats.codec(coding);
            let mut next = next;
            while let Some(c) = next.take() {
                match c {
                    Ok(c) if c.transaction_id != tid => {
                        tracing::debug!("ptp: dropped a container of transaction {}", c.transaction_id)
                    }
                    Ok(c) if c.kind == ContainerKind::Data => data = Some(c.payload),
                    Ok(c) if c.kind == ContainerKind::Response => {
                        let response = Response::from_container(&c)
                            .map_err(|e| self.err(ErrorKind::CorruptData, format!("{what}: {e}")))?;
                        if response.code != rc::OK {
                            return Err(self.err(
                                response_kind(response.code),
                                format!("{what}: camera answered {:#06x} ({})", response.code, rc_text(response.code)),
                            ));
                        }
                        return Ok(Answer { data });
                    }
                    Ok(_) => {}
                    Err(e) => tracing::debug!("ptp: skipped: {e}"),
                }
                let coding = Instant::now();
                next = self.bulk.next();
                stats.codec(coding);
            }
            let left = deadline - self.clock.now_s();
            if left <= 0.0 {
                return Err(self.err(ErrorKind::Timeout, format!("{what}: no answer within {timeout_s} s")));
            }
            let t = self.transport.get_mut().unwrap_or_else(|p| p.into_inner());
            let clock = self.clock.clone();
            tokio::select! {
                r = t.bulk_in() => match r {
                    Ok(b) => {
                        stats.bytes_in.fetch_add(b.len() as u64, Ordering::Relaxed);
                        let coding = Instant::now();
                        self.bulk.push(&b);
                        stats.codec(coding);
                    }
                    Err(e) => return Err(self.lost(what, e)),
                },
                () = clock.sleep_s(left) => {}
            }
        }
    }

    /// Waits for ObjectAdded of transaction `tid` until `deadline` (rig clock).
    async fn object_added(&mut self, tid: u32, deadline: f64, timeout_s: f64) -> Result<u32, DeviceError> {
        loop {
            while let Some(c) = self.events.next() {
                match c.and_then(|c| Event::from_container(&c).map(|e| (c.transaction_id, e))) {
                    Ok((t, Event::ObjectAdded { handle })) if t == tid => return Ok(handle),
                    Ok((t, e)) => tracing::debug!("ptp: ignored event {e:?} of transaction {t}"),
                    Err(e) => tracing::debug!("ptp: skipped event: {e}"),
                }
            }
            let left = deadline - self.clock.now_s();
            if left <= 0.0 {
                self.missed_events += 1;
                return Err(self.err(ErrorKind::Timeout, format!("trigger: no ObjectAdded event within {timeout_s} s")));
            }
            let t = self.transport.get_mut().unwrap_or_else(|p| p.into_inner());
            let clock = self.clock.clone();
            tokio::select! {
                r = t.interrupt_in() => match r {
                    Ok(b) => {
                        self.stats.bytes_in.fetch_add(b.len() as u64, Ordering::Relaxed);
                        self.events.push(&b);
                    }
                    Err(e) => return Err(self.lost("trigger", e)),
                },
                () = clock.sleep_s(left) => {}
            }
        }
    }

    fn check(&self, what: &str, v: f64, (lo, hi): (f64, f64)) -> Result<(), DeviceError> {
        if v >= lo && v <= hi {
            Ok(())
        } else {
            Err(DeviceError::out_of_range(&self.cfg.name, what, v, format!("[{lo}, {hi}]")))
        }
    }
}

fn rc_text(code: u16) -> &'static str {
    match code {
        rc::GENERAL_ERROR => "GeneralError",
        rc::SESSION_NOT_OPEN => "SessionNotOpen",
        rc::OPERATION_NOT_SUPPORTED => "OperationNotSupported",
        rc::PARAMETER_NOT_SUPPORTED => "ParameterNotSupported",
        rc::INCOMPLETE_TRANSFER => "IncompleteTransfer",
        rc::INVALID_OBJECT_HANDLE => "InvalidObjectHandle",
        rc::DEVICE_PROP_NOT_SUPPORTED => "DevicePropNotSupported",
        rc::STORE_FULL => "StoreFull",
        rc::DEVICE_BUSY => "DeviceBusy",
        rc::INVALID_DEVICE_PROP_VALUE => "InvalidDevicePropValue",
        rc::SESSION_ALREADY_OPEN => "SessionAlreadyOpen",
        rc::TRANSACTION_CANCELLED => "TransactionCancelled",
        _ => "other",
    }
}

#[async_trait]
impl Device for PtpCamera {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        let t = self.transport.get_mut().unwrap_or_else(|p| p.into_inner());
        if let Err(e) = t.reset().await {
            return Err(self.lost("reconnect", e));
        }
        self.bulk.clear();
        self.events.clear();
        self.pending = None;
        self.open_session().await
    }
}

#[async_trait]
impl Camera for PtpCamera {
    fn capabilities(&self) -> CameraCapabilities {
        self.cfg.capabilities.clone()
    }

    fn settings(&self) -> CaptureSettings {
        self.settings
    }

    async fn set_exposure_s(&mut self, exposure_s: f64) -> Result<(), DeviceError> {
        self.check("exposure (s)", exposure_s, self.cfg.capabilities.exposure_range_s)?;
        self.set_prop(PropValue::ExposureS(exposure_s), "set_exposure_s").await?;
        self.settings.exposure_s = exposure_s;
        Ok(())
    }

    async fn set_gain(&mut self, gain: f64) -> Result<(), DeviceError> {
        self.check("gain", gain, self.cfg.capabilities.gain_range)?;
        self.set_prop(PropValue::Gain(gain), "set_gain").await?;
        self.settings.gain = gain;
        Ok(())
    }

    async fn set_f_number(&mut self, f_number: f64) -> Result<(), DeviceError> {
        let Some(range) = self.cfg.capabilities.f_number_range else {
            return Err(DeviceError::unsupported(&self.cfg.name, "aperture control"));
        };
        self.check("f-number", f_number, range)?;
        let wire = (f_number * 100.0).round() as u16;
        self.set_prop(PropValue::FNumber(wire), "set_f_number").await?;
        self.settings.f_number = Some(f64::from(wire) / 100.0);
        Ok(())
    }

    async fn trigger(&mut self, timeout_s: f64) -> Result<u64, DeviceError> {
        let deadline = self.clock.now_s() + timeout_s;
        self.pending = None;
        let opn = Operation::InitiateCapture { storage_id: 0, format: FORMAT_BTFRIG_RAW };
        self.transact(opn, None, timeout_s, "trigger").await?;
        let tid = self.tid;
        let handle = self.object_added(tid, deadline, timeout_s).await?;
        self.pending = Some(handle);
        Ok(u64::from(handle))
    }

    async fn read_frame(&mut self, timeout_s: f64) -> Result<RawFrame, DeviceError> {
        let Some(handle) = self.pending.take() else {
            return Err(self.err(ErrorKind::Other, "read_frame: no frame was triggered"));
        };
        let a = self
            .transact(Operation::GetObject { handle }, None, timeout_s + self.cfg.read_margin_s, "read_frame")
            .await?;
        let coding = Instant::now();
        let decoded = raw::decode(&a.data.unwrap_or_default());
        self.stats.codec(coding);
        let frame = decoded.map_err(|e| self.err(ErrorKind::CorruptData, format!("read_frame: object {handle}: {e}")));
        // The object is on the camera's card either way; free it (a failure here loses nothing).
        if let Err(e) =
            self.transact(Operation::DeleteObject { handle }, None, self.cfg.op_timeout_s, "delete object").await
        {
            tracing::warn!("{e}");
        }
        frame
    }
}
