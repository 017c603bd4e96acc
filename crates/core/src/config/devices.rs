//! The `[devices]` section of a rig config: which backend drives each device.
//!
//! Each device is a table with a `kind` naming its backend (`"sim"` is the only one so far)
//! and that backend's own options:
//!
//! ```toml
//! [devices.robot]
//! kind = "sim"
//! jitter_deg = [0.05, 0.05, 0.05]
//! ```
//!
//! The options are kept as a TOML table here and parsed (with unknown fields denied) by the
//! backend that the `kind` selects, so a new backend needs no change in this crate; the
//! backends' factory lists check the kinds and options (see `docs/devices.md`).

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// One device: its backend kind plus the backend's options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceEntry {
    /// Backend that drives the device, e.g. `"sim"`.
    pub kind: String,
    /// Every other key of the table: the backend's options.
    #[serde(flatten)]
    pub options: toml::Table,
}

impl DeviceEntry {
    /// A simulated device with default options.
    pub fn sim() -> Self {
        DeviceEntry { kind: "sim".into(), options: toml::Table::new() }
    }

    /// Whether this is a real backend talking to emulated firmware in front of a simulated
    /// device: a `[devices.<role>.link]` table with `emulated = true`. The entry's other
    /// options are then the simulated device's (`kind = "sim"` options), the `link` table the
    /// backend's (docs/serial.md).
    pub fn is_emulated(&self) -> bool {
        self.kind != "sim"
            && self.options.get("link").and_then(|l| l.get("emulated")).and_then(|e| e.as_bool()) == Some(true)
    }

    /// The simulated device of this entry: itself if simulated, the simulated device behind
    /// the emulated firmware if emulated (`kind = "sim"`, the `link` table removed); `None`
    /// for a real device.
    pub fn simulated(&self) -> Option<DeviceEntry> {
        if self.kind == "sim" {
            return Some(self.clone());
        }
        self.is_emulated().then(|| {
            let mut options = self.options.clone();
            options.remove("link");
            DeviceEntry { kind: "sim".into(), options }
        })
    }
}

/// The `[devices]` section. Robot, rail, lamp and camera default to simulated devices;
/// turntable and LED array are absent unless given.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DevicesConfig {
    /// The robot orienting the sample.
    #[serde(default = "DeviceEntry::sim")]
    pub robot: DeviceEntry,
    /// The camera rail.
    #[serde(default = "DeviceEntry::sim")]
    pub rail: DeviceEntry,
    /// The turntable, if the rig has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub turntable: Option<DeviceEntry>,
    /// The lamp.
    #[serde(default = "DeviceEntry::sim")]
    pub lamp: DeviceEntry,
    /// The LED array, if the rig has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub led_array: Option<DeviceEntry>,
    /// The camera.
    #[serde(default = "DeviceEntry::sim")]
    pub camera: DeviceEntry,
}

impl Default for DevicesConfig {
    fn default() -> Self {
        DevicesConfig {
            robot: DeviceEntry::sim(),
            rail: DeviceEntry::sim(),
            turntable: None,
            lamp: DeviceEntry::sim(),
            led_array: None,
            camera: DeviceEntry::sim(),
        }
    }
}

impl DevicesConfig {
    /// Whether any device is emulated ([`DeviceEntry::is_emulated`]).
    pub fn any_emulated(&self) -> bool {
        self.entries().iter().any(|(_, e)| e.is_emulated())
    }

    /// The all-simulated rig underneath: every emulated device replaced by its simulated
    /// device ([`DeviceEntry::simulated`]); `None` if a device is real.
    pub fn simulated(&self) -> Option<DevicesConfig> {
        Some(DevicesConfig {
            robot: self.robot.simulated()?,
            rail: self.rail.simulated()?,
            turntable: match &self.turntable {
                Some(t) => Some(t.simulated()?),
                None => None,
            },
            lamp: self.lamp.simulated()?,
            led_array: match &self.led_array {
                Some(l) => Some(l.simulated()?),
                None => None,
            },
            camera: self.camera.simulated()?,
        })
    }

    /// Every present device as (role name, entry), in a fixed order.
    pub fn entries(&self) -> Vec<(&'static str, &DeviceEntry)> {
        let mut v = vec![("robot", &self.robot), ("rail", &self.rail)];
        if let Some(t) = &self.turntable {
            v.push(("turntable", t));
        }
        v.push(("lamp", &self.lamp));
        if let Some(l) = &self.led_array {
            v.push(("led_array", l));
        }
        v.push(("camera", &self.camera));
        v
    }

    /// Appends every malformed value of this section to `errors`. Only the shape is checked
    /// here (a kind is a non-empty lower-case name); whether the kind exists and its
    /// options are valid is checked by the backend registry that builds the devices.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        for (role, e) in self.entries() {
            let ok = !e.kind.is_empty()
                && e.kind.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_' || c == '-');
            if !ok {
                errors.push(ConfigError::out_of_range(
                    &format!("devices.{role}.kind"),
                    format!("{:?}", e.kind),
                    "a non-empty name of lower-case letters, digits, '_' or '-'",
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kind_and_options_are_split() {
        let text = "[robot]\nkind = \"sim\"\njitter_deg = [0.1, 0.2, 0.3]\n[led_array]\nkind = \"sim\"\ncount = 8\n";
        let cfg: DevicesConfig = toml::from_str(text).unwrap();
        assert_eq!(cfg.robot.kind, "sim");
        assert_eq!(cfg.robot.options.len(), 1);
        assert!(cfg.robot.options.contains_key("jitter_deg"));
        assert_eq!(cfg.rail, DeviceEntry::sim());
        assert!(cfg.turntable.is_none());
        assert_eq!(cfg.led_array.as_ref().unwrap().options["count"].as_integer(), Some(8));
        let roles: Vec<_> = cfg.entries().iter().map(|(r, _)| *r).collect();
        assert_eq!(roles, ["robot", "rail", "lamp", "led_array", "camera"]);
    }

    #[test]
    fn unknown_device_role_and_bad_kind_are_rejected() {
        assert!(toml::from_str::<DevicesConfig>("[robto]\nkind = \"sim\"").unwrap_err().to_string().contains("robto"));
        let cfg: DevicesConfig = toml::from_str("[rail]\nkind = \"\"\n[lamp]\nkind = \"Sim\"").unwrap();
        let mut errors = Vec::new();
        cfg.validate(&mut errors);
        assert_eq!(errors.len(), 2, "{errors:?}");
        assert!(errors[0].to_string().starts_with("devices.rail.kind = \"\""), "{}", errors[0]);
        assert!(errors[1].to_string().starts_with("devices.lamp.kind = \"Sim\""), "{}", errors[1]);
    }
}
