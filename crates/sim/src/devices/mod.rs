//! The simulated devices. Each holds a [`crate::faults::FaultGate`] through which every
//! call passes, and the shared [`crate::SimWorld`] into which it writes the true state.

mod axis;
mod camera;
mod lamp;
mod leds;
pub(crate) mod motion;
mod robot;

pub use axis::SimAxis;
pub use camera::SimCamera;
pub use lamp::SimLamp;
pub use leds::SimLedArray;
pub use robot::SimRobot;

use btfrig_hw::DeviceInfo;

pub(crate) fn info(name: &str, model: &str) -> DeviceInfo {
    DeviceInfo {
        name: name.to_string(),
        backend: "sim".to_string(),
        model: model.to_string(),
        serial: None,
        firmware: Some(concat!("btfrig-sim ", env!("CARGO_PKG_VERSION")).to_string()),
    }
}
