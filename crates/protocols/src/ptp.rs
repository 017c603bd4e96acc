//! The Picture Transfer Protocol (PTP, ISO 15740, as used by USB still image class
//! cameras) subset for tethered capture, and the raw-frame format the btfrig camera
//! firmware stores its objects in. See `docs/protocols/ptp.md`.
//!
//! Every PTP message is a container: `length u32 | type u16 | code u16 | transaction u32 |
//! payload`, little-endian, `length` counting the 12-byte header. A transaction is a
//! command container (operation code, up to 5 u32 parameters), an optional data container
//! (either direction), and a response container (response code, parameters); events
//! (`ObjectAdded` with the new object's handle) come on the interrupt pipe. Capture:
//! `OpenSession`, `SetDevicePropValue` (exposure), `InitiateCapture`, wait for
//! `ObjectAdded`, `GetObject` (the data is a [`raw`] frame), `DeleteObject`.

use btfrig_hw::ErrorKind;

use crate::{DecodeError, EncodeError};

/// Container header bytes.
pub const HEADER: usize = 12;
/// Default largest container the decoder accepts: 256 MiB (a 60 MP 16-bit raw frame is 120 MB).
pub const DEFAULT_MAX_CONTAINER: usize = 256 << 20;
/// Most parameters a command, response or event carries.
pub const MAX_PARAMS: usize = 5;

/// Operation codes.
pub mod op {
    /// GetDeviceInfo (no session needed).
    pub const GET_DEVICE_INFO: u16 = 0x1001;
    /// OpenSession(session id).
    pub const OPEN_SESSION: u16 = 0x1002;
    /// CloseSession.
    pub const CLOSE_SESSION: u16 = 0x1003;
    /// GetObject(handle): data phase camera -> host.
    pub const GET_OBJECT: u16 = 0x1009;
    /// DeleteObject(handle, format).
    pub const DELETE_OBJECT: u16 = 0x100B;
    /// InitiateCapture(storage id, format).
    pub const INITIATE_CAPTURE: u16 = 0x100E;
    /// GetDevicePropValue(property): data phase camera -> host.
    pub const GET_DEVICE_PROP_VALUE: u16 = 0x1015;
    /// SetDevicePropValue(property): data phase host -> camera.
    pub const SET_DEVICE_PROP_VALUE: u16 = 0x1016;
}

/// Response codes.
pub mod rc {
    /// OK.
    pub const OK: u16 = 0x2001;
    /// General error.
    pub const GENERAL_ERROR: u16 = 0x2002;
    /// Session not open.
    pub const SESSION_NOT_OPEN: u16 = 0x2003;
    /// Invalid transaction id.
    pub const INVALID_TRANSACTION_ID: u16 = 0x2004;
    /// Operation not supported.
    pub const OPERATION_NOT_SUPPORTED: u16 = 0x2005;
    /// Parameter not supported.
    pub const PARAMETER_NOT_SUPPORTED: u16 = 0x2006;
    /// Incomplete transfer.
    pub const INCOMPLETE_TRANSFER: u16 = 0x2007;
    /// Invalid object handle.
    pub const INVALID_OBJECT_HANDLE: u16 = 0x2009;
    /// Device property not supported.
    pub const DEVICE_PROP_NOT_SUPPORTED: u16 = 0x200A;
    /// Store full.
    pub const STORE_FULL: u16 = 0x200C;
    /// Device busy.
    pub const DEVICE_BUSY: u16 = 0x2019;
    /// Invalid device property value.
    pub const INVALID_DEVICE_PROP_VALUE: u16 = 0x201C;
    /// Session already open.
    pub const SESSION_ALREADY_OPEN: u16 = 0x201E;
    /// Transaction cancelled.
    pub const TRANSACTION_CANCELLED: u16 = 0x201F;
}

/// Event codes.
pub mod ev {
    /// ObjectAdded(handle): a captured image is in the camera's store.
    pub const OBJECT_ADDED: u16 = 0x4002;
    /// DevicePropChanged(property).
    pub const DEVICE_PROP_CHANGED: u16 = 0x4006;
    /// CaptureComplete(transaction id of the InitiateCapture).
    pub const CAPTURE_COMPLETE: u16 = 0x400D;
}

/// Device property codes.
pub mod prop {
    /// FNumber, UINT16, f-number x 100.
    pub const F_NUMBER: u16 = 0x5007;
    /// ExposureTime, UINT32, units of 0.1 ms.
    pub const EXPOSURE_TIME: u16 = 0x500D;
    /// ExposureIndex (ISO), UINT16; btfrig maps gain 1 to ISO 100.
    pub const EXPOSURE_INDEX: u16 = 0x500F;
    /// btfrig vendor extension: exposure time, seconds, as the bits of an IEEE f64 in a
    /// UINT64, so HDR brackets are not rounded to 0.1 ms.
    pub const BTFRIG_EXPOSURE_S: u16 = 0xD101;
    /// btfrig vendor extension: analogue gain as f64 bits in a UINT64.
    pub const BTFRIG_GAIN: u16 = 0xD102;
}

/// Object format of btfrig raw frames (vendor range 0xB000..).
pub const FORMAT_BTFRIG_RAW: u16 = 0xB10F;

/// How the host should treat a response code other than OK.
pub fn response_kind(code: u16) -> ErrorKind {
    match code {
        rc::DEVICE_BUSY => ErrorKind::Busy,
        rc::INCOMPLETE_TRANSFER => ErrorKind::CorruptData,
        rc::SESSION_NOT_OPEN => ErrorKind::Disconnected,
        rc::TRANSACTION_CANCELLED => ErrorKind::Timeout,
        rc::INVALID_DEVICE_PROP_VALUE => ErrorKind::OutOfRange,
        rc::OPERATION_NOT_SUPPORTED | rc::PARAMETER_NOT_SUPPORTED | rc::DEVICE_PROP_NOT_SUPPORTED => {
            ErrorKind::Unsupported
        }
        _ => ErrorKind::Other,
    }
}

/// Container type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ContainerKind {
    /// Command block (host -> camera).
    Command = 1,
    /// Data block (either way).
    Data = 2,
    /// Response block (camera -> host).
    Response = 3,
    /// Event block (camera -> host, interrupt pipe).
    Event = 4,
}

impl ContainerKind {
    fn from_u16(v: u16) -> Option<Self> {
        match v {
            1 => Some(ContainerKind::Command),
            2 => Some(ContainerKind::Data),
            3 => Some(ContainerKind::Response),
            4 => Some(ContainerKind::Event),
            _ => None,
        }
    }
}

/// One PTP container.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Container {
    /// Type.
    pub kind: ContainerKind,
    /// Operation, response or event code (for data: the operation's code).
    pub code: u16,
    /// Transaction id.
    pub transaction_id: u32,
    /// Parameters (u32 each) or data bytes.
    pub payload: Vec<u8>,
}

impl Container {
    /// A command, response or event container with parameters.
    pub fn with_params(kind: ContainerKind, code: u16, transaction_id: u32, params: &[u32]) -> Self {
        Container { kind, code, transaction_id, payload: params.iter().flat_map(|p| p.to_le_bytes()).collect() }
    }

    /// The payload read as u32 parameters (commands, responses, events).
    pub fn params(&self) -> Result<Vec<u32>, DecodeError> {
        if self.payload.len() % 4 != 0 || self.payload.len() > 4 * MAX_PARAMS {
            return Err(DecodeError::malformed(
                "ptp parameters",
                format!("{} bytes is not 0..=5 u32 parameters", self.payload.len()),
                &[],
            ));
        }
        Ok(self.payload.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
    }

    /// The bytes on the wire.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let len = HEADER + self.payload.len();
        let len32 = u32::try_from(len).map_err(|_| EncodeError::TooLong {
            what: "ptp container",
            len,
            limit: u32::MAX as usize,
        })?;
        let mut out = Vec::with_capacity(len);
        out.extend_from_slice(&len32.to_le_bytes());
        out.extend_from_slice(&(self.kind as u16).to_le_bytes());
        out.extend_from_slice(&self.code.to_le_bytes());
        out.extend_from_slice(&self.transaction_id.to_le_bytes());
        out.extend_from_slice(&self.payload);
        Ok(out)
    }
}

/// Incremental container decoder. An impossible header (length under 12 or over the
/// limit, unknown type) is reported and one byte dropped, so the decoder scans on.
#[derive(Debug, Clone)]
pub struct ContainerDecoder {
    buf: Vec<u8>,
    max_len: usize,
}

impl Default for ContainerDecoder {
    fn default() -> Self {
        Self::new(DEFAULT_MAX_CONTAINER)
    }
}

impl ContainerDecoder {
    /// A decoder accepting containers of at most `max_len` bytes.
    pub fn new(max_len: usize) -> Self {
        ContainerDecoder { buf: Vec::new(), max_len }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Drops everything buffered (after a pipe reset).
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// Bytes buffered.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// The next container, a decode error, or `None` when more bytes are needed.
    #[allow(clippy::should_implement_trait)] // `None` means "need more bytes"
    pub fn next(&mut self) -> Option<Result<Container, DecodeError>> {
        if self.buf.len() < HEADER {
            return None;
        }
        let b = &self.buf;
        let len = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
        let kind = u16::from_le_bytes([b[4], b[5]]);
        if len > self.max_len {
            self.buf.drain(..1);
            return Some(Err(DecodeError::Oversized { what: "ptp container", limit: self.max_len }));
        }
        let Some(kind) = ContainerKind::from_u16(kind).filter(|_| len >= HEADER) else {
            let head = self.buf[..HEADER].to_vec();
            self.buf.drain(..1);
            return Some(Err(DecodeError::malformed(
                "ptp container",
                format!("impossible header: length {len}, type {kind}"),
                &head,
            )));
        };
        if self.buf.len() < len {
            return None;
        }
        let c = Container {
            kind,
            code: u16::from_le_bytes([b[6], b[7]]),
            transaction_id: u32::from_le_bytes([b[8], b[9], b[10], b[11]]),
            payload: b[HEADER..len].to_vec(),
        };
        self.buf.drain(..len);
        Some(Ok(c))
    }
}

/// The operations of the subset, with their parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Operation {
    /// GetDeviceInfo; data phase: a [`DeviceInfo`].
    GetDeviceInfo,
    /// OpenSession(session id, not 0).
    OpenSession {
        /// Session id chosen by the host.
        session_id: u32,
    },
    /// CloseSession.
    CloseSession,
    /// GetDevicePropValue(property); data phase: the value.
    GetDevicePropValue {
        /// Property code ([`prop`]).
        prop: u16,
    },
    /// SetDevicePropValue(property); data phase host -> camera: the value.
    SetDevicePropValue {
        /// Property code ([`prop`]).
        prop: u16,
    },
    /// InitiateCapture(storage, format); completion is the `ObjectAdded` event.
    InitiateCapture {
        /// Storage id (0: camera's choice).
        storage_id: u32,
        /// Object format (0: camera's choice).
        format: u16,
    },
    /// GetObject(handle); data phase: the object.
    GetObject {
        /// Object handle from `ObjectAdded`.
        handle: u32,
    },
    /// DeleteObject(handle).
    DeleteObject {
        /// Object handle.
        handle: u32,
    },
}

impl Operation {
    /// The operation code.
    pub fn code(&self) -> u16 {
        match self {
            Operation::GetDeviceInfo => op::GET_DEVICE_INFO,
            Operation::OpenSession { .. } => op::OPEN_SESSION,
            Operation::CloseSession => op::CLOSE_SESSION,
            Operation::GetDevicePropValue { .. } => op::GET_DEVICE_PROP_VALUE,
            Operation::SetDevicePropValue { .. } => op::SET_DEVICE_PROP_VALUE,
            Operation::InitiateCapture { .. } => op::INITIATE_CAPTURE,
            Operation::GetObject { .. } => op::GET_OBJECT,
            Operation::DeleteObject { .. } => op::DELETE_OBJECT,
        }
    }

    /// The command container of transaction `transaction_id`.
    pub fn to_container(&self, transaction_id: u32) -> Container {
        let params: Vec<u32> = match *self {
            Operation::GetDeviceInfo | Operation::CloseSession => vec![],
            Operation::OpenSession { session_id } => vec![session_id],
            Operation::GetDevicePropValue { prop } | Operation::SetDevicePropValue { prop } => vec![prop.into()],
            Operation::InitiateCapture { storage_id, format } => vec![storage_id, format.into()],
            Operation::GetObject { handle } => vec![handle],
            Operation::DeleteObject { handle } => vec![handle, 0],
        };
        Container::with_params(ContainerKind::Command, self.code(), transaction_id, &params)
    }

    /// The operation a command container carries.
    pub fn from_container(c: &Container) -> Result<Operation, DecodeError> {
        if c.kind != ContainerKind::Command {
            return Err(DecodeError::malformed("ptp command", format!("{:?} container", c.kind), &[]));
        }
        let p = c.params()?;
        let arg = |i: usize| p.get(i).copied().unwrap_or(0);
        let prop16 = |v: u32| {
            u16::try_from(v)
                .map_err(|_| DecodeError::malformed("ptp command", format!("property {v:#x} wider than 16 bits"), &[]))
        };
        Ok(match c.code {
            op::GET_DEVICE_INFO => Operation::GetDeviceInfo,
            op::OPEN_SESSION => Operation::OpenSession { session_id: arg(0) },
            op::CLOSE_SESSION => Operation::CloseSession,
            op::GET_DEVICE_PROP_VALUE => Operation::GetDevicePropValue { prop: prop16(arg(0))? },
            op::SET_DEVICE_PROP_VALUE => Operation::SetDevicePropValue { prop: prop16(arg(0))? },
            op::INITIATE_CAPTURE => Operation::InitiateCapture { storage_id: arg(0), format: prop16(arg(1))? },
            op::GET_OBJECT => Operation::GetObject { handle: arg(0) },
            op::DELETE_OBJECT => Operation::DeleteObject { handle: arg(0) },
            code => {
                return Err(DecodeError::malformed(
                    "ptp command",
                    format!("operation {code:#06x} not in the subset"),
                    &[],
                ))
            }
        })
    }
}

/// Events of the subset.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// A new object (the captured frame).
    ObjectAdded {
        /// Its handle.
        handle: u32,
    },
    /// A property changed on the camera.
    DevicePropChanged {
        /// Property code.
        prop: u16,
    },
    /// The capture of transaction `transaction_id` completed.
    CaptureComplete,
    /// Another event (ignored by the host).
    Other {
        /// Event code.
        code: u16,
        /// Parameters.
        params: Vec<u32>,
    },
}

impl Event {
    /// The event container (`transaction_id`: the InitiateCapture's).
    pub fn to_container(&self, transaction_id: u32) -> Container {
        let (code, params) = match self {
            Event::ObjectAdded { handle } => (ev::OBJECT_ADDED, vec![*handle]),
            Event::DevicePropChanged { prop } => (ev::DEVICE_PROP_CHANGED, vec![u32::from(*prop)]),
            Event::CaptureComplete => (ev::CAPTURE_COMPLETE, vec![]),
            Event::Other { code, params } => (*code, params.clone()),
        };
        Container::with_params(ContainerKind::Event, code, transaction_id, &params)
    }

    /// The event an event container carries.
    pub fn from_container(c: &Container) -> Result<Event, DecodeError> {
        if c.kind != ContainerKind::Event {
            return Err(DecodeError::malformed("ptp event", format!("{:?} container", c.kind), &[]));
        }
        let p = c.params()?;
        let first = || p.first().copied().ok_or_else(|| DecodeError::malformed("ptp event", "missing parameter", &[]));
        Ok(match c.code {
            ev::OBJECT_ADDED => Event::ObjectAdded { handle: first()? },
            ev::DEVICE_PROP_CHANGED => Event::DevicePropChanged {
                prop: u16::try_from(first()?)
                    .map_err(|_| DecodeError::malformed("ptp event", "property wider than 16 bits", &[]))?,
            },
            ev::CAPTURE_COMPLETE => Event::CaptureComplete,
            code => Event::Other { code, params: p },
        })
    }
}

/// A response: code and parameters.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Response {
    /// Response code ([`rc`]).
    pub code: u16,
    /// Parameters.
    pub params: Vec<u32>,
}

impl Response {
    /// OK without parameters.
    pub fn ok() -> Self {
        Response { code: rc::OK, params: vec![] }
    }

    /// The response container.
    pub fn to_container(&self, transaction_id: u32) -> Container {
        Container::with_params(ContainerKind::Response, self.code, transaction_id, &self.params)
    }

    /// The response a response container carries.
    pub fn from_container(c: &Container) -> Result<Response, DecodeError> {
        if c.kind != ContainerKind::Response {
            return Err(DecodeError::malformed("ptp response", format!("{:?} container", c.kind), &[]));
        }
        Ok(Response { code: c.code, params: c.params()? })
    }
}

/// Reads PTP datasets: little-endian integers, arrays (u32 count), strings (u8 count of
/// UTF-16 units including the terminating NUL; 0 = empty string).
struct Reader<'a> {
    data: &'a [u8],
    at: usize,
    what: &'static str,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        if self.data.len() - self.at < n {
            return Err(DecodeError::malformed(self.what, format!("truncated at byte {}", self.at), &[]));
        }
        let s = &self.data[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn u16(&mut self) -> Result<u16, DecodeError> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32, DecodeError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u16_array(&mut self) -> Result<Vec<u16>, DecodeError> {
        let n = self.u32()? as usize;
        if n > (self.data.len() - self.at) / 2 {
            return Err(DecodeError::malformed(self.what, format!("array of {n} elements exceeds the data"), &[]));
        }
        (0..n).map(|_| self.u16()).collect()
    }
    fn string(&mut self) -> Result<String, DecodeError> {
        let n = usize::from(self.take(1)?[0]);
        if n == 0 {
            return Ok(String::new());
        }
        let units: Vec<u16> = (0..n).map(|_| self.u16()).collect::<Result<_, _>>()?;
        if units.last() != Some(&0) {
            return Err(DecodeError::malformed(self.what, "string without NUL terminator", &[]));
        }
        String::from_utf16(&units[..n - 1]).map_err(|_| DecodeError::malformed(self.what, "invalid UTF-16", &[]))
    }
    fn finish(&self) -> Result<(), DecodeError> {
        if self.at == self.data.len() {
            Ok(())
        } else {
            Err(DecodeError::malformed(self.what, format!("{} trailing bytes", self.data.len() - self.at), &[]))
        }
    }
}

fn put_string(out: &mut Vec<u8>, field: &'static str, s: &str) -> Result<(), EncodeError> {
    if s.is_empty() {
        out.push(0);
        return Ok(());
    }
    let units: Vec<u16> = s.encode_utf16().chain([0]).collect();
    let n =
        u8::try_from(units.len()).map_err(|_| EncodeError::TooLong { what: field, len: units.len(), limit: 255 })?;
    if s.contains('\0') {
        return Err(EncodeError::Text { field, value: s.to_string(), allowed: "no NUL characters" });
    }
    out.push(n);
    for u in units {
        out.extend_from_slice(&u.to_le_bytes());
    }
    Ok(())
}

fn put_u16_array(out: &mut Vec<u8>, v: &[u16]) {
    out.extend_from_slice(&(v.len() as u32).to_le_bytes());
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// The DeviceInfo dataset (ISO 15740 5.5.1).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    /// PTP version x 100 (100 = 1.00).
    pub standard_version: u16,
    /// Vendor extension id.
    pub vendor_extension_id: u32,
    /// Vendor extension version.
    pub vendor_extension_version: u16,
    /// Vendor extension description.
    pub vendor_extension_desc: String,
    /// Functional mode.
    pub functional_mode: u16,
    /// Operation codes supported.
    pub operations: Vec<u16>,
    /// Event codes supported.
    pub events: Vec<u16>,
    /// Device property codes supported.
    pub properties: Vec<u16>,
    /// Capture formats.
    pub capture_formats: Vec<u16>,
    /// Image formats.
    pub image_formats: Vec<u16>,
    /// Manufacturer.
    pub manufacturer: String,
    /// Model.
    pub model: String,
    /// Device (firmware) version.
    pub device_version: String,
    /// Serial number.
    pub serial_number: String,
}

impl DeviceInfo {
    /// The dataset bytes (the data phase of GetDeviceInfo).
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let mut out = Vec::new();
        out.extend_from_slice(&self.standard_version.to_le_bytes());
        out.extend_from_slice(&self.vendor_extension_id.to_le_bytes());
        out.extend_from_slice(&self.vendor_extension_version.to_le_bytes());
        put_string(&mut out, "vendor_extension_desc", &self.vendor_extension_desc)?;
        out.extend_from_slice(&self.functional_mode.to_le_bytes());
        for a in [&self.operations, &self.events, &self.properties, &self.capture_formats, &self.image_formats] {
            put_u16_array(&mut out, a);
        }
        put_string(&mut out, "manufacturer", &self.manufacturer)?;
        put_string(&mut out, "model", &self.model)?;
        put_string(&mut out, "device_version", &self.device_version)?;
        put_string(&mut out, "serial_number", &self.serial_number)?;
        Ok(out)
    }

    /// Parses the dataset.
    pub fn decode(data: &[u8]) -> Result<DeviceInfo, DecodeError> {
        let mut r = Reader { data, at: 0, what: "ptp device info" };
        let info = DeviceInfo {
            standard_version: r.u16()?,
            vendor_extension_id: r.u32()?,
            vendor_extension_version: r.u16()?,
            vendor_extension_desc: r.string()?,
            functional_mode: r.u16()?,
            operations: r.u16_array()?,
            events: r.u16_array()?,
            properties: r.u16_array()?,
            capture_formats: r.u16_array()?,
            image_formats: r.u16_array()?,
            manufacturer: r.string()?,
            model: r.string()?,
            device_version: r.string()?,
            serial_number: r.string()?,
        };
        r.finish()?;
        Ok(info)
    }
}

/// A device property value of the subset, typed by property.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PropValue {
    /// [`prop::EXPOSURE_TIME`]: units of 0.1 ms.
    ExposureTime(u32),
    /// [`prop::EXPOSURE_INDEX`]: ISO.
    ExposureIndex(u16),
    /// [`prop::F_NUMBER`]: f-number x 100.
    FNumber(u16),
    /// [`prop::BTFRIG_EXPOSURE_S`]: seconds, exact.
    ExposureS(f64),
    /// [`prop::BTFRIG_GAIN`]: gain, exact.
    Gain(f64),
}

impl PropValue {
    /// The property code.
    pub fn prop(&self) -> u16 {
        match self {
            PropValue::ExposureTime(_) => prop::EXPOSURE_TIME,
            PropValue::ExposureIndex(_) => prop::EXPOSURE_INDEX,
            PropValue::FNumber(_) => prop::F_NUMBER,
            PropValue::ExposureS(_) => prop::BTFRIG_EXPOSURE_S,
            PropValue::Gain(_) => prop::BTFRIG_GAIN,
        }
    }

    /// The value's bytes (data phase).
    pub fn encode(&self) -> Vec<u8> {
        match *self {
            PropValue::ExposureTime(v) => v.to_le_bytes().to_vec(),
            PropValue::ExposureIndex(v) | PropValue::FNumber(v) => v.to_le_bytes().to_vec(),
            PropValue::ExposureS(v) | PropValue::Gain(v) => v.to_bits().to_le_bytes().to_vec(),
        }
    }

    /// The value of property `prop` from its bytes.
    pub fn decode(prop: u16, data: &[u8]) -> Result<PropValue, DecodeError> {
        let want = match prop {
            prop::EXPOSURE_TIME => 4,
            prop::EXPOSURE_INDEX | prop::F_NUMBER => 2,
            prop::BTFRIG_EXPOSURE_S | prop::BTFRIG_GAIN => 8,
            p => {
                return Err(DecodeError::malformed("ptp property", format!("property {p:#06x} not in the subset"), &[]))
            }
        };
        if data.len() != want {
            return Err(DecodeError::malformed("ptp property", format!("{} bytes, expected {want}", data.len()), data));
        }
        let u16v = || u16::from_le_bytes([data[0], data[1]]);
        let f64v = || {
            let mut b = [0u8; 8];
            b.copy_from_slice(data);
            f64::from_bits(u64::from_le_bytes(b))
        };
        Ok(match prop {
            prop::EXPOSURE_TIME => PropValue::ExposureTime(u32::from_le_bytes([data[0], data[1], data[2], data[3]])),
            prop::EXPOSURE_INDEX => PropValue::ExposureIndex(u16v()),
            prop::F_NUMBER => PropValue::FNumber(u16v()),
            prop::BTFRIG_EXPOSURE_S => PropValue::ExposureS(f64v()),
            _ => PropValue::Gain(f64v()),
        })
    }
}

pub mod raw;

#[cfg(test)]
mod tests {
    use super::*;

    fn info() -> DeviceInfo {
        DeviceInfo {
            standard_version: 100,
            vendor_extension_id: 0,
            vendor_extension_version: 0,
            vendor_extension_desc: "btfrig: 1.0".into(),
            functional_mode: 0,
            operations: vec![op::GET_DEVICE_INFO, op::OPEN_SESSION, op::INITIATE_CAPTURE],
            events: vec![ev::OBJECT_ADDED],
            properties: vec![prop::EXPOSURE_TIME],
            capture_formats: vec![FORMAT_BTFRIG_RAW],
            image_formats: vec![FORMAT_BTFRIG_RAW],
            manufacturer: "btfrig".into(),
            model: "Emulated Ä".into(),
            device_version: "1.0".into(),
            serial_number: String::new(),
        }
    }

    #[test]
    fn container_byte_vectors() {
        // OpenSession(1), transaction 0: length 16, type 1, code 0x1002.
        let c = Operation::OpenSession { session_id: 1 }.to_container(0);
        assert_eq!(c.encode().unwrap(), [16, 0, 0, 0, 1, 0, 0x02, 0x10, 0, 0, 0, 0, 1, 0, 0, 0]);
        // Response OK, transaction 5.
        assert_eq!(Response::ok().to_container(5).encode().unwrap(), [12, 0, 0, 0, 3, 0, 0x01, 0x20, 5, 0, 0, 0]);
        // ObjectAdded(0x42), transaction 7.
        assert_eq!(
            Event::ObjectAdded { handle: 0x42 }.to_container(7).encode().unwrap(),
            [16, 0, 0, 0, 4, 0, 0x02, 0x40, 7, 0, 0, 0, 0x42, 0, 0, 0]
        );
    }

    #[test]
    fn every_operation_event_and_response_round_trips() {
        let ops = [
            Operation::GetDeviceInfo,
            Operation::OpenSession { session_id: 1 },
            Operation::CloseSession,
            Operation::GetDevicePropValue { prop: prop::EXPOSURE_TIME },
            Operation::SetDevicePropValue { prop: prop::BTFRIG_EXPOSURE_S },
            Operation::InitiateCapture { storage_id: 0, format: FORMAT_BTFRIG_RAW },
            Operation::GetObject { handle: 9 },
            Operation::DeleteObject { handle: 9 },
        ];
        for (tid, o) in ops.iter().enumerate() {
            let mut d = ContainerDecoder::default();
            d.push(&o.to_container(tid as u32).encode().unwrap());
            let c = d.next().unwrap().unwrap();
            assert_eq!(c.transaction_id, tid as u32);
            assert_eq!(Operation::from_container(&c).unwrap(), *o);
        }
        for e in [
            Event::ObjectAdded { handle: 3 },
            Event::DevicePropChanged { prop: prop::F_NUMBER },
            Event::CaptureComplete,
            Event::Other { code: 0x4008, params: vec![1, 2] },
        ] {
            assert_eq!(Event::from_container(&e.to_container(1)).unwrap(), e);
        }
        let r = Response { code: rc::DEVICE_BUSY, params: vec![1, 2, 3] };
        assert_eq!(Response::from_container(&r.to_container(4)).unwrap(), r);
    }

    #[test]
    fn device_info_and_props_round_trip() {
        let bytes = info().encode().unwrap();
        assert_eq!(DeviceInfo::decode(&bytes).unwrap(), info());
        // Byte vector of the start: version 100, ext id 0, ext version 0, string "btfrig: 1.0" = 12 units.
        assert_eq!(&bytes[..9], &[100, 0, 0, 0, 0, 0, 0, 0, 12]);
        for cut in 0..bytes.len() {
            assert!(DeviceInfo::decode(&bytes[..cut]).is_err(), "truncated at {cut}");
        }
        let mut extra = bytes.clone();
        extra.push(0);
        assert!(DeviceInfo::decode(&extra).is_err());
        for v in [
            PropValue::ExposureTime(2000),
            PropValue::ExposureIndex(100),
            PropValue::FNumber(800),
            PropValue::ExposureS(0.0123),
            PropValue::Gain(2.5),
        ] {
            assert_eq!(PropValue::decode(v.prop(), &v.encode()).unwrap(), v);
        }
        assert!(PropValue::decode(prop::EXPOSURE_TIME, &[1, 2]).is_err());
        assert!(PropValue::decode(0x5001, &[1, 2]).is_err());
    }

    #[test]
    fn malformed_truncated_oversized_containers() {
        let good = Response::ok().to_container(1).encode().unwrap();
        let mut d = ContainerDecoder::new(64);
        // Truncated: waits.
        d.push(&good[..11]);
        assert!(d.next().is_none());
        d.push(&good[11..]);
        assert!(d.next().unwrap().is_ok());
        // Oversized: length 65 > 64.
        d.push(&[65, 0, 0, 0, 2, 0, 0x09, 0x10, 0, 0, 0, 0]);
        assert_eq!(d.next(), Some(Err(DecodeError::Oversized { what: "ptp container", limit: 64 })));
        d.clear();
        // Length under the header, unknown type.
        for bad in [[4u8, 0, 0, 0, 3, 0, 1, 0x20, 0, 0, 0, 0], [12, 0, 0, 0, 9, 0, 1, 0x20, 0, 0, 0, 0]] {
            let mut d = ContainerDecoder::new(64);
            d.push(&bad);
            assert!(matches!(d.next(), Some(Err(DecodeError::Malformed { .. }))));
        }
        // Garbage then a good container: the scan finds it.
        let mut d = ContainerDecoder::new(64);
        d.push(&[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]);
        d.push(&good);
        let got: Vec<_> = std::iter::from_fn(|| d.next()).collect();
        assert_eq!(got.last().unwrap().as_ref().unwrap(), &Response::ok().to_container(1));
        // Parameters that are not whole u32s, or too many.
        let c = Container { kind: ContainerKind::Response, code: rc::OK, transaction_id: 0, payload: vec![1, 2, 3] };
        assert!(Response::from_container(&c).is_err());
        let c = Container::with_params(ContainerKind::Response, rc::OK, 0, &[0; 6]);
        assert!(Response::from_container(&c).is_err());
        // Wrong container types and unknown operations.
        assert!(Operation::from_container(&Response::ok().to_container(0)).is_err());
        assert!(Operation::from_container(&Container::with_params(ContainerKind::Command, 0x1004, 0, &[])).is_err());
        assert!(Event::from_container(&Container::with_params(ContainerKind::Event, ev::OBJECT_ADDED, 0, &[])).is_err());
    }

    #[test]
    fn response_kinds() {
        assert!(response_kind(rc::DEVICE_BUSY).is_retryable());
        assert!(response_kind(rc::SESSION_NOT_OPEN).is_retryable());
        assert_eq!(response_kind(rc::INVALID_DEVICE_PROP_VALUE), ErrorKind::OutOfRange);
        assert!(!response_kind(rc::STORE_FULL).is_retryable());
    }
}
