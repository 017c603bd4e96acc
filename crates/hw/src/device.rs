//! What every device has in common: a name, identity, health and reconnection.

use async_trait::async_trait;

use crate::DeviceError;

/// Who a device is. Filled in by the backend when it is built (and refreshed on connect).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    /// The device's name in the rig config, e.g. `robot`; every error message starts with it.
    pub name: String,
    /// The backend kind from the rig config, e.g. `sim`.
    pub backend: String,
    /// Make and model, as the device reports it or the backend knows it.
    pub model: String,
    /// Serial number, if the device reports one.
    pub serial: Option<String>,
    /// Firmware version, if the device reports one.
    pub firmware: Option<String>,
}

/// How a device feels, beyond whether its last call succeeded.
#[derive(Debug, Clone, PartialEq)]
pub enum Health {
    /// Working normally.
    Ok,
    /// Working, but something needs attention (warming up, temperature high).
    Warning(String),
    /// Not able to work until something is done (e.g. an emergency stop is pressed).
    Fault(String),
}

/// The part shared by all device traits: a small required core (`info`) and provided
/// defaults for what not every device can report.
#[async_trait]
pub trait Device: Send + Sync {
    /// Identity of the device; cheap, no I/O.
    fn info(&self) -> &DeviceInfo;

    /// The device's name in the rig config (used in error messages).
    fn name(&self) -> &str {
        &self.info().name
    }

    /// Health as the device reports it. Default: [`Health::Ok`].
    async fn health(&mut self) -> Result<Health, DeviceError> {
        Ok(Health::Ok)
    }

    /// Internal temperature, degrees Celsius, or `None` when the device has no sensor.
    async fn temperature_c(&mut self) -> Result<Option<f64>, DeviceError> {
        Ok(None)
    }

    /// Re-establishes the link after [`crate::ErrorKind::Disconnected`]. Default: nothing to do.
    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }
}
