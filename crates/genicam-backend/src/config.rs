//! The `link` keys of a `kind = "genicam"` camera and the rig seen without it.

use std::net::Ipv4Addr;

use btfrig_core::config::devices::DeviceEntry;
use btfrig_core::config::RigConfig;
use btfrig_genicam::{GainUnit, PixelFormat};
use serde::Deserialize;

use crate::Target;

/// `[devices.camera] link = { ... }` of a `kind = "genicam"` camera: the GenICam backend's
/// keys, as a serial device's `link` holds its port (docs/serial.md). The entry's other keys
/// are the camera options every backend shares (exposure and gain ranges, initial settings),
/// and with `emulated = true` they are those of the simulated camera behind the fake camera.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// The camera's IP address (GigE Vision; no discovery broadcast).
    pub address: Option<String>,
    /// Or its device id as Aravis lists it; opening by id broadcasts a discovery, so only
    /// Aravis's in-process `Fake_*` ids are accepted in a rig config.
    pub id: Option<String>,
    /// The pixel format on the wire (PFNC name: `BayerRG12`, `Mono16`, ...).
    pub pixel_format: String,
    /// The unit of the camera's `Gain` feature: `"db"` (SFNC, default) or `"linear"`.
    #[serde(default = "CameraConfig::default_gain_unit")]
    pub gain_unit: String,
    /// Serve Aravis's GigE Vision fake camera at `address` (loopback) from this process, fed
    /// with the simulated camera's frames.
    #[serde(default)]
    pub emulated: bool,
    /// The fake camera's serial number (1..15 ASCII characters; with `emulated`); the client
    /// checks it, so that it never streams from another camera on the same address.
    pub serial: Option<String>,
}

impl CameraConfig {
    fn default_gain_unit() -> String {
        "db".into()
    }

    /// Splits a `kind = "genicam"` entry into its `link` keys and the simulated twin's entry
    /// (the other keys), checking every value.
    pub fn split(entry: &DeviceEntry) -> Result<(CameraConfig, DeviceEntry), String> {
        let mut sim = entry.options.clone();
        let link = sim
            .remove("link")
            .and_then(|l| l.as_table().cloned())
            .ok_or("devices.camera.link: a GenICam camera needs a link table, e.g. link = { address = \"192.168.1.20\", pixel_format = \"BayerRG12\" }")?;
        let cfg: CameraConfig =
            link.try_into().map_err(|e: toml::de::Error| format!("devices.camera.link: {}", e.message()))?;
        cfg.target()?;
        cfg.format()?;
        cfg.gain()?;
        if cfg.emulated {
            if !matches!(cfg.target()?, Target::Address(a) if a.is_loopback()) {
                return Err("devices.camera.link.emulated: the fed fake camera is served on a loopback address; allowed: address = \"127.0.0.1\"".into());
            }
            match &cfg.serial {
                Some(s) if !s.is_empty() && s.len() <= 15 && s.is_ascii() => {}
                other => {
                    return Err(format!(
                        "devices.camera.link.serial = {other:?}: an emulated camera needs 1 to 15 ASCII characters"
                    ))
                }
            }
        } else if cfg.serial.is_some() {
            return Err(
                "devices.camera.link.serial: only with emulated = true (the fake camera's serial number)".into()
            );
        }
        Ok((cfg, DeviceEntry { kind: "sim".into(), options: sim }))
    }

    /// How the camera is reached.
    pub fn target(&self) -> Result<Target, String> {
        match (&self.address, &self.id) {
            (Some(a), None) => a.parse::<Ipv4Addr>().map(Target::Address).map_err(|_| {
                format!("devices.camera.link.address = {a:?} is not an IPv4 address; allowed: e.g. \"192.168.1.20\"")
            }),
            (None, Some(id)) if id.starts_with("Fake_") => Ok(Target::Id(id.clone())),
            (None, Some(id)) => Err(format!(
                "devices.camera.link.id = {id:?}: opening by id broadcasts a discovery on every network interface; \
                 allowed: address = \"IP\" (find it with `btfrig hw probe --discover`), or an Aravis Fake_ id"
            )),
            _ => Err("devices.camera.link: give exactly one of address (an IPv4 address) or id".into()),
        }
    }

    /// The pixel format.
    pub fn format(&self) -> Result<PixelFormat, String> {
        PixelFormat::from_name(&self.pixel_format).ok_or_else(|| {
            format!(
                "devices.camera.link.pixel_format = {:?} is not read by btfrig; allowed: {}",
                self.pixel_format,
                PixelFormat::names().join(", ")
            )
        })
    }

    pub(crate) fn gain(&self) -> Result<GainUnit, String> {
        match self.gain_unit.as_str() {
            "db" => Ok(GainUnit::Decibel),
            "linear" => Ok(GainUnit::Linear),
            other => Err(format!("devices.camera.link.gain_unit = {other:?}; allowed: \"db\", \"linear\"")),
        }
    }
}

/// The rig with its GenICam camera replaced by the simulated twin, and the camera's keys.
pub(crate) fn inner_rig(rig: &RigConfig) -> Result<(RigConfig, CameraConfig), String> {
    if rig.devices.camera.kind != "genicam" {
        return Err(format!(
            "devices.camera.kind = {:?}: the GenICam backend opens kind = \"genicam\"",
            rig.devices.camera.kind
        ));
    }
    let (cfg, sim) = CameraConfig::split(&rig.devices.camera)?;
    let mut inner = rig.clone();
    inner.devices.camera = sim;
    Ok((inner, cfg))
}
