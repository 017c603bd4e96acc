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
    /// A dome's or camera array's cameras: one IP address per camera position of `[dome]`
    /// (a dome's arc positions, a camera array's cameras, in the rig config's order).
    pub addresses: Option<Vec<String>>,
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
    /// checks it, so that it never streams from another camera on the same address. On a dome
    /// or camera array each position's fake camera has this serial followed by its position.
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
        if cfg.addresses.is_none() {
            cfg.target()?;
        }
        cfg.format()?;
        cfg.gain()?;
        if cfg.emulated {
            if cfg.addresses.is_none() && !matches!(cfg.target()?, Target::Address(a) if a.is_loopback()) {
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

    /// How a gonioreflectometer's one camera is reached.
    pub fn target(&self) -> Result<Target, String> {
        match (&self.address, &self.id, &self.addresses) {
            (Some(a), None, None) => parse_address(a, "devices.camera.link.address"),
            (None, Some(id), None) if id.starts_with("Fake_") => Ok(Target::Id(id.clone())),
            (None, Some(id), None) => Err(format!(
                "devices.camera.link.id = {id:?}: opening by id broadcasts a discovery on every network interface; \
                 allowed: address = \"IP\" (find it with `btfrig hw probe --discover`), or an Aravis Fake_ id"
            )),
            (None, None, Some(_)) => Err(
                "devices.camera.link.addresses is for a dome's or camera array's cameras; a gonioreflectometer's one camera has address = \"IP\"".into()
            ),
            _ => Err("devices.camera.link: give exactly one of address (an IPv4 address) or id".into()),
        }
    }

    /// The cameras of a dome or camera array with `positions` camera positions: one site per
    /// position, checked (one address each, all distinct; loopback and a serial that fits when
    /// emulated).
    pub fn sites(&self, positions: usize) -> Result<Vec<CameraSite>, String> {
        let addresses = match (&self.address, &self.id, &self.addresses) {
            (None, None, Some(a)) => a,
            _ => {
                return Err(format!(
                    "devices.camera.link: a dome's or camera array's {positions} cameras need addresses = [\"IP\", ...], \
                     one per camera position of [dome] in order (address and id name a gonioreflectometer's one camera)"
                ))
            }
        };
        if addresses.len() != positions {
            return Err(format!(
                "devices.camera.link.addresses has {} entries; the rig's [dome] has {positions} camera positions, one address each",
                addresses.len()
            ));
        }
        let mut sites = Vec::with_capacity(positions);
        for (position, a) in addresses.iter().enumerate() {
            let target = parse_address(a, &format!("devices.camera.link.addresses[{position}]"))?;
            if let Some(earlier) = sites.iter().position(|s: &CameraSite| s.target == target) {
                return Err(format!(
                    "devices.camera.link.addresses[{position}] = {a:?} is also camera position {earlier}'s: each camera has its own address"
                ));
            }
            let serial = self.serial.as_ref().map(|s| format!("{s}{position}"));
            if self.emulated {
                if !matches!(target, Target::Address(a) if a.is_loopback()) {
                    return Err(format!(
                        "devices.camera.link.addresses[{position}] = {a:?}: emulated cameras are served on loopback addresses; allowed: 127.x.y.z"
                    ));
                }
                if let Some(s) = &serial {
                    if s.len() > 15 {
                        return Err(format!(
                            "devices.camera.link.serial = {:?}: with the position appended ({s:?}) it exceeds the 15 characters a GigE Vision serial holds",
                            self.serial.as_deref().unwrap_or_default()
                        ));
                    }
                }
            }
            sites.push(CameraSite { position, target, serial });
        }
        Ok(sites)
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

/// One GenICam camera of a rig: where it is, and the fed fake camera's serial when emulated.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraSite {
    /// Its camera position on a dome or camera array (0 on a gonioreflectometer).
    pub position: usize,
    /// How it is reached.
    pub target: Target,
    /// The fed fake camera's serial number (emulated cameras).
    pub serial: Option<String>,
}

fn parse_address(a: &str, key: &str) -> Result<Target, String> {
    a.parse::<Ipv4Addr>()
        .map(Target::Address)
        .map_err(|_| format!("{key} = {a:?} is not an IPv4 address; allowed: e.g. \"192.168.1.20\""))
}

/// The rig's GenICam cameras: a gonioreflectometer's one camera, or one per camera position of
/// a dome or camera array.
pub(crate) fn rig_sites(rig: &RigConfig, cfg: &CameraConfig) -> Result<Vec<CameraSite>, String> {
    match &rig.dome {
        Some(dome) => cfg.sites(dome.camera_count()),
        None => Ok(vec![CameraSite { position: 0, target: cfg.target()?, serial: cfg.serial.clone() }]),
    }
}

/// The rig with its GenICam camera replaced by the simulated twin, and the camera's keys
/// (checked against the rig: one address per camera position on a dome).
pub(crate) fn inner_rig(rig: &RigConfig) -> Result<(RigConfig, CameraConfig), String> {
    if rig.devices.camera.kind != "genicam" {
        return Err(format!(
            "devices.camera.kind = {:?}: the GenICam backend opens kind = \"genicam\"",
            rig.devices.camera.kind
        ));
    }
    let (cfg, sim) = CameraConfig::split(&rig.devices.camera)?;
    rig_sites(rig, &cfg)?;
    let mut inner = rig.clone();
    inner.devices.camera = sim;
    Ok((inner, cfg))
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::plan::BUILTIN_RIGS;

    fn rig(name: &str, link: &str) -> RigConfig {
        let (_, text) = BUILTIN_RIGS.iter().find(|(n, _)| *n == name).unwrap();
        let text = text.replace(
            "[devices.camera]\nkind = \"sim\"",
            &format!("[devices.camera]\nkind = \"genicam\"\nlink = {{ pixel_format = \"BayerRG16\", {link} }}"),
        );
        RigConfig::from_toml(&text, name).unwrap()
    }

    fn addresses(n: usize, first: u8) -> String {
        let a: Vec<String> = (0..n).map(|i| format!("\"127.0.1.{}\"", first as usize + i)).collect();
        format!("addresses = [{}]", a.join(", "))
    }

    fn checked(rig: &RigConfig) -> Result<Vec<CameraSite>, String> {
        inner_rig(rig).and_then(|(_, cfg)| rig_sites(rig, &cfg))
    }

    #[test]
    fn a_dome_has_one_address_per_camera_position_and_emulated_serials_name_the_position() {
        // The LED dome has 11 arc positions.
        let sites = checked(&rig(
            "builtin:bonn-dome-sim",
            &format!("emulated = true, serial = \"DOME\", {}", addresses(11, 1)),
        ))
        .unwrap();
        assert_eq!(sites.len(), 11);
        assert_eq!(sites[6].target, Target::Address("127.0.1.7".parse().unwrap()));
        assert_eq!((sites[6].position, sites[6].serial.as_deref()), (6, Some("DOME6")));
        // A real camera array: no serials.
        let sites =
            checked(&rig("builtin:bonn-camera-array-sim", &addresses(151, 1).replace("127.0.1.", "10.0.0."))).unwrap();
        assert_eq!((sites.len(), sites[150].serial.clone()), (151, None));
    }

    #[test]
    fn wrong_camera_addresses_are_named() {
        let dome = "builtin:bonn-dome-sim";
        let e = checked(&rig(dome, &addresses(10, 1))).unwrap_err();
        assert!(e.contains("has 10 entries") && e.contains("11 camera positions"), "{e}");
        let e = checked(&rig(dome, "address = \"127.0.0.1\"")).unwrap_err();
        assert!(e.contains("addresses = [") && e.contains("one per camera position"), "{e}");
        let e = checked(&rig(dome, &addresses(11, 1).replace("127.0.1.5", "127.0.1.2"))).unwrap_err();
        assert!(e.contains("addresses[4] = \"127.0.1.2\" is also camera position 1's"), "{e}");
        let e = checked(&rig(dome, &addresses(11, 1).replace("127.0.1.3", "camera-3"))).unwrap_err();
        assert!(e.contains("addresses[2] = \"camera-3\" is not an IPv4 address"), "{e}");
        let e = checked(&rig(
            dome,
            &format!("emulated = true, serial = \"S\", {}", addresses(11, 1).replace("127.0.1.4", "10.0.0.4")),
        ))
        .unwrap_err();
        assert!(e.contains("addresses[3] = \"10.0.0.4\": emulated cameras are served on loopback"), "{e}");
        let e = checked(&rig(dome, &format!("emulated = true, serial = \"FOURTEEN-CHARS\", {}", addresses(11, 1))))
            .unwrap_err();
        assert!(e.contains("\"FOURTEEN-CHARS10\"") && e.contains("15 characters"), "{e}");
        let e = checked(&rig("builtin:bonn-gonio-sim", &addresses(1, 1))).unwrap_err();
        assert!(e.contains("a gonioreflectometer's one camera has address"), "{e}");
    }
}
