//! [`PtpTransport`] over USB with `nusb` (pure Rust, no libusb): the Still Image Capture
//! interface (class 6, subclass 1, protocol 1) and its bulk-out, bulk-in and interrupt-in
//! endpoints. Untested without a camera: `btfrig hw probe` lists what it finds, and
//! `docs/serial.md` says how a person with a camera verifies it.

use std::io;

use async_trait::async_trait;
use nusb::transfer::{Direction, EndpointType, RequestBuffer};

use crate::transport::PtpTransport;

/// USB interface class, subclass and protocol of a PTP (Still Image) device.
pub const STILL_IMAGE: (u8, u8, u8) = (6, 1, 1);

/// An attached USB device, as `btfrig hw probe` lists it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UsbDevice {
    /// Bus number.
    pub bus: u8,
    /// Address on the bus.
    pub address: u8,
    /// Vendor id.
    pub vendor_id: u16,
    /// Product id.
    pub product_id: u16,
    /// Manufacturer string, if the device gives one.
    pub manufacturer: Option<String>,
    /// Product string.
    pub product: Option<String>,
    /// Serial number.
    pub serial: Option<String>,
    /// The number of its Still Image interface, if it has one (a PTP camera).
    pub ptp_interface: Option<u8>,
}

/// Every attached USB device.
pub fn list_devices() -> io::Result<Vec<UsbDevice>> {
    let list = nusb::list_devices().map_err(io::Error::other)?;
    Ok(list
        .map(|d| UsbDevice {
            bus: d.bus_number(),
            address: d.device_address(),
            vendor_id: d.vendor_id(),
            product_id: d.product_id(),
            manufacturer: d.manufacturer_string().map(str::to_string),
            product: d.product_string().map(str::to_string),
            serial: d.serial_number().map(str::to_string),
            ptp_interface: d
                .interfaces()
                .find(|i| (i.class(), i.subclass(), i.protocol()) == STILL_IMAGE)
                .map(|i| i.interface_number()),
        })
        .collect())
}

/// The PTP pipes of one camera.
pub struct UsbPtpTransport {
    iface: nusb::Interface,
    ep_out: u8,
    ep_in: u8,
    ep_event: u8,
    name: String,
}

fn no(what: &str) -> io::Error {
    io::Error::new(io::ErrorKind::NotFound, what.to_string())
}

impl UsbPtpTransport {
    /// Opens the first camera with a Still Image interface (or the one at `bus`:`address`),
    /// claims the interface (detaching a kernel driver such as gvfs' if needed).
    pub fn open(at: Option<(u8, u8)>) -> io::Result<UsbPtpTransport> {
        let info = nusb::list_devices()
            .map_err(io::Error::other)?
            .filter(|d| at.is_none_or(|(b, a)| d.bus_number() == b && d.device_address() == a))
            .find(|d| d.interfaces().any(|i| (i.class(), i.subclass(), i.protocol()) == STILL_IMAGE))
            .ok_or_else(|| no("no USB device with a Still Image (PTP) interface"))?;
        let n = info
            .interfaces()
            .find(|i| (i.class(), i.subclass(), i.protocol()) == STILL_IMAGE)
            .map(|i| i.interface_number())
            .ok_or_else(|| no("Still Image interface"))?;
        let device = info.open().map_err(io::Error::other)?;
        let iface = device.detach_and_claim_interface(n).map_err(io::Error::other)?;
        let (mut ep_out, mut ep_in, mut ep_event) = (None, None, None);
        for alt in iface.descriptors() {
            for ep in alt.endpoints() {
                match (ep.transfer_type(), ep.direction()) {
                    (EndpointType::Bulk, Direction::Out) => ep_out = ep_out.or(Some(ep.address())),
                    (EndpointType::Bulk, Direction::In) => ep_in = ep_in.or(Some(ep.address())),
                    (EndpointType::Interrupt, Direction::In) => ep_event = ep_event.or(Some(ep.address())),
                    _ => {}
                }
            }
        }
        let name = format!(
            "USB {:04x}:{:04x} {} at bus {} address {}",
            info.vendor_id(),
            info.product_id(),
            info.product_string().unwrap_or("camera"),
            info.bus_number(),
            info.device_address()
        );
        Ok(UsbPtpTransport {
            iface,
            ep_out: ep_out.ok_or_else(|| no("bulk-out endpoint"))?,
            ep_in: ep_in.ok_or_else(|| no("bulk-in endpoint"))?,
            ep_event: ep_event.ok_or_else(|| no("interrupt-in endpoint"))?,
            name,
        })
    }
}

/// Largest bulk-in transfer asked for (containers span transfers; the decoder joins them).
const BULK_CHUNK: usize = 1 << 20;

#[async_trait]
impl PtpTransport for UsbPtpTransport {
    async fn bulk_out(&mut self, bytes: Vec<u8>) -> io::Result<()> {
        self.iface.bulk_out(self.ep_out, bytes).await.into_result().map(|_| ()).map_err(io::Error::other)
    }

    /// Dropping the future cancels the transfer (nusb); bytes already received by a
    /// cancelled transfer are lost, so a cancelled exchange is followed by `reset`.
    async fn bulk_in(&mut self) -> io::Result<Vec<u8>> {
        self.iface.bulk_in(self.ep_in, RequestBuffer::new(BULK_CHUNK)).await.into_result().map_err(io::Error::other)
    }

    async fn interrupt_in(&mut self) -> io::Result<Vec<u8>> {
        self.iface.interrupt_in(self.ep_event, RequestBuffer::new(64)).await.into_result().map_err(io::Error::other)
    }

    async fn reset(&mut self) -> io::Result<()> {
        for ep in [self.ep_out, self.ep_in, self.ep_event] {
            self.iface.clear_halt(ep).map_err(io::Error::other)?;
        }
        Ok(())
    }

    fn describe(&self) -> String {
        self.name.clone()
    }
}
