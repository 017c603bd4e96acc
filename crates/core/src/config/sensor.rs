//! The `[sensor]` section of a rig config: the raw image sensor behind the lens.
//!
//! The noise model and the reasons for the defaults are in `docs/sensor-model.md`. Defaults:
//! a 14-bit APS-C-class sensor read out at 1600 x 1200 (14.75 µm effective photosites), full
//! well 40 000 e-, 2.5 e- per DN at base gain (so full well lands at 16 000 DN above a
//! black level of 256 DN, just inside the 14-bit range), 3 e- read noise, 0.5% PRNU, and the
//! spectral sensitivities of a Nikon D5100 (NPL measurement).

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;
use crate::frame::BayerPattern;

/// Camera spectral sensitivity sets the simulator knows (files in `sim/spectra/`).
pub const KNOWN_CAMERA_SENSITIVITIES: &[&str] = &["nikon_d5100", "canon_5d_mk2"];

/// Colour filter array of the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum Cfa {
    /// Bayer R G / G B.
    Rggb,
    /// Bayer B G / G R.
    Bggr,
    /// Bayer G R / B G.
    Grbg,
    /// Bayer G B / R G.
    Gbrg,
    /// No colour filters: every photosite sees the green channel's spectral sensitivity
    /// (a monochrome sensor with a photopic-like response).
    #[serde(alias = "mono")]
    Mono,
}

impl Cfa {
    /// The Bayer pattern, or `None` for a monochrome sensor.
    pub fn bayer(self) -> Option<BayerPattern> {
        match self {
            Cfa::Rggb => Some(BayerPattern::Rggb),
            Cfa::Bggr => Some(BayerPattern::Bggr),
            Cfa::Grbg => Some(BayerPattern::Grbg),
            Cfa::Gbrg => Some(BayerPattern::Gbrg),
            Cfa::Mono => None,
        }
    }
}

/// The `[sensor]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorConfig {
    /// Colour filter array: "RGGB", "BGGR", "GRBG", "GBRG" or "MONO".
    pub cfa: Cfa,
    /// Spectral sensitivity of the R, G, B channels: one of [`KNOWN_CAMERA_SENSITIVITIES`].
    pub camera_sensitivity: String,
    /// Bits per sample of the analogue-to-digital converter (8..=16; cameras: 12 or 14).
    pub bit_depth: u8,
    /// Photo-electrons per digital number at base gain (analogue gain 1), e-/DN (> 0).
    pub electrons_per_dn: f64,
    /// Largest analogue gain the camera accepts (>= 1).
    pub max_analogue_gain: f64,
    /// Full-well capacity: electrons a photosite holds before it saturates (> 0).
    pub full_well_e: f64,
    /// Read noise, electrons RMS (>= 0).
    pub read_noise_e: f64,
    /// Black (dark) level added to every sample, DN (below 2^bit_depth - 1).
    pub black_level_dn: u16,
    /// Dark current, electrons per second per photosite (>= 0).
    pub dark_current_e_per_s: f64,
    /// Photo-response non-uniformity: relative RMS of the fixed per-photosite gain pattern
    /// (0..=0.2; 0 disables it).
    pub prnu_rms: f64,
    /// Seed of the fixed PRNU pattern (a property of the sensor, the same in every frame).
    pub fixed_pattern_seed: u64,
    /// Photosite pitch, micrometres (> 0); sets the light each photosite collects.
    pub pixel_pitch_um: f64,
    /// Quantum efficiency of the most sensitive channel at its peak wavelength (0 < q <= 1).
    pub peak_quantum_efficiency: f64,
    /// Dark-signal non-uniformity: relative RMS of the fixed per-photosite multiplier of
    /// `dark_current_e_per_s` (0..=2; 0 disables it). Hashed from `fixed_pattern_seed`.
    pub dsnu_rms: f64,
    /// Fraction of photosites that are hot: their dark current is `hot_pixel_dark_e_per_s`
    /// times a log-uniform factor in [1, 10) instead of the DSNU value (0..=0.01).
    pub hot_pixel_fraction: f64,
    /// Smallest dark current of a hot photosite, electrons per second (>= 0).
    pub hot_pixel_dark_e_per_s: f64,
    /// RMS of the fixed per-column offset of the black level, DN (0..=100; 0 disables it):
    /// column-parallel ADCs each have their own offset.
    pub column_offset_rms_dn: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        SensorConfig {
            cfa: Cfa::Rggb,
            camera_sensitivity: "nikon_d5100".into(),
            bit_depth: 14,
            electrons_per_dn: 2.5,
            max_analogue_gain: 16.0,
            full_well_e: 40000.0,
            read_noise_e: 3.0,
            black_level_dn: 256,
            dark_current_e_per_s: 0.5,
            prnu_rms: 0.005,
            fixed_pattern_seed: 1,
            pixel_pitch_um: 14.75,
            peak_quantum_efficiency: 0.5,
            dsnu_rms: 0.0,
            hot_pixel_fraction: 0.0,
            hot_pixel_dark_e_per_s: 0.0,
            column_offset_rms_dn: 0.0,
        }
    }
}

impl SensorConfig {
    /// Appends every out-of-range value of this section to `errors`.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        if !KNOWN_CAMERA_SENSITIVITIES.contains(&self.camera_sensitivity.as_str()) {
            errors.push(ConfigError::Unknown {
                field: "sensor.camera_sensitivity".into(),
                value: self.camera_sensitivity.clone(),
                allowed: KNOWN_CAMERA_SENSITIVITIES.join(", "),
            });
        }
        let mut push = |field: &str, value: String, allowed: &str| {
            errors.push(ConfigError::OutOfRange { field: format!("sensor.{field}"), value, allowed: allowed.into() })
        };
        if !(8..=16).contains(&self.bit_depth) {
            push("bit_depth", self.bit_depth.to_string(), "8..=16 (cameras: 12 or 14)");
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.electrons_per_dn) {
            push("electrons_per_dn", self.electrons_per_dn.to_string(), "> 0");
        }
        if !(self.max_analogue_gain.is_finite() && self.max_analogue_gain >= 1.0) {
            push("max_analogue_gain", self.max_analogue_gain.to_string(), ">= 1");
        }
        if !positive(self.full_well_e) {
            push("full_well_e", self.full_well_e.to_string(), "> 0");
        }
        if !(self.read_noise_e.is_finite() && self.read_noise_e >= 0.0) {
            push("read_noise_e", self.read_noise_e.to_string(), ">= 0");
        }
        if (8..=16).contains(&self.bit_depth) && u32::from(self.black_level_dn) >= (1u32 << self.bit_depth) - 1 {
            push("black_level_dn", self.black_level_dn.to_string(), "below 2^bit_depth - 1");
        }
        if !(self.dark_current_e_per_s.is_finite() && self.dark_current_e_per_s >= 0.0) {
            push("dark_current_e_per_s", self.dark_current_e_per_s.to_string(), ">= 0");
        }
        if !(0.0..=0.2).contains(&self.prnu_rms) {
            push("prnu_rms", self.prnu_rms.to_string(), "0..=0.2");
        }
        if !positive(self.pixel_pitch_um) {
            push("pixel_pitch_um", self.pixel_pitch_um.to_string(), "> 0");
        }
        if !(self.peak_quantum_efficiency > 0.0 && self.peak_quantum_efficiency <= 1.0) {
            push("peak_quantum_efficiency", self.peak_quantum_efficiency.to_string(), "0 < q <= 1");
        }
        if !(0.0..=2.0).contains(&self.dsnu_rms) {
            push("dsnu_rms", self.dsnu_rms.to_string(), "0..=2");
        }
        if !(0.0..=0.01).contains(&self.hot_pixel_fraction) {
            push("hot_pixel_fraction", self.hot_pixel_fraction.to_string(), "0..=0.01");
        }
        if !(self.hot_pixel_dark_e_per_s.is_finite() && self.hot_pixel_dark_e_per_s >= 0.0) {
            push("hot_pixel_dark_e_per_s", self.hot_pixel_dark_e_per_s.to_string(), ">= 0");
        }
        if !(0.0..=100.0).contains(&self.column_offset_rms_dn) {
            push("column_offset_rms_dn", self.column_offset_rms_dn.to_string(), "0..=100");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid() {
        let mut errors = Vec::new();
        SensorConfig::default().validate(&mut errors);
        assert!(errors.is_empty(), "{errors:?}");
    }

    #[test]
    fn all_problems_are_reported() {
        let cfg = SensorConfig {
            camera_sensitivity: "sony".into(),
            bit_depth: 20,
            electrons_per_dn: 0.0,
            read_noise_e: -1.0,
            ..Default::default()
        };
        let mut errors = Vec::new();
        cfg.validate(&mut errors);
        let text = errors.iter().map(|e| e.to_string()).collect::<Vec<_>>().join("\n");
        assert_eq!(errors.len(), 4, "{text}");
        assert!(text.contains("nikon_d5100, canon_5d_mk2"), "{text}");
        assert!(text.contains("sensor.bit_depth = 20"), "{text}");
    }

    #[test]
    fn dark_non_uniformity_fields_default_off_and_are_checked() {
        let cfg: SensorConfig = toml::from_str("prnu_rms = 0.01").unwrap();
        assert_eq!((cfg.dsnu_rms, cfg.hot_pixel_fraction, cfg.column_offset_rms_dn), (0.0, 0.0, 0.0));
        let bad = SensorConfig {
            dsnu_rms: 3.0,
            hot_pixel_fraction: 0.5,
            hot_pixel_dark_e_per_s: -1.0,
            column_offset_rms_dn: f64::NAN,
            ..Default::default()
        };
        let mut errors = Vec::new();
        bad.validate(&mut errors);
        let text = errors.iter().map(|e| e.to_string()).collect::<Vec<_>>().join("\n");
        assert_eq!(errors.len(), 4, "{text}");
        assert!(text.contains("sensor.hot_pixel_fraction = 0.5"), "{text}");
    }

    #[test]
    fn cfa_names_parse() {
        let cfg: SensorConfig = toml::from_str("cfa = \"mono\"").unwrap();
        assert_eq!(cfg.cfa.bayer(), None);
        let cfg: SensorConfig = toml::from_str("cfa = \"GBRG\"").unwrap();
        assert_eq!(cfg.cfa.bayer(), Some(BayerPattern::Gbrg));
        let err = toml::from_str::<SensorConfig>("cfa = \"XYZ\"").unwrap_err().to_string();
        assert!(err.contains("RGGB"), "{err}");
    }
}
