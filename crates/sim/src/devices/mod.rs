//! The simulated devices. Each holds a [`crate::faults::FaultGate`] through which every
//! call passes, and the shared [`crate::SimWorld`] into which it writes the true state.

/// The `Device` part every simulated device shares: its info, a health check and a
/// reconnect that pass through the fault gate (so injected disconnects and timeouts hit
/// them too). The type needs fields `info: DeviceInfo` and `gate: FaultGate`.
macro_rules! impl_sim_device {
    ($device:ty) => {
        #[async_trait::async_trait]
        impl btfrig_hw::Device for $device {
            fn info(&self) -> &btfrig_hw::DeviceInfo {
                &self.info
            }

            async fn health(&mut self) -> Result<btfrig_hw::Health, btfrig_hw::DeviceError> {
                self.gate.begin("health", COMMAND_TIMEOUT_S).await?;
                Ok(btfrig_hw::Health::Ok)
            }

            async fn reconnect(&mut self) -> Result<(), btfrig_hw::DeviceError> {
                self.gate.begin("reconnect", COMMAND_TIMEOUT_S).await.map(|_| ())
            }
        }
    };
}

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
