//! `btfrig dataset export-recording`: a recording (frames, sidecar and a recorded rig config)
//! from a gonio dataset that kept its raw frames, so that its run can be run again through
//! `btfrig run --rig RECDIR/rig.toml`.

use std::path::{Path, PathBuf};

use btfrig_core::frame::RawFrame;
use btfrig_measurement::reprocess::KeptCaptures;

use crate::format::{self, ExportFormat};
use crate::sidecar::{CameraInfo, DirectionDeg, FrameEntry, RecordingInfo, Sidecar, FORMAT_VERSION, SIDECAR_FILE};
use crate::KIND;

/// The recorded rig config an export writes beside the frames.
pub const RIG_FILE: &str = "rig.toml";

/// What an export wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportSummary {
    /// The recording directory.
    pub out: PathBuf,
    /// Steps exported.
    pub captures: usize,
    /// Frame files written (an HDR step has several).
    pub frames: usize,
    /// The recorded rig config (`btfrig run --rig` it).
    pub rig_file: PathBuf,
    /// Things to look at: calibration files the rig config names by relative path.
    pub notes: Vec<String>,
}

/// Why an export failed; nothing is left in `out`.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The dataset cannot be read or has no raw frames.
    #[error("{0}")]
    Dataset(#[from] btfrig_measurement::RunError),
    /// The output directory is unusable.
    #[error("--out {}: {message}", dir.display())]
    Out {
        /// The directory.
        dir: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A frame or the sidecar could not be written.
    #[error("{}: cannot write it: {message}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// The frames of the dataset disagree with each other (sensor layout).
    #[error("dataset {}: {message}", dir.display())]
    Inconsistent {
        /// The dataset.
        dir: PathBuf,
        /// What disagrees.
        message: String,
    },
}

/// Writes the recording of `dataset` into `out` (new or empty) with frames in `format`.
pub fn export_recording(dataset: &Path, out: &Path, format: ExportFormat) -> Result<ExportSummary, ExportError> {
    let kept = KeptCaptures::open(dataset)?;
    if let Ok(mut entries) = std::fs::read_dir(out) {
        if entries.next().is_some() {
            return Err(ExportError::Out {
                dir: out.into(),
                message: "the directory is not empty: an export overwrites nothing; name a new or empty directory"
                    .into(),
            });
        }
    }
    let existed = out.exists();
    std::fs::create_dir_all(out).map_err(|e| ExportError::Out { dir: out.into(), message: e.to_string() })?;
    let result = write_all(&kept, out, format);
    if result.is_err() {
        // Leave nothing half-written behind.
        if existed {
            if let Ok(entries) = std::fs::read_dir(out) {
                for e in entries.flatten() {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        } else {
            let _ = std::fs::remove_dir_all(out);
        }
    }
    result
}

fn write_all(kept: &KeptCaptures, out: &Path, format: ExportFormat) -> Result<ExportSummary, ExportError> {
    let mut entries = Vec::new();
    let mut first: Option<RawFrame> = None;
    for (i, c) in kept.captures.iter().enumerate() {
        let frames = kept.frames(i)?;
        for (k, frame) in frames.iter().enumerate() {
            let stem = format!("l{:03}_v{:03}", c.step.light, c.step.view);
            let name = match k {
                0 => format!("{stem}.{}", format.extension()),
                k => format!("{stem}_e{k}.{}", format.extension()),
            };
            if let Some(f) = &first {
                let (a, b) = (&f.meta, &frame.meta);
                if (f.width, f.height, a.bit_depth, a.black_level, a.white_level, a.bayer)
                    != (frame.width, frame.height, b.bit_depth, b.black_level, b.white_level, b.bayer)
                {
                    return Err(ExportError::Inconsistent {
                        dir: kept.dir.clone(),
                        message: format!("the raw frame of step {} has another sensor layout than the first", c.step),
                    });
                }
            }
            let path = out.join(&name);
            format::write(&path, frame, format)
                .map_err(|message| ExportError::Write { path: path.clone(), message })?;
            let (lt, lp) = c.light.to_degrees();
            let (vt, vp) = c.view.to_degrees();
            entries.push(FrameEntry {
                file: name,
                exposure_s: frame.meta.exposure_s,
                gain: frame.meta.gain,
                robot_deg: Some(c.joints.robot.map(f64::to_degrees)),
                rail_deg: Some(c.joints.rail.to_degrees()),
                light: Some(DirectionDeg { theta_deg: lt, phi_deg: lp }),
                view: Some(DirectionDeg { theta_deg: vt, phi_deg: vp }),
                f_number: frame.meta.f_number,
                temperature_c: frame.meta.temperature_c,
                step: Some(stem),
            });
            if first.is_none() {
                first = Some(frame.clone());
            }
        }
    }
    let Some(first) = first else {
        return Err(ExportError::Inconsistent {
            dir: kept.dir.clone(),
            message: "it has no committed step to export".into(),
        });
    };
    let camera_options =
        kept.rig.devices.entries().into_iter().find(|(r, _)| *r == "camera").map(|(_, e)| e.options.clone());
    let range = |key: &str, values: &mut dyn Iterator<Item = f64>| -> [f64; 2] {
        let from_rig = camera_options.as_ref().and_then(|o| o.get(key)).and_then(|v| v.as_array()).and_then(|a| {
            let f: Vec<f64> =
                a.iter().filter_map(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64))).collect();
            (f.len() == 2).then(|| [f[0], f[1]])
        });
        from_rig.unwrap_or_else(|| {
            let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
            [lo, hi]
        })
    };
    let exposure_range_s = range("exposure_range_s", &mut entries.iter().map(|e| e.exposure_s));
    let gain_range = range("gain_range", &mut entries.iter().map(|e| e.gain));
    let sidecar = Sidecar {
        recording: RecordingInfo {
            format_version: FORMAT_VERSION,
            description: Some(format!(
                "exported by btfrig dataset export-recording from {} (rig {:?})",
                kept.dir.display(),
                kept.rig.rig.name
            )),
        },
        camera: CameraInfo {
            width: first.width,
            height: first.height,
            bit_depth: first.meta.bit_depth,
            black_level: first.meta.black_level,
            white_level: first.meta.white_level,
            bayer: CameraInfo::bayer_name(first.meta.bayer),
            exposure_range_s,
            gain_range,
            f_number: None,
            model: Some(format!("the camera of rig {:?}", kept.rig.rig.name)),
        },
        frames: entries,
    };
    let sidecar_path = out.join(SIDECAR_FILE);
    std::fs::write(&sidecar_path, sidecar.to_toml())
        .map_err(|e| ExportError::Write { path: sidecar_path.clone(), message: e.to_string() })?;
    let (rig_text, notes) = recorded_rig_toml(&kept.rig_toml, &kept.dir)?;
    let rig_file = out.join(RIG_FILE);
    std::fs::write(&rig_file, rig_text)
        .map_err(|e| ExportError::Write { path: rig_file.clone(), message: e.to_string() })?;
    Ok(ExportSummary { out: out.into(), captures: kept.captures.len(), frames: sidecar.frames.len(), rig_file, notes })
}

/// The dataset's rig config with every device `kind = "recorded"` and the camera's
/// recording the directory the file is in; notes on relative calibration references.
fn recorded_rig_toml(rig_toml: &str, dataset: &Path) -> Result<(String, Vec<String>), ExportError> {
    let bad = |m: String| ExportError::Inconsistent { dir: dataset.into(), message: m };
    let mut doc: toml::Table = toml::from_str(rig_toml).map_err(|e| bad(format!("manifest rig.config_toml: {e}")))?;
    let devices = doc
        .get_mut("devices")
        .and_then(|d| d.as_table_mut())
        .ok_or_else(|| bad("manifest rig.config_toml has no [devices]".into()))?;
    for (role, entry) in devices.iter_mut() {
        let mut t = toml::Table::new();
        t.insert("kind".into(), toml::Value::String(KIND.into()));
        if role == "camera" {
            t.insert("recording".into(), toml::Value::String(".".into()));
        }
        *entry = toml::Value::Table(t);
    }
    let mut notes = Vec::new();
    for (section, key) in
        [("camera", "calibration"), ("camera", "color_calibration"), ("camera", "dark_flat"), ("lamp", "calibration")]
    {
        if let Some(r) = doc.get(section).and_then(|s| s.get(key)).and_then(|v| v.as_str()) {
            if !r.starts_with("builtin:") && Path::new(r).is_relative() {
                notes.push(format!(
                    "[{section}] {key} = {r:?} is relative: it resolves from the recording's directory now; copy the file there or edit {RIG_FILE}"
                ));
            }
        }
    }
    let text = format!(
        "# The rig the recording was captured on, its devices replaced by the recording (docs/recorded-camera.md).\n\
         # Run a plan on it: btfrig run --plan PLAN --rig {RIG_FILE} --out DIR\n{}",
        toml::to_string(&doc).map_err(|e| bad(e.to_string()))?
    );
    Ok((text, notes))
}
