//! The device backends this binary opens rigs with (`btfrig_measurement::backend`): the
//! simulated and emulated-firmware ones always; GenICam cameras with the `genicam` feature,
//! and without it a stand-in that refuses `kind = "genicam"` saying how to build with it.

use std::sync::Arc;

use btfrig_core::config::RigConfig;
use btfrig_measurement::backend::RigBackend;
#[cfg(not(feature = "genicam"))]
use btfrig_measurement::{
    backend::{GonioOpenRequest, OpenedGonio},
    RunError,
};

/// Installs the process's backends.
pub fn install() {
    let sim = btfrig_sim_backend::registry();
    #[cfg(feature = "genicam")]
    let genicam: Arc<dyn RigBackend> = Arc::new(btfrig_genicam_backend::GenicamBackend::new(sim.clone()));
    #[cfg(not(feature = "genicam"))]
    let genicam: Arc<dyn RigBackend> = Arc::new(NoGenicam);
    btfrig_measurement::backend::install(sim.with(genicam));
}

/// What a binary without the `genicam` feature says when asked for a GenICam camera.
pub const WITHOUT_GENICAM: &str = "this btfrig was built without GenICam support (devices.camera.kind = \"genicam\"): \
    install Aravis with tests/install-deps.sh (libaravis-dev, libusb-1.0-0-dev) and build with \
    `cargo build --release -p btfrig-cli --features genicam`";

/// The stand-in for the GenICam backend in a build without it.
#[cfg(not(feature = "genicam"))]
struct NoGenicam;

#[cfg(not(feature = "genicam"))]
#[async_trait::async_trait]
impl RigBackend for NoGenicam {
    fn name(&self) -> &'static str {
        "GenICam camera (not in this build)"
    }

    fn kinds(&self) -> &'static [&'static str] {
        &["genicam", "sim", "serial", "ptp"]
    }

    async fn open_gonio(&self, _req: GonioOpenRequest<'_>) -> Result<OpenedGonio, RunError> {
        Err(RunError::Rig(WITHOUT_GENICAM.into()))
    }

    fn check_rig(&self, _rig: &RigConfig) -> Result<(), String> {
        Err(WITHOUT_GENICAM.into())
    }
}

/// Fails with [`WITHOUT_GENICAM`] if `rig` has a GenICam device and this build has no GenICam.
pub fn check_genicam(rig: &RigConfig) -> anyhow::Result<()> {
    let genicam = rig.devices.entries().iter().any(|(_, e)| e.kind == "genicam");
    anyhow::ensure!(!genicam || cfg!(feature = "genicam"), "{WITHOUT_GENICAM}");
    Ok(())
}
