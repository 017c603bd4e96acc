//! [`GenicamCamera`]: one GenICam camera, owned by one thread.
//!
//! Aravis's objects are `Send` but not `Sync`, and two clones on two threads would share
//! them anyway; so one thread owns the camera and its stream, and the handle sends it
//! closures over a channel and waits for the answer with a timeout (never forever: a camera
//! stuck in a GVCP retry shows as [`Error::Timeout`], not as a hang).

use std::net::Ipv4Addr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use aravis::glib::prelude::Cast;
use aravis::prelude::*;
use aravis::{BufferStatus, Camera, Stream};

use crate::error::Error;
use crate::format::PixelFormat;
use crate::frame_id::FrameIdUnwrapper;

/// How a camera is reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Target {
    /// A GigE Vision camera by IP address: no broadcast.
    Address(Ipv4Addr),
    /// A device id as Aravis lists it (`Aravis-Fake-GV01`, a USB3 Vision id, `Fake_1`).
    /// Except for Aravis's in-process fake (`Fake_*`), opening by id runs a discovery that
    /// broadcasts on every network interface, so it needs `allow_discovery`.
    Id(String),
}

impl Target {
    /// `192.168.1.20` is an address, anything else an id.
    pub fn parse(s: &str) -> Target {
        match s.parse::<Ipv4Addr>() {
            Ok(a) => Target::Address(a),
            Err(_) => Target::Id(s.to_string()),
        }
    }

    /// Whether opening it broadcasts a discovery.
    pub fn broadcasts(&self) -> bool {
        match self {
            Target::Address(_) => false,
            Target::Id(id) => !id.starts_with("Fake_"),
        }
    }

    fn aravis_name(&self) -> String {
        match self {
            Target::Address(a) => a.to_string(),
            Target::Id(id) => id.clone(),
        }
    }
}

impl std::fmt::Display for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.aravis_name())
    }
}

/// How to open a camera.
#[derive(Debug, Clone)]
pub struct OpenOptions {
    /// The camera.
    pub target: Target,
    /// Whether opening by id may broadcast a discovery.
    pub allow_discovery: bool,
    /// The longest a control call may take before it counts as timed out.
    pub control_timeout: Duration,
    /// Stream buffers queued.
    pub buffers: usize,
    /// How long opening waits for another client's control privilege (GigE Vision) to end:
    /// a client that died holds it until the camera's heartbeat timeout (3 s by default in the
    /// standard), so a restarted program must wait that out rather than fail.
    pub privilege_wait: Duration,
}

impl OpenOptions {
    /// Defaults for `target`: no discovery, 5 s control timeout, 4 buffers, 5 s wait for the
    /// control privilege.
    pub fn new(target: Target) -> Self {
        OpenOptions {
            target,
            allow_discovery: false,
            control_timeout: Duration::from_secs(5),
            buffers: 4,
            privilege_wait: Duration::from_secs(5),
        }
    }
}

/// Who the camera is and what it offers.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// Device id.
    pub id: String,
    /// Vendor.
    pub vendor: String,
    /// Model.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Firmware / device version, if the camera reports one.
    pub version: Option<String>,
    /// The pixel formats it offers, by PFNC name (`0x...` for codes btfrig does not read).
    pub pixel_formats: Vec<String>,
    /// Sensor width and height, pixels.
    pub sensor: (u32, u32),
    /// Exposure range, microseconds.
    pub exposure_range_us: (f64, f64),
    /// Gain range, in the camera's gain unit (dB for `Gain`, steps for `GainRaw`).
    pub gain_range: (f64, f64),
    /// Whether it has `DeviceTemperature`.
    pub has_temperature: bool,
    /// Whether it has a software trigger.
    pub has_software_trigger: bool,
}

/// The image a camera sends.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageFormat {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Pixel format.
    pub pixel_format: PixelFormat,
}

/// How frames are started.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Trigger {
    /// Free running at the camera's frame rate.
    FreeRun,
    /// One frame per [`GenicamCamera::trigger_software`].
    Software,
    /// One frame per edge on an input line (`TriggerSource`, e.g. `Line0`).
    Hardware {
        /// The line.
        source: String,
    },
}

/// One frame as it arrived.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Pixel format.
    pub pixel_format: PixelFormat,
    /// The image bytes.
    pub data: Vec<u8>,
    /// Sequence number: the camera's frame ids unwrapped (see [`FrameIdUnwrapper`]).
    pub sequence: u64,
    /// The camera's own 16-bit frame id.
    pub frame_id: u64,
    /// The camera's time stamp, ns.
    pub timestamp_ns: u64,
    /// The host's arrival time stamp, ns.
    pub system_timestamp_ns: u64,
    /// Exposure the camera reports, microseconds.
    pub exposure_us: f64,
    /// Gain the camera reports, its unit.
    pub gain: f64,
    /// `DeviceTemperature` read after the frame, °C, where the camera has it.
    pub temperature_c: Option<f64>,
}

/// What the stream did so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamStats {
    /// Frames that arrived complete.
    pub completed: u64,
    /// Buffers that arrived incomplete or damaged.
    pub failures: u64,
    /// Waits that ended without a buffer (dropped frames).
    pub timeouts: u64,
    /// Frame ids skipped between two frames that arrived.
    pub skipped_ids: u64,
    /// Stale buffers discarded before a trigger.
    pub discarded: u64,
    /// Successful reconnections.
    pub reconnects: u64,
    /// Bytes of complete frames.
    pub bytes: u64,
}

type Job = Box<dyn FnOnce(&mut Owner) + Send>;

/// A GenICam camera: a handle to the thread that owns it. Cheap to clone (the clones talk to
/// the same thread); the thread ends when the last handle is dropped.
#[derive(Clone)]
pub struct GenicamCamera {
    jobs: mpsc::Sender<Job>,
    info: Arc<Mutex<CameraInfo>>,
    target: Target,
    control_timeout: Duration,
    privilege_wait: Duration,
}

impl std::fmt::Debug for GenicamCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GenicamCamera").field("target", &self.target).finish_non_exhaustive()
    }
}

/// The state the owner thread keeps.
struct Owner {
    target: Target,
    buffers: usize,
    privilege_wait: Duration,
    camera: Option<Camera>,
    stream: Option<Stream>,
    lost: Arc<AtomicBool>,
    ids: FrameIdUnwrapper,
    stats: StreamStats,
    // Applied settings, re-applied on reconnect.
    format: Option<ImageFormat>,
    exposure_us: Option<f64>,
    gain: Option<f64>,
    trigger: Trigger,
    frame_rate: Option<f64>,
    /// The stream runs, or ran before the connection was lost (restarted on reconnect).
    streaming: bool,
    /// Why the last reconnect failed, while the camera stays unconnected.
    reconnect_failure: Option<String>,
    has_temperature: bool,
}

fn other(e: aravis::glib::Error) -> String {
    e.message().to_string()
}

impl GenicamCamera {
    /// Opens the camera on its own thread and reads who it is.
    pub fn open(options: OpenOptions) -> Result<GenicamCamera, Error> {
        if options.target.broadcasts() && !options.allow_discovery {
            return Err(Error::DiscoveryNotAllowed { id: options.target.to_string() });
        }
        if let Target::Id(id) = &options.target {
            if id.starts_with("Fake_") {
                crate::ffi::enable_interface("Fake");
            }
        }
        let (jobs, rx) = mpsc::channel::<Job>();
        let target = options.target.clone();
        let buffers = options.buffers.max(1);
        let privilege_wait = options.privilege_wait;
        std::thread::Builder::new()
            .name(format!("genicam {target}"))
            .spawn(move || {
                let mut owner = Owner {
                    target,
                    buffers,
                    privilege_wait,
                    camera: None,
                    stream: None,
                    lost: Arc::new(AtomicBool::new(false)),
                    ids: FrameIdUnwrapper::new(),
                    stats: StreamStats::default(),
                    format: None,
                    exposure_us: None,
                    gain: None,
                    trigger: Trigger::FreeRun,
                    frame_rate: None,
                    streaming: false,
                    reconnect_failure: None,
                    has_temperature: false,
                };
                while let Ok(job) = rx.recv() {
                    job(&mut owner);
                }
                owner.close();
            })
            .map_err(|e| Error::Other(format!("cannot start the camera's thread: {e}")))?;
        let placeholder = CameraInfo {
            id: String::new(),
            vendor: String::new(),
            model: String::new(),
            serial: String::new(),
            version: None,
            pixel_formats: Vec::new(),
            sensor: (0, 0),
            exposure_range_us: (0.0, 0.0),
            gain_range: (0.0, 0.0),
            has_temperature: false,
            has_software_trigger: false,
        };
        let cam = GenicamCamera {
            jobs,
            info: Arc::new(Mutex::new(placeholder)),
            target: options.target,
            control_timeout: options.control_timeout,
            privilege_wait,
        };
        let info = cam.call(cam.control_timeout + privilege_wait, |o| o.connect())?;
        *cam.info.lock().unwrap_or_else(|e| e.into_inner()) = info;
        Ok(cam)
    }

    /// Runs `f` on the owner thread, waiting at most `timeout` for its answer.
    fn call<R: Send + 'static>(
        &self,
        timeout: Duration,
        f: impl FnOnce(&mut Owner) -> Result<R, Error> + Send + 'static,
    ) -> Result<R, Error> {
        let (tx, rx) = mpsc::sync_channel(1);
        let job: Job = Box::new(move |o| {
            let _ = tx.send(f(o));
        });
        self.jobs.send(job).map_err(|_| Error::Other("the camera's thread has ended".into()))?;
        match rx.recv_timeout(timeout) {
            Ok(r) => r,
            Err(mpsc::RecvTimeoutError::Timeout) => Err(Error::Disconnected {
                target: self.target.to_string(),
                message: format!("the camera did not answer within {:.1} s", timeout.as_secs_f64()),
            }),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(Error::Other("the camera's thread has ended".into())),
        }
    }

    /// Who the camera is (as read at open or the last reconnect).
    pub fn info(&self) -> CameraInfo {
        self.info.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// How it was opened.
    pub fn target(&self) -> &Target {
        &self.target
    }

    /// Sets width, height (from the sensor's top-left corner) and pixel format; stops a
    /// running stream first (start it again with [`GenicamCamera::start`]).
    pub fn set_image_format(&self, format: ImageFormat) -> Result<(), Error> {
        self.call(self.control_timeout, move |o| o.set_image_format(format))
    }

    /// Sets the exposure, microseconds; returns what the camera reports back.
    pub fn set_exposure_us(&self, us: f64) -> Result<f64, Error> {
        self.call(self.control_timeout, move |o| o.set_exposure_us(us))
    }

    /// Sets the gain in the camera's unit (`Gain`, dB, where it has it, else `GainRaw`);
    /// returns what the camera reports back.
    pub fn set_gain(&self, gain: f64) -> Result<f64, Error> {
        self.call(self.control_timeout, move |o| o.set_gain(gain))
    }

    /// Sets the free-run frame rate, Hz (where the camera has `AcquisitionFrameRate`).
    pub fn set_frame_rate(&self, hz: f64) -> Result<(), Error> {
        self.call(self.control_timeout, move |o| o.set_frame_rate(hz))
    }

    /// Chooses how frames start.
    pub fn set_trigger(&self, trigger: Trigger) -> Result<(), Error> {
        self.call(self.control_timeout, move |o| o.set_trigger(trigger))
    }

    /// Creates the stream, queues its buffers and starts acquisition.
    pub fn start(&self) -> Result<(), Error> {
        self.call(self.control_timeout, |o| o.start())
    }

    /// Stops acquisition and drops the stream.
    pub fn stop(&self) -> Result<(), Error> {
        self.call(self.control_timeout, |o| {
            o.stop();
            Ok(())
        })
    }

    /// Discards frames waiting in the stream, sends a software trigger and waits for the
    /// frame it starts (at most `timeout`).
    pub fn trigger_software(&self, timeout: Duration) -> Result<Frame, Error> {
        self.call(timeout + self.control_timeout, move |o| o.trigger_and_wait(timeout))
    }

    /// The next frame of the stream (free run or hardware trigger), waiting at most `timeout`.
    pub fn next_frame(&self, timeout: Duration) -> Result<Frame, Error> {
        self.call(timeout + self.control_timeout, move |o| o.pop(timeout))
    }

    /// `DeviceTemperature`, °C, or `None` if the camera has none.
    pub fn temperature_c(&self) -> Result<Option<f64>, Error> {
        self.call(self.control_timeout, |o| o.temperature())
    }

    /// What the stream did so far.
    pub fn stats(&self) -> Result<StreamStats, Error> {
        self.call(self.control_timeout, |o| Ok(o.stats))
    }

    /// Drops the connection and opens the camera again, re-applying format, exposure, gain,
    /// trigger and frame rate, and restarting the stream if it ran. Fails with
    /// [`Error::Disconnected`] while the camera is away.
    pub fn reconnect(&self) -> Result<CameraInfo, Error> {
        let info = self.call(self.control_timeout + self.privilege_wait, |o| o.reconnect())?;
        *self.info.lock().unwrap_or_else(|e| e.into_inner()) = info.clone();
        Ok(info)
    }
}

impl Owner {
    fn disconnected(&self, message: impl Into<String>) -> Error {
        Error::Disconnected { target: self.target.to_string(), message: message.into() }
    }

    /// An Aravis error of a control call: the camera is gone if the control channel was lost
    /// or the call timed out or failed to transfer; else what Aravis said about `what`.
    fn control_error(&self, what: &str, e: aravis::glib::Error) -> Error {
        let gone = self.lost.load(Ordering::SeqCst)
            || e.matches(aravis::DeviceError::Timeout)
            || e.matches(aravis::DeviceError::NotConnected)
            || e.matches(aravis::DeviceError::TransferError)
            || e.matches(aravis::DeviceError::ProtocolError);
        if gone {
            self.disconnected(format!("{what}: {}", e.message()))
        } else if e.matches(aravis::DeviceError::FeatureNotFound) {
            Error::Unsupported { what: what.to_string(), message: e.message().to_string() }
        } else {
            Error::Other(format!("{what}: {}", e.message()))
        }
    }

    fn camera(&self) -> Result<&Camera, Error> {
        self.camera.as_ref().ok_or_else(|| {
            self.disconnected(match &self.reconnect_failure {
                Some(e) => format!("not connected: the last reconnect failed: {e}"),
                None => "not connected".to_string(),
            })
        })
    }

    /// Takes a GigE Vision camera's control privilege, waiting up to `privilege_wait` while
    /// another client holds it (one that died keeps it until its heartbeat times out).
    /// Without it the camera can be read but not streamed from.
    fn take_control(&self, camera: &Camera) -> Result<(), Error> {
        let Some(gv) = camera.device().and_then(|d| d.downcast::<aravis::GvDevice>().ok()) else {
            return Ok(());
        };
        let t0 = std::time::Instant::now();
        loop {
            if gv.is_controller() {
                return Ok(());
            }
            match gv.take_control() {
                Ok(()) => return Ok(()),
                Err(_) if t0.elapsed() < self.privilege_wait => std::thread::sleep(Duration::from_millis(200)),
                Err(e) => {
                    return Err(self.disconnected(format!(
                        "another client holds its control privilege (still after {:.1} s: {}); a client that \
                         ended without closing releases it when the camera's heartbeat times out",
                        t0.elapsed().as_secs_f64(),
                        e.message()
                    )))
                }
            }
        }
    }

    fn connect(&mut self) -> Result<CameraInfo, Error> {
        let camera = Camera::new(Some(&self.target.aravis_name()))
            .map_err(|e| self.disconnected(format!("cannot open it: {}", other(e))))?;
        self.take_control(&camera)?;
        self.lost.store(false, Ordering::SeqCst);
        if let Some(device) = camera.device() {
            let lost = self.lost.clone();
            device.connect_control_lost(move |_| lost.store(true, Ordering::SeqCst));
        }
        let s = |r: Result<aravis::glib::GString, aravis::glib::Error>| r.map(|g| g.to_string()).unwrap_or_default();
        let formats = camera
            .dup_available_pixel_formats()
            .map_err(|e| self.control_error("PixelFormat", e))?
            .into_iter()
            .map(|c| match PixelFormat::from_code(c as u32) {
                Some(f) => f.name().to_string(),
                None => format!("{:#010x}", c as u32),
            })
            .collect();
        let (sw, sh) = camera.sensor_size().map_err(|e| self.control_error("SensorWidth/Height", e))?;
        self.has_temperature = camera.is_feature_available("DeviceTemperature").unwrap_or(false);
        let info = CameraInfo {
            id: s(camera.device_id()),
            vendor: s(camera.vendor_name()),
            model: s(camera.model_name()),
            serial: s(camera.device_serial_number()),
            version: camera.string("DeviceVersion").ok().map(|g| g.to_string()),
            pixel_formats: formats,
            sensor: (sw.max(0) as u32, sh.max(0) as u32),
            exposure_range_us: camera.exposure_time_bounds().unwrap_or((0.0, 0.0)),
            gain_range: camera.gain_bounds().unwrap_or((0.0, 0.0)),
            has_temperature: self.has_temperature,
            has_software_trigger: camera.is_software_trigger_supported().is_ok(),
        };
        self.camera = Some(camera);
        Ok(info)
    }

    fn set_image_format(&mut self, format: ImageFormat) -> Result<(), Error> {
        self.stop();
        let cam = self.camera()?;
        let available = cam.dup_available_pixel_formats().map_err(|e| self.control_error("PixelFormat", e))?;
        if !available.iter().any(|&c| c as u32 == format.pixel_format.code()) {
            let names: Vec<String> = available
                .iter()
                .map(|&c| PixelFormat::from_code(c as u32).map_or(format!("{:#010x}", c as u32), |f| f.name().into()))
                .collect();
            return Err(Error::Unsupported {
                what: format!("PixelFormat {}", format.pixel_format.name()),
                message: format!("the camera offers {}", names.join(", ")),
            });
        }
        // The pixel format first: it can change the width and height limits.
        cam.set_pixel_format(aravis::PixelFormat::from_raw(format.pixel_format.code()))
            .map_err(|e| self.control_error("PixelFormat", e))?;
        let (wmin, wmax) = cam.width_bounds().map_err(|e| self.control_error("Width", e))?;
        let (hmin, hmax) = cam.height_bounds().map_err(|e| self.control_error("Height", e))?;
        for (what, v, lo, hi) in [("Width", format.width, wmin, wmax), ("Height", format.height, hmin, hmax)] {
            if (v as i64) < lo as i64 || v as i64 > hi as i64 {
                return Err(Error::OutOfRange {
                    what: what.into(),
                    value: v.to_string(),
                    allowed: format!("[{lo}, {hi}]"),
                });
            }
        }
        cam.set_region(0, 0, format.width as i32, format.height as i32).map_err(|e| self.control_error("region", e))?;
        let got = cam.pixel_format().map_err(|e| self.control_error("PixelFormat", e))?.raw();
        let (_, _, w, h) = cam.region().map_err(|e| self.control_error("region", e))?;
        if got != format.pixel_format.code() || w as u32 != format.width || h as u32 != format.height {
            return Err(Error::Other(format!(
                "the camera took {w} x {h} {got:#010x} for {} x {} {}",
                format.width,
                format.height,
                format.pixel_format.name()
            )));
        }
        self.format = Some(format);
        Ok(())
    }

    fn set_exposure_us(&mut self, us: f64) -> Result<f64, Error> {
        let cam = self.camera()?;
        let (lo, hi) = cam.exposure_time_bounds().map_err(|e| self.control_error("ExposureTime", e))?;
        if !(us >= lo && us <= hi) {
            return Err(Error::OutOfRange {
                what: "ExposureTime (us)".into(),
                value: us.to_string(),
                allowed: format!("[{lo}, {hi}]"),
            });
        }
        cam.set_exposure_time(us).map_err(|e| self.control_error("ExposureTime", e))?;
        let got = cam.exposure_time().map_err(|e| self.control_error("ExposureTime", e))?;
        self.exposure_us = Some(got);
        Ok(got)
    }

    fn set_gain(&mut self, gain: f64) -> Result<f64, Error> {
        let cam = self.camera()?;
        let (lo, hi) = cam.gain_bounds().map_err(|e| self.control_error("Gain", e))?;
        if !(gain >= lo && gain <= hi) {
            return Err(Error::OutOfRange {
                what: "Gain".into(),
                value: gain.to_string(),
                allowed: format!("[{lo}, {hi}]"),
            });
        }
        cam.set_gain(gain).map_err(|e| self.control_error("Gain", e))?;
        let got = cam.gain().map_err(|e| self.control_error("Gain", e))?;
        self.gain = Some(got);
        Ok(got)
    }

    fn set_frame_rate(&mut self, hz: f64) -> Result<(), Error> {
        let cam = self.camera()?;
        cam.set_frame_rate(hz).map_err(|e| self.control_error("AcquisitionFrameRate", e))?;
        self.frame_rate = Some(hz);
        Ok(())
    }

    fn set_trigger(&mut self, trigger: Trigger) -> Result<(), Error> {
        let cam = self.camera()?;
        match &trigger {
            Trigger::FreeRun => cam.clear_triggers().map_err(|e| self.control_error("TriggerMode", e))?,
            Trigger::Software => {
                cam.is_software_trigger_supported()
                    .map_err(|e| Error::Unsupported { what: "TriggerSoftware".into(), message: other(e) })?;
                cam.set_trigger("Software").map_err(|e| self.control_error("TriggerSource Software", e))?
            }
            Trigger::Hardware { source } => {
                let sources =
                    cam.dup_available_trigger_sources().map_err(|e| self.control_error("TriggerSource", e))?;
                if !sources.iter().any(|s| s.as_str() == source) {
                    let names: Vec<&str> = sources.iter().map(|s| s.as_str()).collect();
                    return Err(Error::Unsupported {
                        what: format!("TriggerSource {source}"),
                        message: format!("the camera's trigger sources are {}", names.join(", ")),
                    });
                }
                cam.set_trigger(source).map_err(|e| self.control_error("TriggerSource", e))?
            }
        }
        self.trigger = trigger;
        Ok(())
    }

    fn start(&mut self) -> Result<(), Error> {
        self.stop();
        let cam = self.camera()?;
        // A camera left acquiring by a client that died (killed, its heartbeat expired) still
        // streams to that client's port: stopping it first makes it take the new stream
        // channel (Aravis's fake camera re-reads it only on a fresh start; real cameras refuse
        // to change it while acquiring).
        cam.stop_acquisition().map_err(|e| self.control_error("AcquisitionStop", e))?;
        cam.set_acquisition_mode(aravis::AcquisitionMode::Continuous)
            .map_err(|e| self.control_error("AcquisitionMode", e))?;
        let stream = cam.create_stream().map_err(|e| self.control_error("stream", e))?;
        let payload = cam.payload().map_err(|e| self.control_error("PayloadSize", e))? as usize;
        for _ in 0..self.buffers {
            stream.push_buffer(aravis::Buffer::new_allocate(payload));
        }
        cam.start_acquisition().map_err(|e| self.control_error("AcquisitionStart", e))?;
        // A new acquisition: ids skipped while stopped are no dropped frames.
        self.ids.reset();
        self.stream = Some(stream);
        self.streaming = true;
        Ok(())
    }

    fn stop(&mut self) {
        if let (Some(cam), Some(_)) = (&self.camera, &self.stream) {
            let _ = cam.stop_acquisition();
        }
        self.stream = None;
        self.streaming = false;
    }

    /// Drops the connection, keeping what the stream should be doing: a reconnect that fails
    /// and one that follows must still restart a stream that ran.
    fn close(&mut self) {
        let streaming = self.streaming;
        self.stop();
        self.streaming = streaming;
        self.camera = None;
    }

    fn trigger_and_wait(&mut self, timeout: Duration) -> Result<Frame, Error> {
        // After a reconnect that failed the camera is closed: that is a disconnection (the
        // run reconnects and retries), not a stream someone forgot to start.
        self.camera()?;
        let stream = self.stream.as_ref().ok_or_else(|| Error::Other("the stream is not started".into()))?;
        while let Some(stale) = stream.try_pop_buffer() {
            stream.push_buffer(stale);
            self.stats.discarded += 1;
        }
        self.camera()?.software_trigger().map_err(|e| self.control_error("TriggerSoftware", e))?;
        self.pop(timeout)
    }

    fn pop(&mut self, timeout: Duration) -> Result<Frame, Error> {
        self.camera()?;
        let stream = self.stream.as_ref().ok_or_else(|| Error::Other("the stream is not started".into()))?;
        let Some(buffer) = stream.timeout_pop_buffer(timeout.as_micros() as u64) else {
            self.stats.timeouts += 1;
            if self.lost.load(Ordering::SeqCst) {
                return Err(self.disconnected("the control channel was lost"));
            }
            return Err(Error::Timeout { timeout_s: timeout.as_secs_f64() });
        };
        let status = buffer.status();
        let frame_id = buffer.frame_id();
        if status != BufferStatus::Success {
            stream.push_buffer(buffer);
            self.stats.failures += 1;
            return Err(Error::Incomplete { frame_id, status: format!("{status:?}") });
        }
        let (width, height) = (buffer.image_width().max(0) as u32, buffer.image_height().max(0) as u32);
        let code = buffer.image_pixel_format().raw();
        let data = buffer.image_data();
        let (timestamp_ns, system_timestamp_ns) = (buffer.timestamp(), buffer.system_timestamp());
        stream.push_buffer(buffer);
        let Some(pixel_format) = PixelFormat::from_code(code) else {
            self.stats.failures += 1;
            return Err(Error::Incomplete {
                frame_id,
                status: format!("pixel format {code:#010x} is not one btfrig reads"),
            });
        };
        if data.len() != pixel_format.image_bytes(width as usize, height as usize) {
            self.stats.failures += 1;
            return Err(Error::Incomplete {
                frame_id,
                status: format!("{} bytes for {width} x {height} {}", data.len(), pixel_format.name()),
            });
        }
        let (sequence, skipped) = self.ids.next(frame_id);
        self.stats.completed += 1;
        self.stats.skipped_ids += skipped;
        self.stats.bytes += data.len() as u64;
        let temperature_c = self.temperature().unwrap_or(None);
        Ok(Frame {
            width,
            height,
            pixel_format,
            data,
            sequence,
            frame_id,
            timestamp_ns,
            system_timestamp_ns,
            exposure_us: self.exposure_us.unwrap_or(f64::NAN),
            gain: self.gain.unwrap_or(f64::NAN),
            temperature_c,
        })
    }

    fn temperature(&self) -> Result<Option<f64>, Error> {
        if !self.has_temperature {
            return Ok(None);
        }
        let cam = self.camera()?;
        cam.float("DeviceTemperature").map(Some).map_err(|e| self.control_error("DeviceTemperature", e))
    }

    fn reconnect(&mut self) -> Result<CameraInfo, Error> {
        let was_streaming = self.streaming;
        self.close();
        let info = self.connect().inspect_err(|e| self.reconnect_failure = Some(e.to_string()))?;
        self.reconnect_failure = None;
        self.ids.reset();
        if let Some(f) = self.format {
            self.set_image_format(f)?;
        }
        if let Some(us) = self.exposure_us {
            self.set_exposure_us(us)?;
        }
        if let Some(g) = self.gain {
            self.set_gain(g)?;
        }
        if let Some(hz) = self.frame_rate {
            self.set_frame_rate(hz)?;
        }
        self.set_trigger(self.trigger.clone())?;
        if was_streaming {
            self.start()?;
        }
        self.stats.reconnects += 1;
        Ok(info)
    }
}
