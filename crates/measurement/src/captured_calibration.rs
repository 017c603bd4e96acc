//! The radiometric calibrations captured through the devices: dark and flat fields, the
//! sensor's EMVA 1288 characterisation, the lamp's power and colour from a white tile, and a
//! dome's LED (or a camera array's flash) powers and colours, one light at a time or by
//! Hadamard patterns demultiplexed with `btfrig-mux`.
//!
//! Each procedure opens the rig through the backend registry with a target mounted
//! ([`MountedTarget`]: on a real rig the operator mounts it when asked, a simulated backend
//! puts it into its scene), drives the camera and lights through the device traits, and hands
//! the frames to the numerics in `btfrig-calibrate`, which do no I/O. Nothing here renders or
//! knows a simulator constant: exposures are metered on the frames.
//!
//! Before opening anything a procedure checks the devices it needs by role
//! ([`check_devices`]): a missing device, or one no registered backend opens, is named with
//! its role and port.

use btfrig_calibrate::dark_flat::{calibrate, DarkFlatCamera, DarkFlatResult, DarkFlatShot, RadiometricPlan};
use btfrig_calibrate::emva::{characterise, EmvaInput, EmvaResult, ExposureStats, SensorPlan};
use btfrig_calibrate::leds::{fit_leds, LedCalibrationFile, LedFitOptions, LedShot};
use btfrig_calibrate::light::{calibrate_light, LightCalibration, LightPlan, TileCamera};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::Direction;
use btfrig_hw::{Camera, LedPattern, MoveOptions};
use btfrig_imaging::dark_flat::FrameAverage;

use crate::backend::{self, BackendRegistry, CalibrationOpenRequest, MountedTarget, OpenedRig, RigTime};
use crate::preflight::Role;
use crate::RunError;

/// Read-out timeout of every capture, seconds (longer than any calibration exposure).
const READ_TIMEOUT_S: f64 = 60.0;

/// Where and how a calibration opens its rig.
#[derive(Clone)]
pub struct CalibrationSession<'a> {
    /// The rig config.
    pub rig: &'a RigConfig,
    /// The backends (`backend::installed()` unless a library user passes others).
    pub registry: BackendRegistry,
    /// Seed of a simulated rig's noise.
    pub seed: u64,
    /// The time the devices run on.
    pub time: RigTime,
}

impl<'a> CalibrationSession<'a> {
    /// A session on `rig` through the process's installed backends, on the time its devices
    /// need ([`RigTime::for_rig`]).
    pub fn installed(rig: &'a RigConfig, seed: u64) -> Self {
        CalibrationSession { rig, registry: backend::installed(), seed, time: RigTime::for_rig(rig) }
    }

    fn runtime(&self) -> Result<tokio::runtime::Runtime, RunError> {
        self.time.runtime()
    }

    /// Opens the rig with `target` mounted; a failure names the devices `calibration` needs,
    /// with their kinds and ports.
    async fn open(&self, target: &MountedTarget, cameras: &[usize], calibration: &str) -> Result<OpenedRig, RunError> {
        let backend = self.registry.for_rig(self.rig)?;
        backend
            .open_calibration(CalibrationOpenRequest {
                rig: self.rig,
                target,
                cameras,
                seed: self.seed,
                time: self.time,
            })
            .await
            .map_err(|e| {
                let entries = self.rig.devices.entries();
                let named: Vec<String> = needed_devices(self.rig, calibration)
                    .iter()
                    .filter_map(|(role, why)| {
                        entries.iter().find(|(r, _)| r == role).map(|(r, d)| format!("{} ({why})", describe(r, d)))
                    })
                    .collect();
                RunError::Rig(format!(
                    "opening rig {} for calibrate {calibration} with a {} mounted: {e}; the devices it needs: {}",
                    self.rig.rig.name,
                    target.name(),
                    named.join(", ")
                ))
            })
    }
}

/// The devices a calibration needs, by role (`[devices.ROLE]`), with what each is for.
pub fn needed_devices(rig: &RigConfig, calibration: &str) -> Vec<(&'static str, &'static str)> {
    let dome = rig.dome.is_some();
    match (calibration, dome) {
        ("leds", _) => vec![("led_array", "lights the white tile"), ("camera", "photographs it")],
        ("light", _) => vec![
            ("robot", "turns the white tile"),
            ("rail", "moves the camera"),
            ("lamp", "lights the tile"),
            ("camera", "photographs it"),
        ],
        (_, true) => vec![("led_array", "lights the uniform field"), ("camera", "takes the frames")],
        (_, false) => vec![("lamp", "lights the uniform field"), ("camera", "takes the frames")],
    }
}

/// Checks, before opening anything, that the rig has every device `calibration` needs, that
/// a registered backend opens them and accepts their options, and asks each what a run's
/// preflight asks ([`crate::preflight`]: identity, health, homing of real devices). A missing,
/// refused or failing device is named with its role, kind and port.
pub fn check_devices(session: &CalibrationSession<'_>, calibration: &str) -> Result<(), RunError> {
    let rig = session.rig;
    let entries = rig.devices.entries();
    let mut problems = Vec::new();
    for (role, why) in needed_devices(rig, calibration) {
        if !entries.iter().any(|(r, _)| *r == role) {
            problems.push(format!("[devices.{role}] is missing: calibrate {calibration} needs it ({why})"));
        }
    }
    if !problems.is_empty() {
        return Err(RunError::Rig(format!("rig {}: {}", rig.rig.name, problems.join("; "))));
    }
    let backend = session.registry.for_rig(rig)?;
    backend.check_rig(rig).map_err(|e| {
        let named: Vec<String> = entries.iter().map(|(r, e)| describe(r, e)).collect();
        RunError::Rig(format!("rig {}: {e} (devices: {})", rig.rig.name, named.join(", ")))
    })?;
    let roles: Vec<Role> = needed_devices(rig, calibration).iter().filter_map(|(r, _)| Role::from_name(r)).collect();
    crate::preflight::check_devices(rig, &roles, &session.registry)?.into_result()?;
    Ok(())
}

/// `role (kind "k", port P)` for messages.
fn describe(role: &str, e: &btfrig_core::config::devices::DeviceEntry) -> String {
    match e.options.get("port").and_then(|p| p.as_str()) {
        Some(port) => format!("{role} (kind {:?}, port {port})", e.kind),
        None => format!("{role} (kind {:?})", e.kind),
    }
}

/// A device error as a run error naming the device's role and port.
fn dev_err(rig: &RigConfig, role: &str, e: impl std::fmt::Display) -> RunError {
    let who =
        rig.devices.entries().into_iter().find(|(r, _)| *r == role).map_or(role.to_string(), |(r, e)| describe(r, e));
    RunError::Rig(format!("{who}: {e}"))
}

/// Sets exposure and gain and takes one frame.
async fn shoot(rig: &RigConfig, camera: &mut dyn Camera, exposure_s: f64, gain: f64) -> Result<RawFrame, RunError> {
    let s = camera.settings();
    if s.exposure_s != exposure_s {
        camera.set_exposure_s(exposure_s).await.map_err(|e| dev_err(rig, "camera", e))?;
    }
    if s.gain != gain {
        camera.set_gain(gain).await.map_err(|e| dev_err(rig, "camera", e))?;
    }
    camera.capture(READ_TIMEOUT_S).await.map_err(|e| dev_err(rig, "camera", e))
}

/// Takes `n` frames at one setting.
async fn series(
    rig: &RigConfig,
    camera: &mut dyn Camera,
    exposure_s: f64,
    gain: f64,
    n: usize,
) -> Result<Vec<RawFrame>, RunError> {
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        v.push(shoot(rig, camera, exposure_s, gain).await?);
    }
    Ok(v)
}

/// The brightest channel's mean over the centre box of `fraction`, as a fraction of the
/// frame's range above black (the metering of every procedure here).
pub fn centre_level(frame: &RawFrame, fraction: f64) -> f64 {
    let (x0, y0, x1, y1) = btfrig_calibrate::emva::centre_box(frame.width, frame.height, fraction);
    let (mut s, mut n) = ([0.0f64; 3], [0usize; 3]);
    for y in y0..y1 {
        for x in x0..x1 {
            let c = frame.meta.bayer.map_or(1, |b| b.channel_at(x, y));
            s[c] += f64::from(frame.data[y * frame.width + x]);
            n[c] += 1;
        }
    }
    let black = f64::from(frame.meta.black_level);
    let range = (f64::from(frame.meta.white_level) - black).max(1.0);
    (0..3).filter(|&c| n[c] > 0).map(|c| (s[c] / n[c] as f64 - black) / range).fold(0.0, f64::max)
}

/// Meters: the exposure at which the centre's brightest channel reaches `level` of full
/// scale, found from frames starting at `start_s` (longer while too dark, shorter while
/// saturated), within the camera's range.
async fn meter(
    rig: &RigConfig,
    camera: &mut dyn Camera,
    start_s: f64,
    gain: f64,
    level: f64,
    fraction: f64,
) -> Result<f64, RunError> {
    let (lo, hi) = camera.capabilities().exposure_range_s;
    let mut t = start_s.clamp(lo, hi);
    for _ in 0..24 {
        let f = centre_level(&shoot(rig, camera, t, gain).await?, fraction);
        if f > 0.95 {
            t = (t / 4.0).max(lo);
        } else if f < 0.05 {
            t = (t * 8.0).min(hi);
        } else {
            return Ok((t * level / f).clamp(lo, hi));
        }
        if t == lo || t == hi {
            let f = centre_level(&shoot(rig, camera, t, gain).await?, fraction);
            if (0.05..=0.95).contains(&f) {
                return Ok((t * level / f).clamp(lo, hi));
            }
            return Err(RunError::Rig(format!(
                "metering: the field's centre reads {:.1} % of full scale at the camera's {} exposure of {t} s: \
                 the light is {}",
                100.0 * f,
                if t == lo { "shortest" } else { "longest" },
                if t == lo { "too bright for the camera" } else { "off or blocked (is the lens capped?)" }
            )));
        }
    }
    Err(RunError::Rig("metering did not settle in 24 frames: is the light flickering?".into()))
}

/// The camera (and what lights the field) of an opened rig, lights switched for `lit`.
struct Opened {
    rig: OpenedRig,
}

impl Opened {
    fn camera(&mut self) -> &mut dyn Camera {
        match &mut self.rig {
            OpenedRig::Gonio(g) => &mut *g.camera,
            OpenedRig::Dome(d) => &mut *d.devices.cameras[0],
        }
    }

    /// Switches the rig's light on (lamp on and warmed up; every LED at full output) or off.
    async fn light(&mut self, cfg: &RigConfig, on: bool) -> Result<(), RunError> {
        match &mut self.rig {
            OpenedRig::Gonio(g) => {
                g.lamp.set_on(on).await.map_err(|e| dev_err(cfg, "lamp", e))?;
                if on {
                    let warm = g.lamp.capabilities().warm_up_s;
                    g.lamp.wait_ready(warm + 60.0).await.map_err(|e| dev_err(cfg, "lamp", e))?;
                }
            }
            OpenedRig::Dome(d) => {
                let n = d.devices.leds.count();
                let p = LedPattern { intensities: vec![if on { 1.0 } else { 0.0 }; n] };
                d.devices.leds.set_pattern(&p).await.map_err(|e| dev_err(cfg, "led_array", e))?;
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------
// Dark and flat fields.

/// The devices behind [`DarkFlatCamera`]: the capped rig for dark frames, the uniform field
/// for flats (opened when the first is asked for), each flat group's exposure metered to the
/// plan's level.
struct DeviceDarkFlat<'s, 'a> {
    session: &'s CalibrationSession<'a>,
    rt: &'s tokio::runtime::Runtime,
    cameras: Vec<usize>,
    level: f64,
    centre_fraction: f64,
    current: Option<(bool, Opened)>,
    metered: Option<(u64, f64)>,
}

impl DeviceDarkFlat<'_, '_> {
    fn take(&mut self, shot: &DarkFlatShot) -> Result<RawFrame, RunError> {
        let cfg = self.session.rig;
        if self.current.as_ref().map(|c| c.0) != Some(shot.flat) {
            self.current = None; // the operator swaps cap and field
            let target = if shot.flat { MountedTarget::UniformField } else { MountedTarget::Capped };
            let mut o = Opened { rig: self.rt.block_on(self.session.open(&target, &self.cameras, "radiometric"))? };
            self.rt.block_on(o.light(cfg, shot.flat))?;
            self.current = Some((shot.flat, o));
        }
        let (level, fraction) = (self.level, self.centre_fraction);
        let o = &mut self.current.as_mut().expect("opened above").1;
        self.rt.block_on(async {
            let cam = o.camera();
            if let Err(e) = cam.set_f_number(shot.f_number).await {
                if e.kind() != btfrig_hw::ErrorKind::Unsupported || shot.f_number != cfg.camera.f_number {
                    return Err(dev_err(cfg, "camera", e));
                }
            }
            let mut t = shot.exposure_s;
            if shot.flat {
                t = match self.metered {
                    Some((g, t)) if g == shot.group => t,
                    _ => {
                        let t = meter(cfg, cam, shot.exposure_s, shot.gain, level, fraction).await?;
                        self.metered = Some((shot.group, t));
                        t
                    }
                };
            }
            let mut f = shoot(cfg, cam, t, shot.gain).await?;
            f.meta.f_number = Some(shot.f_number);
            Ok(f)
        })
    }
}

impl DarkFlatCamera for DeviceDarkFlat<'_, '_> {
    fn capture(&mut self, shot: &DarkFlatShot) -> Result<RawFrame, String> {
        self.take(shot).map_err(|e| e.to_string())
    }
}

/// Dark frames (lens capped) and master flats (uniform field, each metered to the plan's
/// `flat.level`) captured on the rig, fitted by `btfrig_calibrate::dark_flat::calibrate`. A
/// dome's or camera array's camera `camera`.
pub fn capture_dark_flat(
    session: &CalibrationSession<'_>,
    plan: &RadiometricPlan,
    camera: usize,
    progress: impl FnMut(&str),
) -> Result<DarkFlatResult, RunError> {
    check_devices(session, "radiometric")?;
    let rt = session.runtime()?;
    let mut dev = DeviceDarkFlat {
        session,
        rt: &rt,
        cameras: vec![camera],
        level: plan.flat.level,
        centre_fraction: plan.flat.centre_fraction,
        current: None,
        metered: None,
    };
    let r = calibrate(session.rig, plan, &mut dev, progress).map_err(|e| RunError::Rig(e.to_string()));
    drop(dev);
    r
}

// ---------------------------------------------------------------------------------------
// Sensor characterisation (EMVA 1288).

/// What [`capture_sensor`] measured, with the exposures it chose.
#[derive(Debug, Clone)]
pub struct SensorCapture {
    /// The figures.
    pub result: EmvaResult,
    /// The photon-transfer exposures, s.
    pub ptc_exposures_s: Vec<f64>,
    /// The PRNU average's exposure, s.
    pub spatial_exposure_s: f64,
    /// Frames taken.
    pub frames: usize,
}

/// The EMVA 1288 series captured on the rig: on the uniform field (lamp or LEDs on) the
/// photon-transfer exposures (metered: evenly spaced up to `max_fraction` of full scale) and
/// the PRNU average; with the lens capped the dark frames at each of those exposures, the long
/// dark series and the PRNU's dark average. A dome's or camera array's camera `camera`.
pub fn capture_sensor(
    session: &CalibrationSession<'_>,
    plan: &SensorPlan,
    camera: usize,
    mut progress: impl FnMut(&str),
) -> Result<SensorCapture, RunError> {
    let problems = plan.problems();
    if !problems.is_empty() {
        return Err(RunError::Input { what: format!("sensor plan {}", plan.name), message: problems.join("; ") });
    }
    check_devices(session, "sensor")?;
    let cfg = session.rig;
    let rt = session.runtime()?;
    let (g, p) = (plan.gain, &plan.photon_transfer);
    let avg = |frames: &[RawFrame], what: &'static str| {
        FrameAverage::of(frames, what).map_err(|e| RunError::Rig(e.to_string()))
    };
    let stats = |a: &FrameAverage| ExposureStats::of(a, p.centre_fraction).map_err(|e| RunError::Rig(e.to_string()));
    let mut count = 0usize;
    rt.block_on(async {
        // The lit half.
        let mut lit = Opened { rig: session.open(&MountedTarget::UniformField, &[camera], "sensor").await? };
        lit.light(cfg, true).await?;
        let cam = lit.camera();
        let (lo, hi) = cam.capabilities().exposure_range_s;
        let t_half = meter(cfg, cam, 0.01, g, 0.5, p.centre_fraction).await?;
        let full_s = 2.0 * t_half; // the exposure that fills the centre's brightest channel
        let ptc_t: Vec<f64> =
            (1..=p.steps).map(|i| (full_s * p.max_fraction * i as f64 / p.steps as f64).clamp(lo, hi)).collect();
        let t_spatial = (full_s * plan.spatial.level).clamp(lo, hi);
        progress(&format!(
            "metered: the field fills full scale in {full_s:.5} s; {} exposures up to {:.5} s",
            p.steps,
            ptc_t.last().copied().unwrap_or(0.0)
        ));
        let mut lit_stats = Vec::new();
        for &t in &ptc_t {
            let f = series(cfg, cam, t, g, p.frames).await?;
            count += f.len();
            let st = stats(&avg(&f, "photon-transfer frames")?)?;
            progress(&format!(
                "  {t:.5} s: mean {:.1} DN, temporal variance {:.1} DN² (green), saturated {:.1} % (green)",
                st.mean_dn[1],
                st.var_dn2[1],
                100.0 * st.saturated_fraction[1]
            ));
            lit_stats.push(st);
        }
        let f = series(cfg, cam, t_spatial, g, plan.spatial.frames).await?;
        count += f.len();
        let spatial_lit = avg(&f, "PRNU frames")?;
        drop(f);
        progress(&format!("lit: {} frames", count));
        drop(lit);

        // The dark half.
        let mut dark = Opened { rig: session.open(&MountedTarget::Capped, &[camera], "sensor").await? };
        dark.light(cfg, false).await?;
        let cam = dark.camera();
        let mut ptc = Vec::new();
        for (&t, l) in ptc_t.iter().zip(lit_stats) {
            let f = series(cfg, cam, t, g, p.frames).await?;
            count += f.len();
            ptc.push((l, stats(&avg(&f, "photon-transfer dark frames")?)?));
        }
        let f = series(cfg, cam, t_spatial, g, plan.spatial.frames).await?;
        count += f.len();
        let spatial_dark = avg(&f, "PRNU dark frames")?;
        let mut dark_series = Vec::new();
        let mut longest: Option<FrameAverage> = None;
        let t_max = plan.dark.exposures_s.iter().copied().fold(0.0, f64::max);
        for &t in &plan.dark.exposures_s {
            let f = series(cfg, cam, t.clamp(lo, hi), g, plan.dark.frames).await?;
            count += f.len();
            let a = avg(&f, "dark frames")?;
            dark_series.push(stats(&a)?);
            if t == t_max {
                longest = Some(a);
            }
        }
        progress(&format!("dark: {} frames in all", count));
        let dsnu_dark = longest.expect("the plan has exposures");
        let result = characterise(&EmvaInput {
            dark_series: &dark_series,
            ptc: &ptc,
            dsnu_dark: &dsnu_dark,
            prnu: (&spatial_lit, &spatial_dark),
            hot_threshold_e_per_s: plan.dark.hot_threshold_e_per_s,
            prnu_radius: plan.spatial.radius,
        })
        .map_err(|e| RunError::Rig(format!("sensor characterisation: {e}")))?;
        Ok(SensorCapture { result, ptc_exposures_s: ptc_t, spatial_exposure_s: t_spatial, frames: count })
    })
}

// ---------------------------------------------------------------------------------------
// The lamp from a white tile.

/// Frames already captured through the devices, handed to `calibrate_light` in its order.
struct CapturedTile {
    exposure_s: f64,
    frames: Vec<(JointState, RawFrame)>,
}

impl TileCamera for CapturedTile {
    fn exposure_for_white(&self, _fraction: f64) -> f64 {
        self.exposure_s
    }

    fn capture(&self, frame: usize, joints: &JointState, exposure_s: f64) -> Result<RawFrame, String> {
        let (j, f) = self.frames.get(frame).ok_or_else(|| format!("frame {frame} was not captured"))?;
        if j != joints || exposure_s != self.exposure_s {
            return Err(format!("frame {frame} was captured at other joints or exposure"));
        }
        Ok(f.clone())
    }
}

/// The lamp's power and colour from the white tile (albedo `plan.reference_albedo`) on the
/// holder: the rig homes, the lamp warms up, the exposure is metered on the tile facing the
/// lamp (a white reflector at `plan.exposure_fraction` of full scale), then the robot and
/// rail take every capture of the plan; `btfrig_calibrate::light::calibrate_light` measures
/// the frames.
pub fn capture_light(
    session: &CalibrationSession<'_>,
    plan: &LightPlan,
    source: String,
) -> Result<LightCalibration, RunError> {
    let problems = plan.problems();
    if !problems.is_empty() {
        return Err(RunError::Input { what: format!("light plan {}", plan.name), message: problems.join("; ") });
    }
    check_devices(session, "light")?;
    let cfg = session.rig;
    let gonio = Gonio::new(cfg.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?;
    let mut joints = Vec::new();
    for (i, c) in plan.captures.iter().enumerate() {
        let light = Direction::from_degrees(c.light_theta_deg, c.light_phi_deg);
        let view = Direction::from_degrees(c.view_theta_deg, c.view_phi_deg);
        let j = gonio.ik(light, view).map_err(|e| RunError::Input {
            what: format!("light plan capture {i}"),
            message: format!("unreachable: {e:?}"),
        })?;
        joints.push(j);
    }
    let rt = session.runtime()?;
    let tile = rt.block_on(async {
        let target = MountedTarget::WhiteTile { albedo: plan.reference_albedo };
        let OpenedRig::Gonio(mut g) = session.open(&target, &[], "light").await? else {
            return Err(RunError::Rig(format!(
                "rig {}: the light calibration is a gonioreflectometer's",
                cfg.rig.name
            )));
        };
        let opts = MoveOptions::default();
        let (r, t) = tokio::join!(g.robot.home(opts), g.rail.home(opts));
        r.map_err(|e| dev_err(cfg, "robot", e))?;
        t.map_err(|e| dev_err(cfg, "rail", e))?;
        g.lamp.set_on(true).await.map_err(|e| dev_err(cfg, "lamp", e))?;
        let warm = g.lamp.capabilities().warm_up_s;
        g.lamp.wait_ready(warm + 60.0).await.map_err(|e| dev_err(cfg, "lamp", e))?;
        // Meter on the tile with the lamp at the normal: the tile fills the centre of view.
        let normal = gonio
            .ik(
                Direction::from_degrees(0.0, 0.0),
                Direction::from_degrees(plan.captures[0].view_theta_deg, plan.captures[0].view_phi_deg),
            )
            .map_err(|e| RunError::Rig(format!("metering pose unreachable: {e:?}")))?;
        move_to(cfg, &mut *g.robot, &mut *g.rail, &normal).await?;
        let level = plan.exposure_fraction * plan.reference_albedo;
        let exposure_s = meter(cfg, &mut *g.camera, 0.01, 1.0, level, 0.05).await?;
        let mut frames = Vec::new();
        for j in &joints {
            move_to(cfg, &mut *g.robot, &mut *g.rail, j).await?;
            for _ in 0..plan.repeats {
                frames.push((*j, shoot(cfg, &mut *g.camera, exposure_s, 1.0).await?));
            }
        }
        Ok(CapturedTile { exposure_s, frames })
    })?;
    calibrate_light(cfg, plan, &tile, source).map_err(|e| RunError::Rig(e.to_string()))
}

async fn move_to(
    cfg: &RigConfig,
    robot: &mut dyn btfrig_hw::Robot,
    rail: &mut dyn btfrig_hw::Rail,
    j: &JointState,
) -> Result<(), RunError> {
    let opts = MoveOptions::default();
    let (r, t) = tokio::join!(robot.move_to_rad(j.robot, opts), rail.move_to_rad(j.rail, opts));
    r.map_err(|e| dev_err(cfg, "robot", e))?;
    t.map_err(|e| dev_err(cfg, "rail", e))?;
    Ok(())
}

// ---------------------------------------------------------------------------------------
// LEDs and flashes.

/// How the LED calibration lights the tile.
#[derive(Debug, Clone)]
pub struct LedCaptureOptions {
    /// Frames per light (one at a time) or per pattern (multiplexed).
    pub repeats: usize,
    /// Hadamard S-matrix patterns (about half the lights on per frame), demultiplexed, instead
    /// of one light at a time.
    pub multiplexed: bool,
    /// An LED dome's exposure is metered so the brightest light's tile signal reaches this
    /// fraction of full scale (a flash's exposure is its pulse).
    pub exposure_fraction: f64,
    /// The fit's options.
    pub fit: LedFitOptions,
}

/// What [`capture_leds`] measured.
#[derive(Debug, Clone)]
pub struct LedCapture {
    /// The fitted file.
    pub file: LedCalibrationFile,
    /// Exposure of the frames, s.
    pub exposure_s: f64,
    /// Frames taken.
    pub frames: usize,
}

/// Each light's power and colour from the white tile on the turntable: an LED dome's lights
/// seen by camera 0, a camera array's flash `j` by its own camera `j`; one light at a time, or
/// by Hadamard patterns demultiplexed into one image per light (`btfrig-mux`). The frames go
/// to `btfrig_calibrate::leds::fit_leds` with the processing camera `camera`.
pub fn capture_leds(
    session: &CalibrationSession<'_>,
    camera: &CameraModel,
    opts: &LedCaptureOptions,
) -> Result<LedCapture, RunError> {
    let (shots, exposure_s, frames) = capture_led_shots(session, opts, None)?;
    let mut fit = opts.fit.clone();
    if opts.multiplexed {
        fit.method = format!("white reference tile lit by Hadamard S-matrix patterns, demultiplexed ({})", fit.method);
    }
    let file = fit_leds(session.rig, camera, &shots, &fit).map_err(|e| RunError::Rig(e.to_string()))?;
    Ok(LedCapture { file, exposure_s, frames })
}

/// The frames of [`capture_leds`] (one per light and repeat, demultiplexed when multiplexed),
/// their exposure and how many frames were taken; with `lights`, of those lights only, one
/// at a time. A light's frames are the same whichever others are taken (the simulated
/// cameras' noise is keyed by what a frame shows), so a few lights check a whole file.
pub fn capture_led_shots(
    session: &CalibrationSession<'_>,
    opts: &LedCaptureOptions,
    lights: Option<&[usize]>,
) -> Result<(Vec<LedShot>, f64, usize), RunError> {
    check_devices(session, "leds")?;
    let cfg = session.rig;
    let dome = cfg.dome.as_ref().ok_or_else(|| {
        RunError::Rig(format!("rig {}: LED calibration needs an LED dome or a camera array", cfg.rig.name))
    })?;
    let n = dome.led_count();
    let flash = dome.is_flash();
    let lights: Vec<usize> = lights.map_or_else(|| (0..n).collect(), <[usize]>::to_vec);
    if let Some(j) = lights.iter().find(|&&j| j >= n) {
        return Err(RunError::Input { what: "lights".into(), message: format!("light {j}: the rig has {n} (0..{n})") });
    }
    if opts.multiplexed && lights.len() != n {
        return Err(RunError::Input {
            what: "lights".into(),
            message: "multiplexed patterns light every light: a subset is measured one light at a time".into(),
        });
    }
    let cameras: Vec<usize> = if flash { lights.clone() } else { vec![0] };
    let repeats = opts.repeats.max(1);
    let rt = session.runtime()?;
    rt.block_on(async {
        let target = MountedTarget::WhiteTile { albedo: opts.fit.reference_albedo };
        let OpenedRig::Dome(mut d) = session.open(&target, &cameras, "leds").await? else {
            return Err(RunError::Rig(format!("rig {}: not opened as a dome", cfg.rig.name)));
        };
        let dev = &mut d.devices;
        if let Some(t) = dev.turntable.as_mut() {
            t.home(MoveOptions::default()).await.map_err(|e| dev_err(cfg, "turntable", e))?;
            t.move_to_rad(0.0, MoveOptions::default()).await.map_err(|e| dev_err(cfg, "turntable", e))?;
        }
        let leds_err = |e| dev_err(cfg, "led_array", e);
        let exposure_s = match &dome.flash {
            Some(f) => f.duration_s,
            None => {
                // Metered on LED 0; the lights differ by up to ~20 %, so meter below the target.
                dev.leds.set_pattern(&LedPattern::single(n, 0)).await.map_err(leds_err)?;
                let level = if opts.multiplexed { opts.exposure_fraction } else { opts.exposure_fraction / 1.2 };
                let one = meter(cfg, &mut *dev.cameras[0], 0.01, 1.0, level, 0.1).await?;
                if opts.multiplexed {
                    // About half the lights on in each pattern.
                    let s = btfrig_mux::SMatrix::for_sources(n).map_err(|e| RunError::Rig(e.to_string()))?;
                    let lit = s.s.lit_per_pattern() as f64;
                    let (lo, _) = dev.cameras[0].capabilities().exposure_range_s;
                    (one / (lit * 1.2)).max(lo)
                } else {
                    one
                }
            }
        };
        let mut shots = Vec::new();
        let mut frames = 0usize;
        if !opts.multiplexed {
            for (i, &j) in lights.iter().enumerate() {
                dev.leds.set_pattern(&LedPattern::single(n, j)).await.map_err(leds_err)?;
                // A flash's own camera (opened in the order of `lights`); an LED's camera 0.
                let (c, device) = if flash { (j, i) } else { (0, 0) };
                for _ in 0..repeats {
                    let frame = shoot(cfg, &mut *dev.cameras[device], exposure_s, 1.0).await?;
                    frames += 1;
                    shots.push(LedShot { light: j, camera: c, turntable_rad: 0.0, frame });
                }
            }
        } else {
            if flash {
                return Err(RunError::Input {
                    what: "--multiplexed".into(),
                    message:
                        "a camera array's flash j is seen by its own camera j only: calibrate its flashes one at a time"
                            .into(),
                });
            }
            let padded = btfrig_mux::SMatrix::for_sources(n).map_err(|e| RunError::Rig(e.to_string()))?;
            let s = &padded.s;
            let order = s.order();
            let mut pattern_frames: Vec<Vec<RawFrame>> = Vec::with_capacity(order);
            for k in 0..order {
                let row = s.row(k);
                let p = LedPattern { intensities: (0..n).map(|j| f64::from(row[j])).collect() };
                dev.leds.set_pattern(&p).await.map_err(leds_err)?;
                pattern_frames.push(series(cfg, &mut *dev.cameras[0], exposure_s, 1.0, repeats).await?);
                frames += repeats;
            }
            shots = demultiplex(cfg, s, n, &pattern_frames)?;
        }
        dev.leds.all_off().await.map_err(leds_err)?;
        Ok((shots, exposure_s, frames))
    })
}

/// Per pattern frames (each a stack of repeats) to one frame per light: each repeat's
/// patterns demultiplexed (above black, then the black level added back and rounded, so
/// `fit_leds` reads them as single-light frames; the dark signal, the same in every pattern,
/// comes out as every light's own, as in a single-light frame).
fn demultiplex(
    cfg: &RigConfig,
    s: &btfrig_mux::SMatrix,
    n: usize,
    pattern_frames: &[Vec<RawFrame>],
) -> Result<Vec<LedShot>, RunError> {
    let order = s.order();
    let demuxer = btfrig_mux::Demuxer::new(s, &btfrig_mux::DemuxParams::default())
        .map_err(|e| RunError::Rig(format!("demultiplexer: {e}")))?;
    let repeats = pattern_frames.first().map_or(0, Vec::len);
    let first = &pattern_frames[0][0];
    let (w, h) = (first.width, first.height);
    let cols = w * h;
    let black = f32::from(first.meta.black_level);
    // A pattern frame's dark signal is in every pattern once; demultiplexing spreads it as
    // 2 / (n + 1) per light (the rows of S⁻¹ sum to that). Subtract it before and add one
    // dark signal after, so a light's image holds what a single-light frame would.
    let dark_dn = (cfg.sensor.dark_current_e_per_s * first.meta.exposure_s * first.meta.gain
        / cfg.sensor.electrons_per_dn) as f32;
    let mut shots = Vec::new();
    for r in 0..repeats {
        let mut stack = vec![0.0f32; order * cols];
        for (k, frames) in pattern_frames.iter().enumerate() {
            let f = &frames[r];
            for (o, &v) in stack[k * cols..(k + 1) * cols].iter_mut().zip(&f.data) {
                *o = f32::from(v) - black - dark_dn;
            }
        }
        let images = demuxer.demux(&stack, cols).map_err(|e| RunError::Rig(format!("demultiplexing: {e}")))?;
        for j in 0..n {
            let mut frame = first.clone();
            frame.data = images[j * cols..(j + 1) * cols]
                .iter()
                .map(|&v| (v + black + dark_dn).round().clamp(0.0, f32::from(u16::MAX)) as u16)
                .collect();
            shots.push(LedShot { light: j, camera: 0, turntable_rad: 0.0, frame });
        }
    }
    Ok(shots)
}
