//! The `[lamp]` section of a rig config: the light source's spectrum and power.
//!
//! Radiometry (see `docs/sensor-model.md`): the lamp is a point source; `irradiance_at_1m_w_m2`
//! is the irradiance, in W/m² integrated over 380–780 nm, on a surface facing the lamp at 1 m.
//! At distance `d` metres it is `irradiance_at_1m_w_m2 / d²`, distributed over wavelength by the
//! named relative spectrum. The default, 50 W/m² (about 15 klx of metal-halide light), is of
//! the order of a 575 W HMI spotlight at 1 m, so a white sample at ~2 m fills the default
//! sensor's wells in about 10 ms.

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// Lamp spectra the simulator knows: the column names of `sim/spectra/illuminants_10nm.csv`.
pub const KNOWN_LAMP_SPECTRA: &[&str] = &[
    "D65",
    "D50",
    "A",
    "LED-B1",
    "LED-B2",
    "LED-B3",
    "LED-B4",
    "LED-B5",
    "LED-BH1",
    "LED-RGB1",
    "LED-V1",
    "LED-V2",
    "LS_Metal_Halide",
    "LS_MHC100_U_MP_4K",
    "LS_Phosphor_LED_YAG",
];

/// The `[lamp]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LampConfig {
    /// Relative spectral power distribution: one of [`KNOWN_LAMP_SPECTRA`] (the metal-halide
    /// lamp is the closest published analogue of the Bonn rig's HMI lamp).
    pub spectrum: String,
    /// Irradiance on a surface facing the lamp at 1 m, W/m² over 380–780 nm (0 < E <= 1e5).
    pub irradiance_at_1m_w_m2: f64,
    /// Whether the lamp is on when the rig starts (a real HMI lamp is switched on, and warms
    /// up, under the run's control).
    pub on_at_start: bool,
    /// Optional light calibration the pipeline converts to radiance factor with (the lamp's
    /// power and colour, `docs/light.md`): a file made by `btfrig calibrate light`, as a path
    /// relative to the rig config's directory (ending in `.toml`) or `builtin:NAME`. None:
    /// textures in relative units, and the run's report says so.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<String>,
}

impl Default for LampConfig {
    fn default() -> Self {
        LampConfig {
            spectrum: "LS_Metal_Halide".into(),
            irradiance_at_1m_w_m2: 50.0,
            on_at_start: false,
            calibration: None,
        }
    }
}

impl LampConfig {
    /// Appends every out-of-range value of this section to `errors`.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        if !KNOWN_LAMP_SPECTRA.contains(&self.spectrum.as_str()) {
            errors.push(ConfigError::Unknown {
                field: "lamp.spectrum".into(),
                value: self.spectrum.clone(),
                allowed: KNOWN_LAMP_SPECTRA.join(", "),
            });
        }
        let e = self.irradiance_at_1m_w_m2;
        if !(e.is_finite() && e > 0.0 && e <= 1e5) {
            errors.push(ConfigError::out_of_range("lamp.irradiance_at_1m_w_m2", e, "0 < E <= 1e5 W/m²"));
        }
        if let Some(c) = &self.calibration {
            let ok = match c.strip_prefix("builtin:") {
                Some(name) => !name.trim().is_empty(),
                None => c.trim().ends_with(".toml") && c.trim().len() > 5,
            };
            if !ok {
                errors.push(ConfigError::Unknown {
                    field: "lamp.calibration".into(),
                    value: format!("{c:?}"),
                    allowed: "a light calibration file path ending in .toml, or builtin:NAME".into(),
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid_and_unknown_names_list_the_known_ones() {
        let mut errors = Vec::new();
        LampConfig::default().validate(&mut errors);
        assert!(errors.is_empty(), "{errors:?}");
        let cfg = LampConfig { spectrum: "HMI".into(), irradiance_at_1m_w_m2: -1.0, ..Default::default() };
        cfg.validate(&mut errors);
        assert_eq!(errors.len(), 2);
        let text = errors[0].to_string();
        assert!(text.contains("\"HMI\"") && text.contains("LS_Metal_Halide") && text.contains("D65"), "{text}");
    }
}
