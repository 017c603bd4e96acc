//! The dry run of a dome plan (`btfrig plan show` on an LED dome or camera array plan, and
//! the daemon's `POST /api/v1/plans/dry-run`): the capture mode the noise model chooses with
//! every candidate's predicted gain, the frames, an estimate of the rig time from the rig's
//! `[timing]`, and disk and memory, without touching a device or rendering a frame. Every
//! candidate mode is also planned as if the plan forced it, so each has its own frames, rig
//! time and memory.
//!
//! The rig-time estimate follows what a dome step does (`btfrig_acquire::dome`): home the
//! turntable, then per step turn the table when the rotation changes (trapezoidal profile
//! plus settle), set the pattern (`timing.leds.switch_s`), set the exposure on every camera
//! when it changes (`timing.camera.command_s`), trigger (latency, exposure, read-out), and
//! read every camera (frame bytes over the link; the cameras transfer in parallel). It leaves
//! out the serial command round trips of the LED controller and the turntable, so it is a
//! lower bound; `crates/measurement/tests/dome_dry_run.rs` measures how close it is to a run.

use std::path::Path;

use btfrig_core::config::dome::DomeConfig;
use btfrig_core::config::RigConfig;
use btfrig_core::plan::dome::{MultiplexPolicy, ValidatedDomePlan};
use btfrig_core::profile::move_time_s;
use btfrig_mux::{Mode, Prediction};
use btfrig_planner::dome::{plan_dome, DomeSchedule, DomeShot};

use crate::RunError;

/// Whether `text` is a dome plan (it has a `[dome]` table; a gonio plan has none).
pub fn is_dome_plan(text: &str) -> bool {
    // Too long to parse: the gonio plan parser refuses it, naming the limit.
    text.len() <= btfrig_core::plan::MAX_PLAN_BYTES
        && toml::from_str::<toml::Table>(text).is_ok_and(|t| t.contains_key("dome"))
}

/// How bright the planner takes a light of nominal power to be (`plan_dome`'s
/// `led_e_per_s`): it chooses the capture mode and, against saturation, the exposure.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanningBrightness {
    /// e-/s per photosite (e- per flash) of a white reflector facing a light of nominal power.
    pub e_per_s: f64,
    /// Where it comes from: the LED calibration file, or the rig config's nominal value.
    pub source: String,
}

impl PlanningBrightness {
    /// The line a dry run and a run print.
    pub fn line(&self) -> String {
        format!("planned for lights of {:.4} e-/s at a white reflector ({})", self.e_per_s, self.source)
    }
}

/// The planner's brightness of a dome rig's lights, never the simulator's: the
/// `reference_rate` of the LED calibration `[dome] led_calibration` names (resolved against
/// `rig_path`'s directory), else the rig config's `[dome] nominal_signal_e_per_s`. With
/// neither, nothing says how bright the lights are: an error naming both settings.
pub fn planning_brightness(rig: &RigConfig, rig_path: Option<&Path>) -> Result<PlanningBrightness, RunError> {
    let input = |e: String| RunError::Input { what: "dome planning".into(), message: e };
    let dome = rig.require_dome("dome planning").map_err(|e| input(e.to_string()))?;
    let leds = btfrig_calibrate::leds::processing_leds(rig, rig_path)
        .map_err(|e| RunError::Input { what: "LED calibration".into(), message: e.to_string() })?;
    match (leds, dome.nominal_signal_e_per_s) {
        (Some(f), _) => Ok(PlanningBrightness {
            e_per_s: f.reference_rate,
            source: format!(
                "reference_rate of the LED calibration {}",
                dome.led_calibration.as_deref().unwrap_or_default()
            ),
        }),
        (None, Some(n)) => Ok(PlanningBrightness {
            e_per_s: n,
            source: "no LED calibration: the rig config's nominal [dome] nominal_signal_e_per_s".into(),
        }),
        (None, None) => Err(input(format!(
            "the rig {} names no [dome] led_calibration and no [dome] nominal_signal_e_per_s, so the lights' \
             brightness is unknown: name one (btfrig calibrate leds) or set the nominal value",
            rig.rig.name
        ))),
    }
}

/// What a dome plan would do.
#[derive(Debug, Clone)]
pub struct DomeDryRun {
    /// The plan's name.
    pub name: String,
    /// The rig's name and kind (`led_dome`, `camera_array`).
    pub rig: String,
    /// `"LED"` or `"flash"`.
    pub light: &'static str,
    /// Cameras and rotations captured.
    pub cameras: Vec<usize>,
    /// Rotation indices.
    pub rotations: Vec<u32>,
    /// The schedule (mode, reason, candidates, patterns, steps).
    pub schedule: DomeSchedule,
    /// The lights' brightness it was planned for, and where that comes from.
    pub brightness: PlanningBrightness,
    /// Frames per camera (pattern and reference frames).
    pub frames: usize,
    /// Textures the run stores (lights x views).
    pub textures: usize,
    /// Estimated rig time, s (a lower bound: module docs), and its parts.
    pub rig_time_s: f64,
    /// Of it: exposing.
    pub exposure_s: f64,
    /// Of it: reading and transferring frames.
    pub transfer_s: f64,
    /// Of it: turning the table.
    pub turntable_s: f64,
    /// Of it: LED switching, trigger latency and exposure commands.
    pub commands_s: f64,
    /// Homing the turntable before the run, s (not in `rig_time_s`, as in the run's figure).
    pub home_s: f64,
    /// Bytes of the stored textures (32-bit float RGB EXR).
    pub texture_bytes: u64,
    /// With `[outputs] raw_frames = true`: the pattern frames kept (every view group's, all
    /// cameras) and their bytes (32-bit float DN per photosite, RLE: noisy frames do not
    /// shrink); `None` without.
    pub raw_frames: Option<(usize, u64)>,
    /// Bytes one view group's stack holds (frames x photosites x 4, per camera).
    pub group_bytes: u64,
    /// Every mode the noise model evaluated (`schedule.choice.candidates`, in that order),
    /// each planned as if the plan forced it: frames, rig time and memory per mode.
    pub candidates: Vec<CandidateEstimate>,
}

/// One candidate mode of the noise model, planned for this plan.
#[derive(Debug, Clone)]
pub struct CandidateEstimate {
    /// The noise model's prediction (mode, frames per view group, lit sources, exposure,
    /// saturation, predicted gain).
    pub prediction: Prediction,
    /// Whether the noise model chose it (`schedule.choice.best`).
    pub chosen: bool,
    /// Whether the plan captures with it (the choice, or the mode the plan forces).
    pub used: bool,
    /// Frames per camera in this mode (reference frames included).
    pub frames: usize,
    /// Estimated rig time in this mode, s (a lower bound, as [`DomeDryRun::rig_time_s`]).
    pub rig_time_s: f64,
    /// Bytes one view group's stack holds in this mode.
    pub group_bytes: u64,
}

/// The rig time of a schedule from the rig's `[timing]` (module docs), s, in parts.
#[derive(Debug, Clone, Copy, Default)]
struct RigTime {
    exposure_s: f64,
    transfer_s: f64,
    turntable_s: f64,
    commands_s: f64,
}

impl RigTime {
    fn total_s(&self) -> f64 {
        self.exposure_s + self.transfer_s + self.turntable_s + self.commands_s
    }
}

fn rig_time(rig: &RigConfig, dome: &DomeConfig, schedule: &DomeSchedule) -> RigTime {
    let t = &rig.timing;
    let cam = &rig.camera;
    let frame_bytes = t.camera.frame_bytes.unwrap_or((cam.width_px * cam.height_px) as u64 * 2);
    let per_frame_transfer = t.camera.read_out_s + frame_bytes as f64 / t.camera.transfer_bytes_per_s;
    let mut out = RigTime::default();
    let (mut table_at, mut exposure_set): (Option<u32>, Option<f64>) = (None, None);
    for step in &schedule.steps {
        if table_at != Some(step.rotation) {
            if dome.rotations > 1 {
                let from = table_at.map_or(0.0, |k| dome.rotation_rad(k));
                let deg = (step.turntable_rad - from).to_degrees();
                out.turntable_s += move_time_s(deg, t.turntable.max_speed_deg_per_s, t.turntable.accel_deg_per_s2)
                    + t.turntable.settle_s;
            }
            table_at = Some(step.rotation);
        }
        let e = match step.shot {
            DomeShot::Pattern(_) => schedule.exposure_s,
            DomeShot::Reference(_) => schedule.single_exposure_s,
        };
        if exposure_set != Some(e) {
            out.commands_s += t.camera.command_s;
            exposure_set = Some(e);
        }
        out.commands_s += t.leds.switch_s + t.camera.trigger_latency_s;
        out.exposure_s += e;
        out.transfer_s += per_frame_transfer;
    }
    out
}

/// The estimated rig time of `schedule`'s steps, s (a lower bound: module docs).
pub(crate) fn schedule_rig_time_s(rig: &RigConfig, dome: &DomeConfig, schedule: &DomeSchedule) -> f64 {
    rig_time(rig, dome, schedule).total_s()
}

/// Bytes of one kept raw frame (`btfrig_imageio::encode_raw_exr`): 4 per photosite, 8 per
/// scan line of offset table, and the header with the frame's metadata.
fn raw_frame_bytes(rig: &RigConfig) -> u64 {
    let (w, h) = (rig.camera.width_px as u64, rig.camera.height_px as u64);
    w * h * 4 + 8 * h + RAW_HEADER_BYTES
}

/// The EXR header of a kept raw frame with its metadata JSON, about 1 kB (the estimate is
/// 0.7 % above the files of `tests/dome_dry_run.rs`'s camera array: RLE shrinks them a little).
const RAW_HEADER_BYTES: u64 = 1000;

/// Bytes one view group's stack holds: its frames x photosites x 4, for every camera.
fn group_bytes(rig: &RigConfig, cameras: usize, schedule: &DomeSchedule) -> u64 {
    let per_group = if schedule.mode.is_multiplexed() { schedule.patterns.len() } else { schedule.leds };
    (per_group * rig.camera.width_px * rig.camera.height_px * 4) as u64 * cameras as u64
}

/// The plan `v` as if it forced `mode` (the noise model's candidates are planned this way).
fn forcing(v: &ValidatedDomePlan, mode: Mode) -> ValidatedDomePlan {
    let mut forced = v.clone();
    let d = &mut forced.plan.dome;
    (d.multiplex, d.group_order) = match mode {
        Mode::Single => (MultiplexPolicy::Off, None),
        Mode::SMatrix { .. } => (MultiplexPolicy::On, None),
        Mode::Grouped { order, .. } => (MultiplexPolicy::On, Some(order)),
    };
    forced
}

/// The dry run of the dome plan `text` (from `file`, which names it in errors and resolves
/// relative rig configs).
pub fn dry_run(text: &str, file: &Path) -> Result<DomeDryRun, RunError> {
    let (v, rig, _) = crate::plan::load_dome(text, file)?;
    let rig_path = (!v.plan.rig.config.starts_with("builtin:"))
        .then(|| file.parent().unwrap_or(Path::new(".")).join(&v.plan.rig.config));
    let brightness = planning_brightness(&rig, rig_path.as_deref())?;
    let planning = |v: &ValidatedDomePlan| {
        plan_dome(&rig, v, brightness.e_per_s)
            .map_err(|e| RunError::Input { what: "dome planning".into(), message: e.to_string() })
    };
    let schedule = planning(&v)?;
    let dome = rig
        .require_dome("the dome dry run")
        .map_err(|e| RunError::Input { what: "rig".into(), message: e.to_string() })?;
    let t = rig_time(&rig, dome, &schedule);
    // Homing comes before the engine's clock starts (as in the run's rig time): apart.
    let home_s = if dome.rotations > 1 { rig.timing.turntable.home_s } else { 0.0 };
    let used = schedule.mode.mux_mode();
    let mut candidates = Vec::with_capacity(schedule.choice.candidates.len());
    for p in &schedule.choice.candidates {
        let (frames, rig_time_s, bytes) = if p.mode == used {
            (schedule.steps.len(), t.total_s(), group_bytes(&rig, v.cameras.len(), &schedule))
        } else {
            let s = planning(&forcing(&v, p.mode))?;
            (s.steps.len(), rig_time(&rig, dome, &s).total_s(), group_bytes(&rig, v.cameras.len(), &s))
        };
        candidates.push(CandidateEstimate {
            prediction: *p,
            chosen: p.mode == schedule.choice.best.mode,
            used: p.mode == used,
            frames,
            rig_time_s,
            group_bytes: bytes,
        });
    }
    let views = v.cameras.len() * v.rotations.len();
    let textures = schedule.leds * views;
    let size = v.plan.texture_size as u64;
    Ok(DomeDryRun {
        name: v.plan.name.clone(),
        rig: format!("{} ({})", rig.rig.name, rig.rig.kind.as_str()),
        light: if dome.is_flash() { "flash" } else { "LED" },
        cameras: v.cameras.clone(),
        rotations: v.rotations.clone(),
        frames: schedule.steps.len(),
        textures,
        rig_time_s: t.total_s(),
        exposure_s: t.exposure_s,
        transfer_s: t.transfer_s,
        turntable_s: t.turntable_s,
        commands_s: t.commands_s,
        home_s,
        // 3 x 32-bit floats per texel plus the EXR header and offset table.
        texture_bytes: textures as u64 * (size * size * 12 + 400 + 8 * size),
        raw_frames: v.plan.outputs.raw_frames.then(|| {
            let kept = schedule.patterns.len() * views;
            (kept, kept as u64 * raw_frame_bytes(&rig))
        }),
        group_bytes: group_bytes(&rig, v.cameras.len(), &schedule),
        candidates,
        schedule,
        brightness,
    })
}

/// One line per candidate mode of the noise model: mode, frames, lit sources, exposure,
/// predicted gain, and this plan's frames per camera and rig time in that mode.
pub fn candidate_lines(d: &DomeDryRun) -> Vec<String> {
    d.candidates
        .iter()
        .map(|c| {
            let p = &c.prediction;
            let chosen = if c.chosen { "  <- the noise model's choice" } else { "" };
            let sat = if p.saturation_factor < 0.999 {
                format!(", exposure cut to {:.0} % by saturation", 100.0 * p.saturation_factor)
            } else {
                String::new()
            };
            format!(
                "{:<16} {:>5} frames, {:>5.1} lit, {:.4} s per frame{sat}: predicted gain {:.3}; \
                 {} frames per camera, rig time at least {:.1} s{chosen}",
                p.mode.describe(),
                p.frames,
                p.lit,
                p.exposure_s,
                p.gain,
                c.frames,
                c.rig_time_s
            )
        })
        .collect()
}

impl DomeDryRun {
    /// Single-light reference frames (first view group; they measure the gain, not stored).
    pub fn reference_frames(&self) -> usize {
        self.schedule.steps.iter().filter(|st| matches!(st.shot, DomeShot::Reference(_))).count()
    }

    /// The plan as it would run, for `btfrig plan show`.
    pub fn lines(&self, file: &Path) -> Vec<String> {
        let s = &self.schedule;
        let lights = if self.light == "flash" { "flashes" } else { "LEDs" };
        let mut out = vec![
            format!("dome plan {:?} from {} on rig {}", self.name, file.display(), self.rig),
            format!(
                "{} {lights} x {} views (cameras {:?} x rotations {:?}): {} textures",
                s.leds,
                self.cameras.len() * self.rotations.len(),
                self.cameras,
                self.rotations,
                self.textures
            ),
            format!("mode {}: {}", s.mode.describe(), s.reason),
            self.brightness.line(),
        ];
        out.push("noise model candidates (equal total exposure time):".into());
        out.extend(candidate_lines(self).into_iter().map(|l| format!("  {l}")));
        let refs = self.reference_frames();
        out.push(format!(
            "frames: {} per camera ({} per view group{}), pattern exposure {:.4} s, single-light exposure {:.4} s",
            self.frames,
            s.patterns.len(),
            if refs > 0 { format!(", plus {refs} single-{} reference frames", self.light) } else { String::new() },
            s.exposure_s,
            s.single_exposure_s
        ));
        let saved = if self.light == "flash" {
            "frames single-flash capture averages"
        } else {
            "exposure time single-light capture needs"
        };
        out.push(format!(
            "predicted SNR gain {:.3}; time saved {:.1} % of the {saved} for the same SNR",
            s.predicted_gain,
            100.0 * s.time_saved_fraction
        ));
        out.push(format!(
            "estimated rig time at least {:.1} s: exposing {:.1} s, read-out and transfer {:.1} s, turntable {:.1} s, \
             commands {:.1} s (after homing the turntable, {:.1} s)",
            self.rig_time_s, self.exposure_s, self.transfer_s, self.turntable_s, self.commands_s, self.home_s
        ));
        let raw = match self.raw_frames {
            Some((n, bytes)) => format!(" + {:.1} MB of {n} raw pattern frames kept (raw_frames)", bytes as f64 / 1e6),
            None => String::new(),
        };
        out.push(format!(
            "disk {:.1} MB of textures{raw}; memory {:.1} MB per view group stack",
            self.texture_bytes as f64 / 1e6,
            self.group_bytes as f64 / 1e6
        ));
        out
    }
}

/// `btfrig plan check` on a dome plan: the one-paragraph summary.
pub fn check_lines(text: &str, file: &Path) -> Result<Vec<String>, RunError> {
    let (v, rig, _) = crate::plan::load_dome(text, file)?;
    let dome = rig
        .require_dome("the dome plan check")
        .map_err(|e| RunError::Input { what: "rig".into(), message: e.to_string() })?;
    let views = v.cameras.len() * v.rotations.len();
    let light = if dome.is_flash() { "flashes" } else { "LEDs" };
    Ok(vec![
        format!("{}: valid dome plan {:?}", file.display(), v.plan.name),
        format!(
            "rig {} ({}, {}), {} {light} x {} views (cameras {:?} x rotations {:?}), {} textures",
            rig.rig.name,
            v.plan.rig.config,
            rig.rig.kind.as_str(),
            dome.led_count(),
            views,
            v.cameras,
            v.rotations,
            dome.led_count() * views
        ),
    ])
}
