//! An in-process PTP responder: serves any [`Camera`] (in tests and the serial demo rig:
//! the simulator's) behind a [`ChannelTransport`], as the btfrig camera firmware would.
//!
//! Operations map onto the trait: `InitiateCapture` is answered `OK` at once, then the
//! camera is triggered and `ObjectAdded(handle)` follows on the interrupt pipe; `GetObject`
//! reads the frame out of the camera (its transfer time), encodes it as a
//! [`btfrig_protocols::ptp::raw`] object and keeps it until `DeleteObject`, so a damaged
//! download can be fetched again. Device errors become the response codes the host maps
//! back to the same kinds (`Timeout` -> TransactionCancelled, `CorruptData` ->
//! IncompleteTransfer, `OutOfRange` -> InvalidDevicePropValue, ...).

use std::collections::HashMap;

use btfrig_hw::{Camera, DeviceError, ErrorKind};
use btfrig_protocols::ptp::{
    ev, op, prop, raw, rc, Container, ContainerDecoder, ContainerKind, DeviceInfo, Event, Operation, PropValue,
    Response, FORMAT_BTFRIG_RAW,
};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use crate::transport::ChannelTransport;

/// Faults a test injects.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Fault {
    /// The next capture completes but its `ObjectAdded` event is never sent.
    DropObjectAdded,
    /// The next object download has one sample byte flipped on the way.
    CorruptObject,
}

/// Options of the responder.
#[derive(Debug, Clone)]
pub struct ResponderConfig {
    /// Manufacturer, model, version, serial for `GetDeviceInfo`.
    pub manufacturer: String,
    /// Model.
    pub model: String,
    /// Firmware version.
    pub version: String,
    /// Serial number.
    pub serial: String,
    /// Bound of the camera's own trigger beyond the exposure, rig seconds.
    pub trigger_timeout_s: f64,
    /// Bound of the camera's read-out, rig seconds (set it to the host's read timeout).
    pub read_timeout_s: f64,
}

impl Default for ResponderConfig {
    fn default() -> Self {
        ResponderConfig {
            manufacturer: "btfrig".into(),
            model: "emulated PTP camera".into(),
            version: "1.0".into(),
            serial: "EMU-C1".into(),
            trigger_timeout_s: 10.0,
            read_timeout_s: 30.0,
        }
    }
}

/// Handle on a running responder; dropping it stops it (the host sees the camera gone).
pub struct PtpResponder {
    tx: mpsc::UnboundedSender<Fault>,
    task: JoinHandle<()>,
}

impl PtpResponder {
    /// Serves `camera`; returns the handle and the host's transport (call inside a runtime).
    pub fn spawn(camera: Box<dyn Camera>, cfg: ResponderConfig) -> (PtpResponder, ChannelTransport) {
        let (fault_tx, mut fault_rx) = mpsc::unbounded_channel::<Fault>();
        let (out_tx, mut out_rx) = mpsc::unbounded_channel::<Vec<u8>>();
        let (bulk_tx, bulk_rx) = mpsc::unbounded_channel();
        let (ev_tx, ev_rx) = mpsc::unbounded_channel();
        let name = cfg.model.clone();
        let mut r = Responder {
            camera,
            cfg,
            bulk: bulk_tx,
            events: ev_tx,
            decoder: ContainerDecoder::default(),
            session: None,
            pending_set: None,
            next_handle: 1,
            pending_handle: None,
            objects: HashMap::new(),
            drop_event: false,
            corrupt_next: false,
        };
        let task = tokio::spawn(async move {
            loop {
                tokio::select! {
                    // Faults first: one injected before a request is applied before it.
                    biased;
                    Some(f) = fault_rx.recv() => r.inject(f),
                    b = out_rx.recv() => match b {
                        Some(b) => r.push(&b).await,
                        None => return,
                    },
                }
            }
        });
        let transport = ChannelTransport { out: out_tx, bulk: bulk_rx, events: ev_rx, name };
        (PtpResponder { tx: fault_tx, task }, transport)
    }

    /// Injects a fault.
    pub fn inject(&self, fault: Fault) {
        let _ = self.tx.send(fault);
    }
}

impl Drop for PtpResponder {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// The response code for a device error.
pub fn response_code(e: &DeviceError) -> u16 {
    match e.kind() {
        ErrorKind::Timeout => rc::TRANSACTION_CANCELLED,
        ErrorKind::Busy => rc::DEVICE_BUSY,
        ErrorKind::CorruptData => rc::INCOMPLETE_TRANSFER,
        ErrorKind::OutOfRange => rc::INVALID_DEVICE_PROP_VALUE,
        ErrorKind::Unsupported => rc::DEVICE_PROP_NOT_SUPPORTED,
        ErrorKind::Disconnected => rc::SESSION_NOT_OPEN,
        _ => rc::GENERAL_ERROR,
    }
}

struct Responder {
    camera: Box<dyn Camera>,
    cfg: ResponderConfig,
    bulk: mpsc::UnboundedSender<Vec<u8>>,
    events: mpsc::UnboundedSender<Vec<u8>>,
    decoder: ContainerDecoder,
    session: Option<u32>,
    /// A SetDevicePropValue waiting for its data phase: (transaction, property).
    pending_set: Option<(u32, u16)>,
    next_handle: u32,
    /// The handle of the frame triggered but not yet read out of the camera.
    pending_handle: Option<u32>,
    objects: HashMap<u32, Vec<u8>>,
    drop_event: bool,
    corrupt_next: bool,
}

impl Responder {
    fn inject(&mut self, f: Fault) {
        match f {
            Fault::DropObjectAdded => self.drop_event = true,
            Fault::CorruptObject => self.corrupt_next = true,
        }
    }

    fn send(&self, c: Container) {
        if let Ok(b) = c.encode() {
            let _ = self.bulk.send(b);
        }
    }

    fn respond(&self, tid: u32, code: u16) {
        self.send(Response { code, params: vec![] }.to_container(tid));
    }

    fn data(&self, tid: u32, code: u16, payload: Vec<u8>) {
        self.send(Container { kind: ContainerKind::Data, code, transaction_id: tid, payload });
    }

    async fn push(&mut self, bytes: &[u8]) {
        self.decoder.push(bytes);
        while let Some(c) = self.decoder.next() {
            match c {
                Ok(c) => self.container(c).await,
                Err(e) => tracing::debug!("PTP responder: skipped: {e}"),
            }
        }
    }

    async fn container(&mut self, c: Container) {
        let tid = c.transaction_id;
        if c.kind == ContainerKind::Data {
            return match self.pending_set.take() {
                Some((t, p)) if t == tid => self.set_prop(tid, p, &c.payload).await,
                _ => tracing::debug!("PTP responder: data container without a command"),
            };
        }
        let opn = match Operation::from_container(&c) {
            Ok(o) => o,
            Err(_) if c.kind == ContainerKind::Command => return self.respond(tid, rc::OPERATION_NOT_SUPPORTED),
            Err(_) => return,
        };
        match opn {
            Operation::GetDeviceInfo => return self.device_info(tid),
            Operation::OpenSession { session_id } => {
                let code = match self.session {
                    Some(_) => rc::SESSION_ALREADY_OPEN,
                    None if session_id == 0 => rc::PARAMETER_NOT_SUPPORTED,
                    None => {
                        self.session = Some(session_id);
                        rc::OK
                    }
                };
                return self.respond(tid, code);
            }
            _ if self.session.is_none() => return self.respond(tid, rc::SESSION_NOT_OPEN),
            _ => {}
        }
        match opn {
            Operation::GetDeviceInfo | Operation::OpenSession { .. } => {}
            Operation::CloseSession => {
                self.session = None;
                self.respond(tid, rc::OK);
            }
            Operation::GetDevicePropValue { prop: p } => {
                let s = self.camera.settings();
                let v = match p {
                    prop::BTFRIG_EXPOSURE_S => Some(PropValue::ExposureS(s.exposure_s)),
                    prop::BTFRIG_GAIN => Some(PropValue::Gain(s.gain)),
                    prop::EXPOSURE_TIME => {
                        Some(PropValue::ExposureTime((s.exposure_s * 1e4).round().min(f64::from(u32::MAX)) as u32))
                    }
                    prop::EXPOSURE_INDEX => {
                        Some(PropValue::ExposureIndex((s.gain * 100.0).round().min(65535.0) as u16))
                    }
                    prop::F_NUMBER => s.f_number.map(|f| PropValue::FNumber((f * 100.0).round().min(65535.0) as u16)),
                    _ => None,
                };
                match v {
                    Some(v) => {
                        self.data(tid, op::GET_DEVICE_PROP_VALUE, v.encode());
                        self.respond(tid, rc::OK);
                    }
                    None => self.respond(tid, rc::DEVICE_PROP_NOT_SUPPORTED),
                }
            }
            Operation::SetDevicePropValue { prop: p } => self.pending_set = Some((tid, p)),
            Operation::InitiateCapture { format, .. } => {
                if format != 0 && format != FORMAT_BTFRIG_RAW {
                    return self.respond(tid, rc::PARAMETER_NOT_SUPPORTED);
                }
                self.respond(tid, rc::OK);
                let timeout = self.cfg.trigger_timeout_s + self.camera.settings().exposure_s;
                // A new trigger discards a frame not yet read out (the trait's contract).
                self.pending_handle = None;
                match self.camera.trigger(timeout).await {
                    Ok(_) => {
                        let h = self.next_handle;
                        self.next_handle = self.next_handle.checked_add(1).unwrap_or(1);
                        self.pending_handle = Some(h);
                        if std::mem::take(&mut self.drop_event) {
                            tracing::warn!("PTP responder: ObjectAdded({h}) dropped (injected)");
                        } else if let Ok(b) = (Event::ObjectAdded { handle: h }).to_container(tid).encode() {
                            let _ = self.events.send(b);
                        }
                    }
                    // No event: the host's wait for ObjectAdded times out and it re-triggers.
                    Err(e) => tracing::warn!("PTP responder: trigger failed: {e}"),
                }
            }
            Operation::GetObject { handle } => {
                if !self.objects.contains_key(&handle) {
                    if self.pending_handle != Some(handle) {
                        return self.respond(tid, rc::INVALID_OBJECT_HANDLE);
                    }
                    match self.camera.read_frame(self.cfg.read_timeout_s).await {
                        Ok(frame) => match raw::encode(&frame) {
                            Ok(b) => {
                                self.pending_handle = None;
                                self.objects.insert(handle, b);
                            }
                            Err(_) => return self.respond(tid, rc::GENERAL_ERROR),
                        },
                        Err(e) => {
                            self.pending_handle = None;
                            return self.respond(tid, response_code(&e));
                        }
                    }
                }
                let mut b = self.objects.get(&handle).cloned().unwrap_or_default();
                if std::mem::take(&mut self.corrupt_next) && b.len() > raw::HEADER {
                    b[raw::HEADER] ^= 0x01;
                }
                self.data(tid, op::GET_OBJECT, b);
                self.respond(tid, rc::OK);
            }
            Operation::DeleteObject { handle } => {
                let code = if self.objects.remove(&handle).is_some() { rc::OK } else { rc::INVALID_OBJECT_HANDLE };
                self.respond(tid, code);
            }
        }
    }

    fn device_info(&self, tid: u32) {
        let info = DeviceInfo {
            standard_version: 100,
            vendor_extension_id: 0,
            vendor_extension_version: 0,
            vendor_extension_desc: String::new(),
            functional_mode: 0,
            operations: vec![
                op::GET_DEVICE_INFO,
                op::OPEN_SESSION,
                op::CLOSE_SESSION,
                op::GET_OBJECT,
                op::DELETE_OBJECT,
                op::INITIATE_CAPTURE,
                op::GET_DEVICE_PROP_VALUE,
                op::SET_DEVICE_PROP_VALUE,
            ],
            events: vec![ev::OBJECT_ADDED],
            properties: vec![
                prop::BTFRIG_EXPOSURE_S,
                prop::BTFRIG_GAIN,
                prop::F_NUMBER,
                prop::EXPOSURE_TIME,
                prop::EXPOSURE_INDEX,
            ],
            capture_formats: vec![FORMAT_BTFRIG_RAW],
            image_formats: vec![FORMAT_BTFRIG_RAW],
            manufacturer: self.cfg.manufacturer.clone(),
            model: self.cfg.model.clone(),
            device_version: self.cfg.version.clone(),
            serial_number: self.cfg.serial.clone(),
        };
        match info.encode() {
            Ok(b) => {
                self.data(tid, op::GET_DEVICE_INFO, b);
                self.respond(tid, rc::OK);
            }
            Err(_) => self.respond(tid, rc::GENERAL_ERROR),
        }
    }

    async fn set_prop(&mut self, tid: u32, p: u16, data: &[u8]) {
        let v = match PropValue::decode(p, data) {
            Ok(v) => v,
            Err(_) => return self.respond(tid, rc::DEVICE_PROP_NOT_SUPPORTED),
        };
        let r = match v {
            PropValue::ExposureS(s) => self.camera.set_exposure_s(s).await,
            PropValue::ExposureTime(t) => self.camera.set_exposure_s(f64::from(t) * 1e-4).await,
            PropValue::Gain(g) => self.camera.set_gain(g).await,
            PropValue::ExposureIndex(iso) => self.camera.set_gain(f64::from(iso) / 100.0).await,
            PropValue::FNumber(f) => self.camera.set_f_number(f64::from(f) / 100.0).await,
        };
        let code = match r {
            Ok(()) => rc::OK,
            Err(e) => response_code(&e),
        };
        self.respond(tid, code);
    }
}
