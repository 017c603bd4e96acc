//! What the pipeline knows of a rig: the processing model.
//!
//! Processing is a function of frames, the rig config and calibration files, nothing else
//! (`docs/ARCHITECTURE.md`). A [`ProcessingModel`] gathers what the stages need: the nominal
//! kinematics and holder plate (rig config), the camera model (a geometric calibration file,
//! or the config's nominal lens), the sensor's constants (the config's `[sensor]` datasheet
//! values), the dark model and flats, the light calibration (power and colour of the lamp)
//! and the colour calibration. The runner loads it (`btfrig_measurement::model`); the pipeline
//! never sees the simulator.
//!
//! A calibration that is absent degrades the output visibly, never silently: each absence
//! adds a [`ProcessingModel::notes`] line that the run's report carries, e.g. "no light
//! calibration: textures in relative units (full scales per second of exposure at gain 1,
//! not radiance factor)": the signal rate divided by the sensor's full scale, so a relative
//! texture stays in the range a half-float file holds.

use std::sync::Arc;

use btfrig_core::camera::CameraModel;
use btfrig_core::config::plate::PlateConfig;
use btfrig_core::kinematics::Gonio;

use crate::color::ColorCorrection;
use crate::dark_flat::DarkFlat;
use crate::light::LightCorrection;

/// The sensor's constants the radiometric conversion and the HDR merge need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorConstants {
    /// System gain at analogue gain 1, electrons per DN.
    pub electrons_per_dn: f64,
    /// Read noise, electrons RMS.
    pub read_noise_e: f64,
    /// Mean dark current, electrons per second per photosite (subtracted without a dark model).
    pub dark_current_e_per_s: f64,
    /// Electrons from black to the white level at gain 1: the unit of relative textures.
    pub full_scale_e: f64,
}

impl SensorConstants {
    /// DN per electron at analogue gain `gain`.
    pub fn dn_per_electron(&self, gain: f64) -> f64 {
        gain / self.electrons_per_dn
    }
}

/// Where one part of the model came from, for the report and the manifest.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSource {
    /// The part: `camera`, `sensor`, `light`, `color`, `dark_flat`.
    pub part: &'static str,
    /// A file (its path, or `<embedded calibration/NAME.toml>`), or what stood in for it.
    pub source: String,
}

/// What the pipeline processes frames with (see the module documentation).
#[derive(Clone)]
pub struct ProcessingModel {
    /// The rig's name (`[rig] name`).
    pub rig: String,
    /// Nominal kinematics: the pose of commanded joints.
    pub gonio: Gonio,
    /// The camera model frames are registered and rectified with.
    pub camera: CameraModel,
    /// The sensor's constants.
    pub sensor: SensorConstants,
    /// The holder plate (markers, white area) as the rig config describes it.
    pub plate: PlateConfig,
    /// The lamp's calibrated power and colour; `None`: relative units.
    pub light: Option<LightCorrection>,
    /// The colour calibration; `None`: white-balanced camera RGB.
    pub color: Option<ColorCorrection>,
    /// Measured dark model and flats; `None`: the mean dark current and the lens model's
    /// vignetting.
    pub dark_flat: Option<Arc<DarkFlat>>,
    /// Where each part came from.
    pub sources: Vec<ModelSource>,
    /// What the output lacks because a calibration is absent (for the report).
    pub notes: Vec<String>,
}

impl std::fmt::Debug for ProcessingModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProcessingModel")
            .field("rig", &self.rig)
            .field("sources", &self.sources)
            .field("notes", &self.notes)
            .finish_non_exhaustive()
    }
}

/// The note of a model without a light calibration.
pub const NO_LIGHT_NOTE: &str =
    "no light calibration: textures in relative units (full scales per second of exposure at gain 1, not radiance factor)";

/// The note of a model without a colour calibration.
pub const NO_COLOR_NOTE: &str =
    "no colour calibration: textures in the camera's own RGB (white-balanced if a light calibration is given), not linear sRGB";

impl ProcessingModel {
    /// A model of `gonio`, `camera`, `sensor` and `plate` with no calibration files: relative
    /// units, camera RGB, the lens model's vignetting (its notes say so).
    pub fn uncalibrated(
        rig: impl Into<String>,
        gonio: Gonio,
        camera: CameraModel,
        sensor: SensorConstants,
        plate: PlateConfig,
    ) -> ProcessingModel {
        ProcessingModel {
            rig: rig.into(),
            gonio,
            camera,
            sensor,
            plate,
            light: None,
            color: None,
            dark_flat: None,
            sources: Vec::new(),
            notes: vec![NO_LIGHT_NOTE.to_string(), NO_COLOR_NOTE.to_string()],
        }
    }

    /// The same model with a light calibration (drops the relative-units note).
    pub fn with_light(mut self, light: Option<LightCorrection>) -> Self {
        self.notes.retain(|n| n != NO_LIGHT_NOTE);
        if light.is_none() {
            self.notes.push(NO_LIGHT_NOTE.to_string());
        }
        self.light = light;
        self
    }

    /// The same model with a colour calibration (drops the camera-RGB note).
    pub fn with_color(mut self, color: Option<ColorCorrection>) -> Self {
        self.notes.retain(|n| n != NO_COLOR_NOTE);
        if color.is_none() {
            self.notes.push(NO_COLOR_NOTE.to_string());
        }
        self.color = color;
        self
    }

    /// The same model with measured dark model and flats.
    pub fn with_dark_flat(mut self, dark_flat: Option<Arc<DarkFlat>>) -> Self {
        self.dark_flat = dark_flat;
        self
    }

    /// The same model recording where `part` came from.
    pub fn with_source(mut self, part: &'static str, source: impl Into<String>) -> Self {
        self.sources.retain(|s| s.part != part);
        self.sources.push(ModelSource { part, source: source.into() });
        self
    }

    /// Whether textures come out as absolute radiance factor (a light calibration is given).
    pub fn is_absolute(&self) -> bool {
        self.light.is_some()
    }
}
