//! A recording directory, read and checked: the sidecar, each frame file (present, a known
//! format, the camera's size), every frame file named by an entry, each entry's pose. Every
//! problem is collected and reported at once, each naming the file and the field.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use btfrig_core::direction::Direction;
use btfrig_core::frame::{BayerPattern, FrameMeta, RawFrame};
use btfrig_core::kinematics::{Gonio, JointState};

use crate::format::{self, FrameFormat};
use crate::sidecar::{FrameEntry, Sidecar, SIDECAR_FILE};
use crate::RecordingError;

/// How far a commanded joint may be from a recorded one and still match it, degrees
/// (`[devices.camera] pose_tolerance_deg` changes it): far below any two poses of a plan,
/// far above the rounding of degrees written as text.
pub const DEFAULT_POSE_TOLERANCE_DEG: f64 = 1e-3;

/// Relative difference up to which a commanded exposure or gain matches a recorded one.
pub const SETTING_TOLERANCE: f64 = 1e-6;

/// One recorded frame: its file and what it was taken with.
#[derive(Debug, Clone)]
pub struct RecordedFrame {
    /// Its index in the sidecar (`frame[i]`).
    pub index: usize,
    /// The file.
    pub path: PathBuf,
    /// Its format.
    pub format: FrameFormat,
    /// Its sidecar entry.
    pub entry: FrameEntry,
    /// The commanded joints (from `robot_deg`/`rail_deg`, or the directions through the rig's
    /// inverse kinematics once [`Recording::resolve_poses`] ran).
    pub joints: Option<JointState>,
}

/// A recording, checked.
#[derive(Debug, Clone)]
pub struct Recording {
    /// Its directory.
    pub dir: PathBuf,
    /// The sidecar.
    pub sidecar: Sidecar,
    /// The colour filter array (`None`: mono).
    pub bayer: Option<BayerPattern>,
    /// The frames, in sidecar order.
    pub frames: Vec<RecordedFrame>,
}

fn frame_err(path: &Path, message: impl Into<String>) -> RecordingError {
    RecordingError::Frame { path: path.to_path_buf(), message: message.into() }
}

fn sidecar_err(path: &Path, message: impl Into<String>) -> RecordingError {
    RecordingError::Sidecar { path: path.to_path_buf(), message: message.into() }
}

fn gather(dir: &Path, mut problems: Vec<RecordingError>) -> Result<(), RecordingError> {
    match problems.len() {
        0 => Ok(()),
        1 => Err(problems.remove(0)),
        _ => Err(RecordingError::Problems { dir: dir.to_path_buf(), problems }),
    }
}

impl Recording {
    /// Reads and checks the recording in `dir`: its sidecar, and every frame file's presence,
    /// format and size from its header (the samples are read when a frame is served).
    pub fn open(dir: &Path) -> Result<Recording, RecordingError> {
        let sidecar_path = dir.join(SIDECAR_FILE);
        if !dir.is_dir() {
            return Err(RecordingError::Directory {
                dir: dir.to_path_buf(),
                message: "not a directory: a recording is a directory of frame files and its sidecar recording.toml"
                    .into(),
            });
        }
        let text = std::fs::read_to_string(&sidecar_path).map_err(|e| {
            sidecar_err(
                &sidecar_path,
                format!("cannot read the sidecar ({e}): every recording has one (docs/recorded-camera.md)"),
            )
        })?;
        let sidecar = Sidecar::from_toml(&text, &sidecar_path)?;
        let mut problems = Vec::new();
        let cam = &sidecar.camera;
        let bayer = match cam.bayer_pattern() {
            Ok(b) => b,
            Err(m) => {
                problems.push(sidecar_err(&sidecar_path, format!("camera.bayer = {m}")));
                None
            }
        };
        let camera_checks: [(bool, String); 6] = [
            (
                cam.width > 0 && cam.height > 0,
                format!("camera.width x height = {}x{}: allowed at least 1x1", cam.width, cam.height),
            ),
            ((1..=16).contains(&cam.bit_depth), format!("camera.bit_depth = {}: allowed 1..=16", cam.bit_depth)),
            (
                cam.black_level < cam.white_level,
                format!("camera.black_level = {} is not below white_level = {}", cam.black_level, cam.white_level),
            ),
            (
                cam.bit_depth >= 16 || u32::from(cam.white_level) < (1u32 << cam.bit_depth),
                format!("camera.white_level = {} exceeds the {}-bit range", cam.white_level, cam.bit_depth),
            ),
            (
                cam.exposure_range_s[0] > 0.0 && cam.exposure_range_s[0] <= cam.exposure_range_s[1],
                format!("camera.exposure_range_s = {:?}: allowed [min, max] with 0 < min <= max", cam.exposure_range_s),
            ),
            (
                cam.gain_range[0] > 0.0 && cam.gain_range[0] <= cam.gain_range[1],
                format!("camera.gain_range = {:?}: allowed [min, max] with 0 < min <= max", cam.gain_range),
            ),
        ];
        problems.extend(camera_checks.into_iter().filter(|(ok, _)| !ok).map(|(_, m)| sidecar_err(&sidecar_path, m)));
        if sidecar.frames.is_empty() {
            problems
                .push(sidecar_err(&sidecar_path, "it has no [[frame]] entry: a recording needs at least one frame"));
        }

        let mut frames = Vec::with_capacity(sidecar.frames.len());
        let mut named = BTreeSet::new();
        for (i, entry) in sidecar.frames.iter().enumerate() {
            let field = |f: &str| format!("{SIDECAR_FILE} frame[{i}].{f}");
            let path = dir.join(&entry.file);
            named.insert(path.clone());
            let mut ok = true;
            for (name, v) in [("exposure_s", entry.exposure_s), ("gain", entry.gain)] {
                if !(v.is_finite() && v > 0.0) {
                    problems.push(frame_err(&path, format!("{} = {v}: allowed a positive number", field(name))));
                    ok = false;
                }
            }
            if let Err(m) = pose_fields(entry) {
                problems.push(frame_err(&path, format!("{}: {m}", field("pose"))));
                ok = false;
            }
            let Some(format) = FrameFormat::from_name(Path::new(&entry.file)) else {
                problems.push(frame_err(
                    &path,
                    format!(
                        "unknown frame format ({} = {:?}): allowed {}",
                        field("file"),
                        entry.file,
                        format::allowed_extensions()
                    ),
                ));
                continue;
            };
            if !path.is_file() {
                problems.push(frame_err(
                    &path,
                    format!("the frame file is missing ({} = {:?} names it)", field("file"), entry.file),
                ));
                continue;
            }
            if let Err(m) = format::check_signature(&path, format) {
                problems.push(frame_err(&path, format!("{} = {:?}: {m}", field("file"), entry.file)));
                continue;
            }
            match format::dimensions(&path, format) {
                Ok((w, h)) if (w, h) != (cam.width, cam.height) => problems.push(frame_err(
                    &path,
                    format!(
                        "wrong frame size: it is {w}x{h}, the sidecar's camera.width x camera.height is {}x{}",
                        cam.width, cam.height
                    ),
                )),
                Ok(_) if ok => {
                    let joints = entry.robot_deg.zip(entry.rail_deg).map(|(r, rail)| JointState {
                        rail: rail.to_radians(),
                        robot: r.map(f64::to_radians),
                        turntable: 0.0,
                    });
                    frames.push(RecordedFrame { index: i, path, format, entry: entry.clone(), joints });
                }
                Ok(_) => {}
                Err(m) => problems.push(frame_err(&path, format!("cannot read its header as {}: {m}", format.name()))),
            }
        }
        // Every frame file of the directory belongs to an entry: a frame without its sidecar
        // entry would be silently left out of the measurement.
        if let Ok(entries) = std::fs::read_dir(dir) {
            let mut strays: Vec<PathBuf> = entries
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.is_file() && FrameFormat::from_name(p).is_some() && !named.contains(p))
                .collect();
            strays.sort();
            problems.extend(strays.iter().map(|p| {
                frame_err(
                    p,
                    format!(
                        "a frame file without its sidecar entry: no [[frame]] of {SIDECAR_FILE} names it (add an entry with \
                         file, exposure_s, gain and the pose, or move the file out of the recording)"
                    ),
                )
            }));
        }
        gather(dir, problems)?;
        Ok(Recording { dir: dir.to_path_buf(), sidecar, bayer, frames })
    }

    /// Gives every frame its commanded joints: the recorded `robot_deg`/`rail_deg`, or the
    /// light and view directions through `gonio`'s inverse kinematics (as the planner expands a
    /// plan's directions); where an entry has both, they must agree within `tolerance_deg`.
    /// Two frames of one pose, exposure and gain are ambiguous and refused.
    pub fn resolve_poses(&mut self, gonio: &Gonio, tolerance_deg: f64) -> Result<(), RecordingError> {
        let mut problems = Vec::new();
        for f in &mut self.frames {
            let field = format!("{SIDECAR_FILE} frame[{}]", f.index);
            let from_dirs = match (f.entry.light, f.entry.view) {
                (Some(l), Some(v)) => {
                    let (l, v) = (
                        Direction::from_degrees(l.theta_deg, l.phi_deg),
                        Direction::from_degrees(v.theta_deg, v.phi_deg),
                    );
                    match gonio.ik(l, v) {
                        Ok(j) => Some(j),
                        Err(e) => {
                            problems
                                .push(frame_err(&f.path, format!("{field}.light/view: the rig cannot reach it: {e}")));
                            continue;
                        }
                    }
                }
                _ => None,
            };
            match (f.joints, from_dirs) {
                (Some(j), Some(d)) if max_joint_diff_deg(&j, &d) > tolerance_deg => problems.push(frame_err(
                    &f.path,
                    format!(
                        "{field}: robot_deg/rail_deg {} and light/view (through the rig's inverse kinematics: {}) \
                         disagree by {:.4} deg (allowed {tolerance_deg} deg, [devices.camera] pose_tolerance_deg)",
                        joints_deg(&j),
                        joints_deg(&d),
                        max_joint_diff_deg(&j, &d)
                    ),
                )),
                (None, Some(d)) => f.joints = Some(d),
                _ => {}
            }
        }
        for (a, fa) in self.frames.iter().enumerate() {
            for fb in &self.frames[a + 1..] {
                if let (Some(ja), Some(jb)) = (fa.joints, fb.joints) {
                    if max_joint_diff_deg(&ja, &jb) <= tolerance_deg
                        && same_setting(fa.entry.exposure_s, fb.entry.exposure_s)
                        && same_setting(fa.entry.gain, fb.entry.gain)
                    {
                        problems.push(frame_err(
                            &fb.path,
                            format!(
                                "{SIDECAR_FILE} frame[{}] has the pose, exposure and gain of frame[{}] ({}): which to \
                                 serve is ambiguous; remove one",
                                fb.index, fa.index, fa.entry.file
                            ),
                        ));
                    }
                }
            }
        }
        gather(&self.dir, problems)
    }

    /// The frame taken at `joints` with `exposure_s` and `gain`; the error says what the
    /// recording has at that pose instead.
    pub fn find(
        &self,
        joints: &JointState,
        exposure_s: f64,
        gain: f64,
        tolerance_deg: f64,
    ) -> Result<&RecordedFrame, String> {
        let at_pose: Vec<&RecordedFrame> = self
            .frames
            .iter()
            .filter(|f| f.joints.is_some_and(|j| max_joint_diff_deg(&j, joints) <= tolerance_deg))
            .collect();
        if let Some(f) =
            at_pose.iter().find(|f| same_setting(f.entry.exposure_s, exposure_s) && same_setting(f.entry.gain, gain))
        {
            return Ok(f);
        }
        if at_pose.is_empty() {
            return Err(format!(
                "the recording {} has no frame at robot/rail {}: the plan asks for a capture the recording lacks",
                self.dir.display(),
                joints_deg(joints)
            ));
        }
        let have: Vec<String> = at_pose
            .iter()
            .map(|f| format!("{} ({} s, gain {})", f.entry.file, f.entry.exposure_s, f.entry.gain))
            .collect();
        Err(format!(
            "the recording {} has no frame at robot/rail {} with exposure {exposure_s} s and gain {gain}: it has {}",
            self.dir.display(),
            joints_deg(joints),
            have.join(", ")
        ))
    }

    /// Reads frame `f`'s samples as a raw frame with its metadata (`sequence` and
    /// `timestamp_s` as given: the camera's).
    pub fn read(&self, f: &RecordedFrame, sequence: u64, timestamp_s: f64) -> Result<RawFrame, RecordingError> {
        let (w, h, data) = format::read_dn(&f.path, f.format)
            .map_err(|m| frame_err(&f.path, format!("cannot read it as {}: {m}", f.format.name())))?;
        let cam = &self.sidecar.camera;
        if (w, h) != (cam.width, cam.height) || data.len() != w * h {
            return Err(frame_err(
                &f.path,
                format!(
                    "wrong frame size: it is {w}x{h}, the sidecar's camera.width x camera.height is {}x{}",
                    cam.width, cam.height
                ),
            ));
        }
        let max = if cam.bit_depth >= 16 { u16::MAX } else { (1u16 << cam.bit_depth) - 1 };
        if let Some(i) = data.iter().position(|&v| v > max) {
            return Err(frame_err(
                &f.path,
                format!(
                    "sample {i} (x {}, y {}) = {} exceeds camera.bit_depth = {} (at most {max})",
                    i % w,
                    i / w,
                    data[i],
                    cam.bit_depth
                ),
            ));
        }
        Ok(RawFrame {
            width: w,
            height: h,
            data,
            meta: FrameMeta {
                sequence,
                exposure_s: f.entry.exposure_s,
                gain: f.entry.gain,
                f_number: f.entry.f_number.or(cam.f_number),
                black_level: cam.black_level,
                white_level: cam.white_level,
                bit_depth: cam.bit_depth,
                bayer: self.bayer,
                timestamp_s,
                temperature_c: f.entry.temperature_c,
            },
        })
    }
}

/// Whether an entry names a pose: both joints fields, or both directions, or all four.
fn pose_fields(e: &FrameEntry) -> Result<(), String> {
    let joints = (e.robot_deg.is_some(), e.rail_deg.is_some());
    let dirs = (e.light.is_some(), e.view.is_some());
    match (joints, dirs) {
        ((true, false), _) => Err("robot_deg without rail_deg: give both".into()),
        ((false, true), _) => Err("rail_deg without robot_deg: give both".into()),
        (_, (true, false)) => Err("light without view: give both".into()),
        (_, (false, true)) => Err("view without light: give both".into()),
        ((false, false), (false, false)) => {
            Err("no pose: give robot_deg and rail_deg (the commanded joints), or light and view (directions, degrees)"
                .into())
        }
        _ => Ok(()),
    }
}

/// Largest difference between two joint states' robot and rail angles, degrees.
pub fn max_joint_diff_deg(a: &JointState, b: &JointState) -> f64 {
    let mut d = (a.rail - b.rail).abs();
    for k in 0..3 {
        d = d.max((a.robot[k] - b.robot[k]).abs());
    }
    d.to_degrees()
}

/// `robot [a, b, c] deg, rail d deg`.
pub fn joints_deg(j: &JointState) -> String {
    format!(
        "robot [{:.4}, {:.4}, {:.4}] deg, rail {:.4} deg",
        j.robot[0].to_degrees(),
        j.robot[1].to_degrees(),
        j.robot[2].to_degrees(),
        j.rail.to_degrees()
    )
}

/// Whether two exposures (or gains) are the same setting.
pub fn same_setting(a: f64, b: f64) -> bool {
    (a - b).abs() <= SETTING_TOLERANCE * a.abs().max(b.abs())
}
