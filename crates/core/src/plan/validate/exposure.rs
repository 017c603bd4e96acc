//! `[exposure]`: fixed, auto or bracketed exposures and HDR.

use crate::config::RigConfig;

use super::{ExposurePolicy, HdrMode, HdrSettings};
use crate::plan::{ExposureSpec, PlanError};

/// Reads a `[lo, hi]` float pair from a device's options, if present and well formed.
fn option_range(rig: &RigConfig, key: &str) -> Option<[f64; 2]> {
    let arr = rig.devices.camera.options.get(key)?.as_array()?;
    let v: Vec<f64> = arr.iter().filter_map(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64))).collect();
    (v.len() == 2).then(|| [v[0], v[1]])
}

pub(super) fn resolve_exposure(
    e: &ExposureSpec,
    rig: Option<&RigConfig>,
    errors: &mut Vec<PlanError>,
) -> Option<ExposurePolicy> {
    match e {
        ExposureSpec::Auto {
            white_fraction,
            hdr,
            max_exposures,
            stop_ratio,
            saturated_max_fraction,
            dark_max_fraction,
        } => {
            let white_fraction = *white_fraction;
            let n_before = errors.len();
            if !(white_fraction.is_finite() && (0.05..=0.95).contains(&white_fraction)) {
                errors.push(PlanError::out_of_range(
                    "exposure.white_fraction",
                    white_fraction,
                    "0.05..=0.95 (fraction of full scale)",
                ));
            }
            let hdr =
                resolve_hdr(hdr, *max_exposures, *stop_ratio, *saturated_max_fraction, *dark_max_fraction, errors);
            (errors.len() == n_before).then(|| ExposurePolicy::Auto { white_fraction, hdr: hdr.expect("checked") })
        }
        &ExposureSpec::Fixed { exposure_s, gain } => {
            let t_range = rig.and_then(|r| option_range(r, "exposure_range_s")).unwrap_or([1e-6, 3600.0]);
            let max_gain = rig.map_or(64.0, |r| r.sensor.max_analogue_gain);
            let g_range = rig
                .and_then(|r| option_range(r, "gain_range"))
                .map_or([1.0, max_gain], |[lo, hi]| [lo.max(1.0), hi.min(max_gain)]);
            let mut ok = true;
            if !(exposure_s.is_finite() && exposure_s >= t_range[0] && exposure_s <= t_range[1]) {
                errors.push(PlanError::out_of_range(
                    "exposure.exposure_s",
                    exposure_s,
                    format!("{} ..= {} seconds (the camera's exposure range)", t_range[0], t_range[1]),
                ));
                ok = false;
            }
            if !(gain.is_finite() && gain >= g_range[0] && gain <= g_range[1]) {
                errors.push(PlanError::out_of_range(
                    "exposure.gain",
                    gain,
                    format!("{} ..= {} (the camera's analogue gain range)", g_range[0], g_range[1]),
                ));
                ok = false;
            }
            ok.then_some(ExposurePolicy::Fixed { exposure_s, gain })
        }
        ExposureSpec::Bracket { stops } => {
            let n_before = errors.len();
            match stops.as_deref() {
                None | Some([]) => errors.push(PlanError::invalid(
                    "exposure.stops",
                    "[]",
                    "mode \"bracket\" needs the exposure multipliers",
                    "1 to 8 of them, e.g. stops = [1.0, 0.125]",
                )),
                Some(v) if v.len() > 8 => {
                    errors.push(PlanError::out_of_range("exposure.stops", format!("{} entries", v.len()), "1 ..= 8"))
                }
                Some(v) => {
                    for (i, x) in v.iter().enumerate() {
                        if !(x.is_finite() && (1.0 / 1024.0..=64.0).contains(x)) {
                            errors.push(PlanError::out_of_range(format!("exposure.stops[{i}]"), x, "1/1024 ..= 64"));
                        }
                    }
                }
            }
            (errors.len() == n_before).then(|| ExposurePolicy::Auto {
                white_fraction: 0.6,
                hdr: HdrSettings {
                    mode: HdrMode::Always(stops.clone().unwrap_or_default()),
                    max_exposures: stops.as_ref().map_or(1, |v| v.len() as u32),
                    ..HdrSettings::off()
                },
            })
        }
    }
}

/// Checks the HDR fields of `mode = "auto"`; `None` after an error.
fn resolve_hdr(
    hdr: &str,
    max_exposures: u32,
    stop_ratio: f64,
    saturated_max_fraction: f64,
    dark_max_fraction: f64,
    errors: &mut Vec<PlanError>,
) -> Option<HdrSettings> {
    let n_before = errors.len();
    if !(1..=8).contains(&max_exposures) {
        errors.push(PlanError::out_of_range("exposure.max_exposures", max_exposures, "1 ..= 8"));
    }
    if !(stop_ratio.is_finite() && (1.0 / 64.0..=0.5).contains(&stop_ratio)) {
        errors.push(PlanError::out_of_range("exposure.stop_ratio", stop_ratio, "1/64 ..= 1/2"));
    }
    if !(saturated_max_fraction.is_finite() && (0.0..=0.5).contains(&saturated_max_fraction)) {
        errors.push(PlanError::out_of_range("exposure.saturated_max_fraction", saturated_max_fraction, "0 ..= 0.5"));
    }
    if !(dark_max_fraction.is_finite() && (0.0..=1.0).contains(&dark_max_fraction)) {
        errors.push(PlanError::out_of_range("exposure.dark_max_fraction", dark_max_fraction, "0 ..= 1"));
    }
    let mode = match hdr {
        "off" => HdrMode::Off,
        "adaptive" => HdrMode::Adaptive,
        other => {
            errors.push(PlanError::unknown("exposure.hdr", other, "\"off\", \"adaptive\""));
            HdrMode::Off
        }
    };
    (errors.len() == n_before).then_some(HdrSettings {
        mode,
        max_exposures,
        stop_ratio,
        saturated_max_fraction,
        dark_max_fraction,
    })
}
