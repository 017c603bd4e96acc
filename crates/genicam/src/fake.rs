//! A GigE Vision fake camera served by this process on a loopback address, whose frames carry
//! our own pixels: Aravis's `ArvGvFakeCamera` with a fill hook ([`crate::ffi::FillHook`]).
//!
//! A client (our [`crate::GenicamCamera`], or any GenICam tool) opens it by address and
//! receives the pixels over real GVCP/GVSP. Aravis's fake camera describes itself with a
//! GenICam XML embedded in libaravis; at start we take that XML from Aravis and add, by a
//! few named insertions ([`fed_genicam_xml`]):
//! - the 12- and 16-bit Bayer and mono pixel formats (its registers take any PFNC code, its
//!   XML lists only 8-bit ones and Mono16);
//! - `ExposureTime` as a 64-bit float register in microseconds (the stock one is an integer
//!   register of whole microseconds), so that an exposure round-trips exactly;
//! - `Gain` as a float register in dB (the stock camera has only `GainRaw`, 0..10);
//! - `DeviceTemperature` (°C), a float register the feeding side sets.
//!
//! The new registers live in the fake camera's free memory from [`BTFRIG_REGISTERS`].

use std::net::Ipv4Addr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use crate::error::Error;
use crate::ffi::FillHook;
use crate::format::FORMATS;

/// Start of the registers added to the fake camera's XML (its 64 KiB memory has nothing there).
pub const BTFRIG_REGISTERS: u32 = 0x8000;
const EXPOSURE_REGISTER: u32 = BTFRIG_REGISTERS;
const GAIN_REGISTER: u32 = BTFRIG_REGISTERS + 8;
const TEMPERATURE_REGISTER: u32 = BTFRIG_REGISTERS + 16;

/// The next frame a fed fake camera sends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FeedFrame {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// PFNC pixel format code.
    pub pixel_format: u32,
    /// The bytes, as they go on the wire.
    pub bytes: Vec<u8>,
}

/// What the fill hook reads: the next frame, and counters.
#[derive(Debug, Default)]
pub struct Feed {
    next: Mutex<Option<FeedFrame>>,
    fills: AtomicU64,
    misses: AtomicU64,
}

impl Feed {
    /// Sets the frame the next triggered buffer carries (replacing one not yet sent).
    pub fn set_next(&self, frame: FeedFrame) {
        *self.next.lock().unwrap_or_else(|e| e.into_inner()) = Some(frame);
    }

    /// Frames filled with our pixels so far.
    pub fn fills(&self) -> u64 {
        self.fills.load(Ordering::Relaxed)
    }

    /// Buffers sent without our pixels (none set, or not of the buffer's size and format).
    pub fn misses(&self) -> u64 {
        self.misses.load(Ordering::Relaxed)
    }

    pub(crate) fn count_miss(&self) {
        self.misses.fetch_add(1, Ordering::Relaxed);
    }

    /// The hook's side: hands the next frame's bytes to `write` if it is `width` x `height`
    /// of `pixel_format` and exactly `bytes` long, and consumes it; otherwise counts a miss.
    pub(crate) fn take_matching(
        &self,
        width: u32,
        height: u32,
        pixel_format: u32,
        bytes: usize,
        write: impl FnOnce(&[u8]),
    ) {
        let frame = self.next.lock().unwrap_or_else(|e| e.into_inner()).take();
        match frame {
            Some(f)
                if f.width == width
                    && f.height == height
                    && f.pixel_format == pixel_format
                    && f.bytes.len() == bytes =>
            {
                write(&f.bytes);
                self.fills.fetch_add(1, Ordering::Relaxed);
            }
            _ => self.count_miss(),
        }
    }
}

/// Aravis's fake camera XML with btfrig's additions (see the module docs). Fails naming the
/// anchor that was not found, should a later Aravis change its XML.
pub fn fed_genicam_xml(stock: &str) -> Result<String, Error> {
    let anchor =
        |what: &str| Error::Other(format!("Aravis's fake camera XML has no {what}: cannot add btfrig's features"));
    let mut xml = stock.to_string();

    // Pixel formats: entries after the enumeration's display name.
    let pf = "<Enumeration Name=\"PixelFormat\"";
    let at = xml.find(pf).ok_or_else(|| anchor("PixelFormat enumeration"))?;
    let open_end = at + xml[at..].find('>').ok_or_else(|| anchor("PixelFormat enumeration"))? + 1;
    let entries: String = FORMATS
        .iter()
        .filter(|(name, _, _)| !stock.contains(&format!("<EnumEntry Name=\"{name}\"")))
        .map(|(name, code, _)| {
            format!("\n\t\t<EnumEntry Name=\"{name}\" NameSpace=\"Standard\">\n\t\t\t<Value>{code}</Value>\n\t\t</EnumEntry>")
        })
        .collect();
    xml.insert_str(open_end, &entries);

    // ExposureTimeAbs reads the float register instead of the integer one.
    let old = "<pValue>ExposureTimeAbsConverter</pValue>";
    if !xml.contains(old) {
        return Err(anchor("ExposureTimeAbs converter"));
    }
    xml = xml.replacen(old, "<pValue>BtfrigExposureTimeRegister</pValue>", 1);

    let float_reg = |name: &str, address: u32, length: u32, access: &str| {
        format!(
            "\n\t<FloatReg Name=\"{name}\" NameSpace=\"Custom\">\n\t\t<Address>{address:#x}</Address>\n\t\t<Length>{length}</Length>\n\t\t<AccessMode>{access}</AccessMode>\n\t\t<pPort>Device</pPort>\n\t\t<Endianess>BigEndian</Endianess>\n\t</FloatReg>\n"
        )
    };
    let mut added = String::new();
    added += &float_reg("BtfrigExposureTimeRegister", EXPOSURE_REGISTER, 8, "RW");
    added += "\n\t<Float Name=\"Gain\" NameSpace=\"Standard\">\n\t\t<Description>Analogue gain, dB (btfrig).</Description>\n\t\t<pValue>BtfrigGainRegister</pValue>\n\t\t<Min>0.0</Min>\n\t\t<Max>48.0</Max>\n\t\t<Unit>dB</Unit>\n\t</Float>\n";
    added += &float_reg("BtfrigGainRegister", GAIN_REGISTER, 8, "RW");
    added += "\n\t<Float Name=\"DeviceTemperature\" NameSpace=\"Standard\">\n\t\t<Description>Sensor temperature, degrees Celsius (btfrig: set by the feeding side).</Description>\n\t\t<pValue>BtfrigDeviceTemperatureRegister</pValue>\n\t\t<Min>-273.15</Min>\n\t\t<Max>1000.0</Max>\n\t\t<Unit>C</Unit>\n\t</Float>\n";
    added += &float_reg("BtfrigDeviceTemperatureRegister", TEMPERATURE_REGISTER, 4, "RO");
    let end = xml.rfind("</RegisterDescription>").ok_or_else(|| anchor("</RegisterDescription>"))?;
    xml.insert_str(end, &added);
    Ok(xml)
}

/// A GigE Vision fake camera served by this process, fed with our pixels. `Sync`: Aravis's
/// objects (Send, not Sync) sit behind a mutex.
pub struct FedFakeCamera {
    served: Mutex<Served>,
    feed: Arc<Feed>,
    xml: PathBuf,
    address: Ipv4Addr,
    serial: String,
}

/// Aravis's side of a [`FedFakeCamera`].
struct Served {
    // Field order is drop order: the hook is removed before the camera goes.
    _hook: FillHook,
    gv: aravis::GvFakeCamera,
    fake: aravis::FakeCamera,
}

impl FedFakeCamera {
    /// Starts a fake camera on `address` (port 3956; 127.0.0.1 for loopback) with serial
    /// number `serial` (at most 15 characters), answering software triggers within 1 ms.
    /// Fails if the port is taken (another fake camera in this network namespace).
    pub fn start(address: Ipv4Addr, serial: &str) -> Result<FedFakeCamera, Error> {
        if serial.is_empty() || serial.len() > 15 || !serial.is_ascii() {
            return Err(Error::Other(format!("fake camera serial {serial:?}: allowed 1 to 15 ASCII characters")));
        }
        let (stock, _) = aravis::FakeCamera::new("btfrig-xml").genicam_xml();
        let xml_text = fed_genicam_xml(stock.as_str())?;
        let xml = std::env::temp_dir().join(format!("btfrig-fake-camera-{}-{serial}.xml", std::process::id()));
        std::fs::write(&xml, xml_text)
            .map_err(|e| Error::Other(format!("cannot write the fake camera's XML {}: {e}", xml.display())))?;
        let gv = aravis::GvFakeCamera::new_full(
            Some(&address.to_string()),
            Some(serial),
            Some(xml.to_str().ok_or_else(|| Error::Other("temporary directory is not UTF-8".into()))?),
        );
        if !gv.is_running() {
            let _ = std::fs::remove_file(&xml);
            return Err(Error::Other(format!(
                "the fake camera could not listen on {address}:3956: another GigE Vision camera or fake camera holds \
                 the port in this network namespace, or {address} is not an address of this host"
            )));
        }
        let fake = gv.fake_camera().ok_or_else(|| Error::Other("the GigE fake camera has no fake camera".into()))?;
        fake.set_trigger_frequency(1000.0);
        let feed = Arc::new(Feed::default());
        let hook = FillHook::install(fake.clone(), feed.clone());
        let cam = FedFakeCamera {
            served: Mutex::new(Served { _hook: hook, gv, fake }),
            feed,
            xml,
            address,
            serial: serial.to_string(),
        };
        cam.set_temperature_c(25.0);
        Ok(cam)
    }

    /// Where clients open it.
    pub fn address(&self) -> Ipv4Addr {
        self.address
    }

    /// Its serial number (clients check it to be sure they reached this camera).
    pub fn serial(&self) -> &str {
        &self.serial
    }

    /// The feed its frames come from.
    pub fn feed(&self) -> Arc<Feed> {
        self.feed.clone()
    }

    /// Sets what `DeviceTemperature` reads.
    pub fn set_temperature_c(&self, celsius: f64) {
        let served = self.served.lock().unwrap_or_else(|e| e.into_inner());
        served.fake.write_register(TEMPERATURE_REGISTER, (celsius as f32).to_bits());
    }

    /// Whether it still listens.
    pub fn is_running(&self) -> bool {
        self.served.lock().unwrap_or_else(|e| e.into_inner()).gv.is_running()
    }
}

impl Drop for FedFakeCamera {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.xml);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xml_additions_fail_clearly_without_their_anchors() {
        let e = fed_genicam_xml("<RegisterDescription></RegisterDescription>").unwrap_err();
        assert!(e.to_string().contains("PixelFormat enumeration"), "{e}");
    }

    #[test]
    fn feed_hands_over_only_a_matching_frame_once() {
        let feed = Feed::default();
        feed.set_next(FeedFrame { width: 2, height: 1, pixel_format: 0x0110_0007, bytes: vec![1, 2, 3, 4] });
        let mut got = Vec::new();
        feed.take_matching(2, 1, 0x0108_0001, 2, |b| got.extend_from_slice(b));
        assert!(got.is_empty());
        assert_eq!((feed.fills(), feed.misses()), (0, 1));
        feed.set_next(FeedFrame { width: 2, height: 1, pixel_format: 0x0110_0007, bytes: vec![1, 2, 3, 4] });
        feed.take_matching(2, 1, 0x0110_0007, 4, |b| got.extend_from_slice(b));
        assert_eq!(got, [1, 2, 3, 4]);
        feed.take_matching(2, 1, 0x0110_0007, 4, |b| got.extend_from_slice(b));
        assert_eq!((feed.fills(), feed.misses()), (1, 2));
    }
}
