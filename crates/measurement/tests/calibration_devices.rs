//! A calibration checks the devices it needs before moving anything: a camera that does not
//! answer stops a geometric calibration with an error naming its role and port, and no
//! capture is taken.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use btfrig_calibrate::CalibrationPlan;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_hw::{Camera, CameraCapabilities, CaptureSettings, Device, DeviceError, DeviceInfo, ErrorKind, Health};
use btfrig_measurement::backend::{
    BackendRegistry, CalibrationOpenRequest, GonioOpenRequest, OpenedGonio, OpenedRig, RigBackend, RigTime,
};
use btfrig_measurement::geometric_calibration::calibrate_geometry;
use btfrig_measurement::RunError;
use btfrig_sim_backend::SimBackend;

/// A camera unplugged from its port: it answers nothing, and counts what it was asked.
struct Unplugged {
    inner: Box<dyn Camera>,
    asked: Arc<AtomicUsize>,
}

#[async_trait::async_trait]
impl Device for Unplugged {
    fn info(&self) -> &DeviceInfo {
        self.inner.info()
    }
    async fn health(&mut self) -> Result<Health, DeviceError> {
        Err(DeviceError::new("camera", ErrorKind::Disconnected, "no answer"))
    }
}

#[async_trait::async_trait]
impl Camera for Unplugged {
    fn capabilities(&self) -> CameraCapabilities {
        self.inner.capabilities()
    }
    fn settings(&self) -> CaptureSettings {
        self.inner.settings()
    }
    async fn set_exposure_s(&mut self, _: f64) -> Result<(), DeviceError> {
        self.asked.fetch_add(1, Ordering::SeqCst);
        Err(DeviceError::new("camera", ErrorKind::Disconnected, "no answer"))
    }
    async fn set_gain(&mut self, _: f64) -> Result<(), DeviceError> {
        self.asked.fetch_add(1, Ordering::SeqCst);
        Err(DeviceError::new("camera", ErrorKind::Disconnected, "no answer"))
    }
    async fn trigger(&mut self, _: f64) -> Result<u64, DeviceError> {
        self.asked.fetch_add(1, Ordering::SeqCst);
        Err(DeviceError::new("camera", ErrorKind::Disconnected, "no answer"))
    }
    async fn read_frame(&mut self, _: f64) -> Result<RawFrame, DeviceError> {
        self.asked.fetch_add(1, Ordering::SeqCst);
        Err(DeviceError::new("camera", ErrorKind::Disconnected, "no answer"))
    }
}

/// The simulated rig with its camera unplugged (the rig config's `port` is this backend's
/// option; the simulated devices behind it do not know it).
struct UnpluggedCamera {
    asked: Arc<AtomicUsize>,
}

#[async_trait::async_trait]
impl RigBackend for UnpluggedCamera {
    fn name(&self) -> &'static str {
        "test rig with an unplugged camera"
    }
    fn kinds(&self) -> &'static [&'static str] {
        &["sim"]
    }
    async fn open_gonio(&self, _: GonioOpenRequest<'_>) -> Result<OpenedGonio, RunError> {
        Err(RunError::Rig("not for runs".into()))
    }
    async fn open_calibration(&self, req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
        let mut rig = req.rig.clone();
        rig.devices.camera.options.remove("port");
        let opened = SimBackend.open_calibration(CalibrationOpenRequest { rig: &rig, ..req }).await?;
        let OpenedRig::Gonio(mut g) = opened else { unreachable!("a gonio") };
        g.camera = Box::new(Unplugged { inner: g.camera, asked: self.asked.clone() });
        Ok(OpenedRig::Gonio(g))
    }
}

#[test]
fn an_unplugged_camera_is_named_with_its_port_before_anything_is_captured() {
    let mut rig =
        RigConfig::from_toml(include_str!("../../../rig-configs/bonn-gonio-sim.toml"), "bonn-gonio-sim").unwrap();
    rig.devices.camera.options.insert("port".into(), toml::Value::String("/dev/ttyUSB3".into()));
    let asked = Arc::new(AtomicUsize::new(0));
    let registry = BackendRegistry::new().with(Arc::new(UnpluggedCamera { asked: asked.clone() }));
    let plan = CalibrationPlan::default_plan();
    let e = calibrate_geometry(&rig, Some(&registry), &plan, 1, RigTime::Virtual, |_| {}).unwrap_err().to_string();
    assert!(e.contains("device camera") && e.contains("/dev/ttyUSB3") && e.contains("does not answer"), "{e}");
    assert_eq!(asked.load(Ordering::SeqCst), 0, "the camera was asked to capture: {e}");
}
