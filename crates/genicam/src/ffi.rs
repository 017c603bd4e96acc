//! The crate's only unsafe code: what the safe `aravis` crate does not offer. Each block says
//! why it is sound.
//!
//! - [`enable_interface`] / [`disable_interface`]: switch Aravis's device interfaces (the
//!   in-process "Fake" one; the GigE Vision one, whose discovery broadcasts).
//! - [`discover`]: Aravis's device list, which broadcasts on every network interface.
//! - [`FillHook`]: the fake camera's fill-pattern hook, which puts our pixels into its frames.

use std::ffi::{c_void, CStr, CString};
use std::sync::{Arc, Mutex};

use aravis::glib::translate::ToGlibPtr;

use crate::fake::Feed;

/// Aravis keeps its device list in process-global state; every use here goes through this lock.
static DEVICE_LIST: Mutex<()> = Mutex::new(());

/// Enables one of Aravis's interfaces by its id ("Fake", "GigEVision", "USB3Vision").
pub(crate) fn enable_interface(id: &str) {
    let id = CString::new(id).expect("interface ids have no NUL");
    let _guard = DEVICE_LIST.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: `id` is a valid NUL-terminated string that outlives the call (Aravis copies
    // what it needs); the call touches Aravis's global interface table, which every caller in
    // this crate reaches only under DEVICE_LIST.
    unsafe { aravis_sys::arv_enable_interface(id.as_ptr()) }
}

/// Disables one of Aravis's interfaces (see [`enable_interface`]).
pub(crate) fn disable_interface(id: &str) {
    let id = CString::new(id).expect("interface ids have no NUL");
    let _guard = DEVICE_LIST.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: as in `enable_interface`.
    unsafe { aravis_sys::arv_disable_interface(id.as_ptr()) }
}

/// A device Aravis's discovery found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Discovered {
    /// Device id (opens it: `Camera::new(id)`).
    pub id: String,
    /// Vendor.
    pub vendor: String,
    /// Model.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Protocol: "GigEVision", "USB3Vision", "Fake".
    pub protocol: String,
    /// Address (IP address for GigE Vision).
    pub address: String,
}

/// Every device on every enabled interface. BROADCASTS a GigE Vision discovery on every
/// network interface: callers ask the user first (`--discover`).
pub(crate) fn discover() -> Vec<Discovered> {
    let _guard = DEVICE_LIST.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: `aravis::get_device_list` is unsafe only because it uses Aravis's global device
    // list without mutual exclusion; DEVICE_LIST provides it for every caller in this process
    // that goes through this crate.
    let list = unsafe { aravis::get_device_list() };
    let s = |c: &CStr| c.to_string_lossy().into_owned();
    list.iter()
        .map(|d| Discovered {
            id: s(&d.id),
            vendor: s(&d.vendor),
            model: s(&d.model),
            serial: s(&d.physical_id),
            protocol: s(&d.protocol),
            address: s(&d.address),
        })
        .collect()
}

/// Our pixels in a fake camera's frames, for as long as this value lives.
///
/// Installs an `extern "C"` fill-pattern callback with a pointer to a [`Feed`] as its user
/// data; on drop it restores Aravis's own pattern and only then releases the `Feed`.
pub(crate) struct FillHook {
    camera: aravis::FakeCamera,
    feed: *const Feed,
}

// SAFETY: the raw pointer is an `Arc<Feed>` turned into a pointer; `Feed` is Send + Sync (a
// Mutex and atomics), and `aravis::FakeCamera` is Send. FillHook is never shared (not Sync).
unsafe impl Send for FillHook {}

impl FillHook {
    /// Installs the hook on `camera`; the camera's frames come from `feed` from now on.
    pub(crate) fn install(camera: aravis::FakeCamera, feed: Arc<Feed>) -> FillHook {
        let data = Arc::into_raw(feed);
        // SAFETY: `fill` matches ArvFakeCameraFillPattern's C signature. `data` points to a
        // live `Feed` (the strong count Arc::into_raw leaked) until `Drop` below, which first
        // replaces the callback under the fake camera's fill-pattern mutex (Aravis takes it
        // both here and around each callback call, arvfakecamera.c), so no call can use `data`
        // after it is released.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(camera.to_glib_none().0, Some(fill), data as *mut c_void);
        }
        FillHook { camera, feed: data }
    }
}

impl Drop for FillHook {
    fn drop(&mut self) {
        // SAFETY: a NULL callback makes Aravis restore its own pattern (and NULL user data),
        // under the fill-pattern mutex: once this returns, no callback holds `self.feed`.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(self.camera.to_glib_none().0, None, std::ptr::null_mut());
        }
        // SAFETY: `self.feed` came from Arc::into_raw in `install` and is released exactly once.
        drop(unsafe { Arc::from_raw(self.feed) });
    }
}

/// The fill-pattern callback: copies the [`Feed`]'s next frame into the buffer when it has the
/// buffer's width, height and pixel format; otherwise leaves the buffer as it is and counts a
/// miss. Never unwinds into C.
unsafe extern "C" fn fill(
    buffer: *mut aravis_sys::ArvBuffer,
    data: *mut c_void,
    _exposure_time_us: u32,
    _gain: u32,
    pixel_format: aravis_sys::ArvPixelFormat,
) {
    if buffer.is_null() || data.is_null() {
        return;
    }
    // SAFETY: `data` is the `Feed` FillHook::install registered, alive while the hook is
    // installed (see FillHook). `buffer` is the live ArvBuffer Aravis passes; width and height
    // are plain getters on it.
    let (feed, width, height, target) = unsafe {
        let mut size = 0usize;
        let target = aravis_sys::arv_buffer_get_data(buffer, &mut size);
        (
            &*(data as *const Feed),
            aravis_sys::arv_buffer_get_image_width(buffer),
            aravis_sys::arv_buffer_get_image_height(buffer),
            target,
        )
    };
    if target.is_null() || width <= 0 || height <= 0 {
        return;
    }
    // Bytes of the frame Aravis is about to send: width x height x (PFNC bits 16..24) / 8.
    let bytes = width as usize * height as usize * ((pixel_format >> 16) & 0xff) as usize / 8;
    let copied = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        feed.take_matching(width as u32, height as u32, pixel_format, bytes, |pixels| {
            // SAFETY: arv_fake_camera_fill_buffer calls this hook only after checking that the
            // buffer's allocated size is at least the payload of the current Width, Height and
            // PixelFormat registers, the values the buffer's image width, height and
            // `pixel_format` were just set from; `pixels` has exactly that payload's length
            // (take_matching checks), and our Vec cannot overlap Aravis's buffer.
            unsafe { std::ptr::copy_nonoverlapping(pixels.as_ptr(), target, pixels.len()) }
        })
    }));
    if copied.is_err() {
        feed.count_miss();
    }
}
