//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::Arc;

use btfrig_core::config::devices::DevicesConfig;
use btfrig_core::config::timing::TimingConfig;
use btfrig_hw::{DeviceError, ErrorKind, TokioClock};
use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig};

pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

pub fn scenario(name: &str) -> FaultScenario {
    let path = repo_root().join("sim/faults").join(format!("{name}.toml"));
    let text = std::fs::read_to_string(&path).unwrap();
    FaultScenario::from_toml(&text, &path.display().to_string()).unwrap()
}

pub fn source() -> Arc<FlatFrameSource> {
    Arc::new(FlatFrameSource::new(16, 12, 1000.0))
}

/// Devices all homed at start (so tests can move at once); each table in `extra` (TOML)
/// replaces the default one of its device.
pub fn devices(extra: &str) -> DevicesConfig {
    let mut t: toml::Table = toml::from_str(
        "[robot]\nkind = \"sim\"\nhomed_at_start = true\n[rail]\nkind = \"sim\"\nhomed_at_start = true\n",
    )
    .unwrap();
    let extra: toml::Table = toml::from_str(extra).unwrap();
    t.extend(extra);
    t.try_into().unwrap()
}

/// Must be called inside the (paused) runtime.
pub fn rig(devices: &DevicesConfig, seed: u64, faults: &FaultScenario) -> SimRig {
    SimRig::build(devices, &TimingConfig::bonn(), seed, faults, TokioClock::shared(), source()).unwrap()
}

/// Retries an operation while its error is retryable, like a run engine would; returns the
/// result and the number of failed attempts.
#[macro_export]
macro_rules! retry {
    ($max:expr, $op:expr) => {{
        let mut failures = 0u32;
        loop {
            match $op.await {
                Ok(v) => break Ok((v, failures)),
                Err(e) if e.is_retryable() && failures < $max => failures += 1,
                Err(e) => break Err(e),
            }
        }
    }};
}

pub fn assert_kind(e: &DeviceError, kind: ErrorKind, retryable: bool) {
    assert_eq!(e.kind(), kind, "{e}");
    assert_eq!(e.is_retryable(), retryable, "{e}");
}
