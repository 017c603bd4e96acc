//! Loading a rig's processing model (`btfrig_process::ProcessingModel`) from its rig config
//! and the calibration files the config names: `[camera] calibration` (geometry),
//! `[camera] color_calibration`, `[camera] dark_flat` (or a dark/flat calibration given with
//! the run), and the light: `[lamp] calibration` for a gonioreflectometer ([`gonio_model`]),
//! `[dome] led_calibration` for a dome or camera array (`crate::dome`, on [`rig_model`]). Every part records where it came from; an absent
//! calibration leaves a note in the model that the run's report carries. A named file that
//! cannot be read or does not fit is an error naming the file and the field.

use std::path::Path;
use std::sync::Arc;

use btfrig_calibrate::light::LightCalibrationFile;
use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::Gonio;
use btfrig_process::color::ColorCorrection;
use btfrig_process::dark_flat::DarkFlat;
use btfrig_process::light::{LampReference, LightCorrection};
use btfrig_process::{ProcessingModel, SensorConstants};

use crate::RunError;

/// Light calibration files embedded in the binary, for `[lamp] calibration = "builtin:NAME"`.
pub const BUILTIN_LIGHT_CALIBRATIONS: &[(&str, &str)] = &[
    ("bonn-gonio-sim-light", include_str!("../../../calibration/bonn-gonio-sim-light.toml")),
    ("bonn-gonio-sim-12mp-light", include_str!("../../../calibration/bonn-gonio-sim-12mp-light.toml")),
];

/// The light id of a gonioreflectometer's lamp in a light calibration file.
pub const LAMP: &str = "lamp";

fn rig_err(what: &str, e: impl std::fmt::Display) -> RunError {
    RunError::Rig(format!("{what}: {e}"))
}

/// The light calibration the rig config names (`[lamp] calibration`) as the pipeline's
/// correction (power and colour; no drift correction, which a run asks for with its own
/// light calibration), with where it came from; `None` when the config names none.
pub fn config_light(rig: &RigConfig, rig_path: Option<&Path>) -> Result<Option<(LightCorrection, String)>, RunError> {
    let Some((mut correction, origin)) = config_lamp_correction(rig, rig_path)? else { return Ok(None) };
    correction.correct_drift = false;
    Ok(Some((correction, origin)))
}

/// The lamp's correction (drift correction on, as a run's own light calibration) from the
/// light calibration file the rig config names (`[lamp] calibration`: `builtin:NAME` or a
/// path relative to the rig file's directory), with where it came from; `None` when the
/// config names none.
pub fn config_lamp_correction(
    rig: &RigConfig,
    rig_path: Option<&Path>,
) -> Result<Option<(LightCorrection, String)>, RunError> {
    let Some(reference) = rig.lamp.calibration.as_deref() else { return Ok(None) };
    let what = format!("[lamp] calibration = {reference:?}");
    let (text, origin) = if let Some(name) = reference.strip_prefix("builtin:") {
        let (_, text) = BUILTIN_LIGHT_CALIBRATIONS.iter().find(|(n, _)| *n == name).ok_or_else(|| {
            let known: Vec<&str> = BUILTIN_LIGHT_CALIBRATIONS.iter().map(|(n, _)| *n).collect();
            rig_err(&what, format!("no built-in light calibration {name:?} (built in: {})", known.join(", ")))
        })?;
        (text.to_string(), format!("<embedded calibration/{name}.toml>"))
    } else {
        let base = rig_path.and_then(Path::parent).map(Path::to_path_buf).unwrap_or_default();
        let path = base.join(reference);
        let text = std::fs::read_to_string(&path)
            .map_err(|e| rig_err(&what, format!("cannot read the light calibration {}: {e}", path.display())))?;
        (text, path.display().to_string())
    };
    let file = LightCalibrationFile::from_toml(&text, &origin).map_err(|e| rig_err(&what, e))?;
    let correction = lamp_correction(&file).map_err(|e| rig_err(&what, format!("{origin}: {e}")))?;
    Ok(Some((correction, origin)))
}

/// The lamp's correction (drift correction on) from a light calibration file.
pub fn lamp_correction(file: &LightCalibrationFile) -> Result<LightCorrection, String> {
    let e = file.light(LAMP).ok_or_else(|| {
        let ids: Vec<&str> = file.lights.keys().map(String::as_str).collect();
        format!("no light {LAMP:?} in the file (it has: {})", ids.join(", "))
    })?;
    Ok(LightCorrection::new(LampReference {
        light: LAMP.into(),
        white_rate: e.white_rate_e_per_s,
        plate_albedo: e.plate_albedo,
    }))
}

/// The processing model of the gonioreflectometer `rig` (its config file at `rig_path`, for
/// relative calibration paths): [`rig_model`], with `light` instead of the config's light
/// calibration when given (a run's own, e.g. with drift correction).
pub fn gonio_model(
    rig: &RigConfig,
    rig_path: Option<&Path>,
    light: Option<LightCorrection>,
    dark_flat: Option<Arc<DarkFlat>>,
) -> Result<ProcessingModel, RunError> {
    let (light, light_source) = match light {
        Some(l) => (Some(l), "the run's light calibration (drift corrected)".to_string()),
        None => match config_light(rig, rig_path)? {
            Some((l, origin)) => (Some(l), origin),
            None => (None, "none: relative units".to_string()),
        },
    };
    Ok(rig_model(rig, rig_path, dark_flat)?.with_source("light", light_source).with_light(light))
}

/// The processing model every rig shares, from `rig`'s config (its file at `rig_path`, for
/// relative calibration paths): the config's nominal kinematics, plate and `[sensor]`
/// datasheet values, the geometric and colour calibrations it names, and the dark/flat
/// calibration `dark_flat` (a run's own) or else the one `[camera] dark_flat` names. No light
/// calibration: a gonio adds its lamp's ([`gonio_model`]), a dome its per-LED one.
pub fn rig_model(
    rig: &RigConfig,
    rig_path: Option<&Path>,
    dark_flat: Option<Arc<DarkFlat>>,
) -> Result<ProcessingModel, RunError> {
    let mut gonio = Gonio::new(rig.geometry.clone()).map_err(|e| rig_err("[geometry]", e))?;
    // The nominal pose with the joints' measured zero offsets, when the config names them.
    let geometry_source = match btfrig_calibrate::rig_geometry::processing_joint_offsets(rig, rig_path)
        .map_err(|e| RunError::Rig(format!("the rig's geometry calibration: {e}")))?
    {
        Some((offsets, origin)) => {
            gonio = gonio.with_joint_offsets(offsets);
            origin
        }
        None => "rig config [geometry] (nominal joint zeros)".to_string(),
    };
    let camera = btfrig_calibrate::processing_camera(rig, rig_path)
        .map_err(|e| RunError::Rig(format!("the rig's camera calibration: {e}")))?;
    let sensor = SensorConstants {
        electrons_per_dn: rig.sensor.electrons_per_dn,
        read_noise_e: rig.sensor.read_noise_e,
        dark_current_e_per_s: rig.sensor.dark_current_e_per_s,
        full_scale_e: (white_level_dn(&rig.sensor) - f64::from(rig.sensor.black_level_dn))
            * rig.sensor.electrons_per_dn,
    };
    let color = btfrig_calibrate::color::processing_color(rig, rig_path)
        .map_err(|e| RunError::Rig(format!("the rig's colour calibration: {e}")))?
        .map(|f| {
            let model = f.to_model().expect("checked when read");
            ColorCorrection { name: f.source.plan.clone(), white_balance: f.white_balance, model }
        });
    let (dark_flat, dark_flat_source) = match dark_flat {
        Some(d) => (Some(d), "the run's dark/flat calibration".to_string()),
        None => match btfrig_calibrate::dark_flat::processing_dark_flat(rig, rig_path)
            .map_err(|e| RunError::Rig(format!("the rig's dark/flat calibration: {e}")))?
        {
            Some((d, origin)) => (Some(Arc::new(d)), origin),
            None => (None, "none: mean dark current, lens model vignetting".to_string()),
        },
    };
    let model = ProcessingModel::uncalibrated(rig.rig.name.clone(), gonio, camera, sensor, rig.plate.clone())
        .with_source(
            "camera",
            rig.camera.calibration.clone().unwrap_or_else(|| "rig config [camera] (nominal lens)".into()),
        )
        .with_source("geometry", geometry_source)
        .with_source("sensor", "rig config [sensor] (datasheet values)")
        .with_source(
            "color",
            rig.camera.color_calibration.clone().unwrap_or_else(|| "none: white-balanced camera RGB".into()),
        )
        .with_source("dark_flat", dark_flat_source)
        .with_color(color)
        .with_dark_flat(dark_flat);
    Ok(model)
}

/// The white level at analogue gain 1, DN, from the config's `[sensor]` datasheet values: the
/// full well less four read-noise sigmas (where a real raw file's white level sits, below the
/// noisy saturation plateau), or the ADC's largest value if that is lower.
pub fn white_level_dn(sensor: &btfrig_core::config::sensor::SensorConfig) -> f64 {
    let adc_max = f64::from((1u32 << sensor.bit_depth) - 1);
    let well = f64::from(sensor.black_level_dn)
        + ((sensor.full_well_e - 4.0 * sensor.read_noise_e) / sensor.electrons_per_dn).floor();
    well.min(adc_max)
}

/// The exposure, seconds, at which a white Lambertian reflector lit along its normal from the
/// nominal lamp distance reaches `fraction` of full scale in the green channel at gain 1:
/// `fraction * full scale (e-) / W_g` with `W_g` the light calibration's green white rate.
pub fn exposure_for_white(
    sensor: &btfrig_core::config::sensor::SensorConfig,
    light: &LightCorrection,
    fraction: f64,
) -> f64 {
    let full_scale_e = (white_level_dn(sensor) - f64::from(sensor.black_level_dn)) * sensor.electrons_per_dn;
    fraction * full_scale_e / light.reference.white_rate[1]
}
