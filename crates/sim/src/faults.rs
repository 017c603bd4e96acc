//! Fault injection: scenarios read from `sim/faults/*.toml` and the per-device gate that
//! applies them.
//!
//! Every device call (every async method of a device trait) counts as one call of that
//! device, numbered from 1. A scenario can make chosen calls time out, take a device
//! off-line from a call on (and bring it back after some calls), drop or corrupt frames,
//! keep LEDs stuck, make the lamp drift, and hide the holder plate's markers from the camera
//! ([`HiddenMarkers`], applied by the frame source wrapper [`MarkerOccluder`]). Random faults draw from a ChaCha stream seeded
//! from the rig seed and the device name, so the same seed and the same calls give the same
//! faults. The format is documented in `docs/devices.md`.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use btfrig_core::camera::CameraModel;
use btfrig_core::config::plate::{MarkerPlacement, PlateConfig};
use btfrig_core::frame::RawFrame;
use btfrig_core::pose::ScenePose;
use btfrig_core::ConfigError;
use btfrig_hw::{DeviceError, ErrorKind, SharedClock};
use btfrig_render::rig_scene::RigScene;
use nalgebra::{Point2, Point3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::world::{FaultKind, SimWorld};
use crate::{FrameSource, SensorFormat, TrueState};

/// A device of the rig, as named in fault scenarios and in `[devices]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceRole {
    /// The robot orienting the sample.
    Robot,
    /// The camera rail.
    Rail,
    /// The turntable.
    Turntable,
    /// The lamp.
    Lamp,
    /// The LED array.
    LedArray,
    /// The camera.
    Camera,
}

impl DeviceRole {
    /// The name used in configs and error messages.
    pub const fn as_str(self) -> &'static str {
        match self {
            DeviceRole::Robot => "robot",
            DeviceRole::Rail => "rail",
            DeviceRole::Turntable => "turntable",
            DeviceRole::Lamp => "lamp",
            DeviceRole::LedArray => "led_array",
            DeviceRole::Camera => "camera",
        }
    }
}

/// A device times out on chosen calls, or on each call with a probability.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeoutFault {
    /// Which device.
    pub device: DeviceRole,
    /// Call numbers (1-based) that time out.
    #[serde(default)]
    pub calls: Vec<u64>,
    /// Probability that any other call times out, in `[0, 1]`.
    #[serde(default)]
    pub probability: f64,
}

/// A device loses its link at a call and possibly gets it back.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DisconnectFault {
    /// Which device.
    pub device: DeviceRole,
    /// First call (1-based) that finds the device disconnected.
    pub at_call: u64,
    /// Number of calls that fail before the link is back; absent = never comes back.
    #[serde(default)]
    pub reconnect_after_calls: Option<u64>,
}

/// A device reports an internal error on chosen calls: `ErrorKind::Other`, which no retry
/// can help (the engine pauses the run for an operator).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FailureFault {
    /// Which device.
    pub device: DeviceRole,
    /// Call numbers (1-based) that fail.
    pub calls: Vec<u64>,
}

/// Frames lost or damaged on the way from camera to host.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameFault {
    /// Read-out numbers (1-based count of `read_frame` calls) that are hit.
    #[serde(default)]
    pub frames: Vec<u64>,
    /// Probability that any other read-out is hit, in `[0, 1]`.
    #[serde(default)]
    pub probability: f64,
}

/// State a stuck LED is stuck in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StuckState {
    /// Always lit at full output.
    On,
    /// Never lit.
    Off,
}

/// An LED that ignores its commands.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StuckLed {
    /// Index of the LED in the array.
    pub index: usize,
    /// What it is stuck at.
    pub state: StuckState,
}

pub use crate::world::LampDrift;

/// Markers of the holder plate covered by a dark object (a cable, a hand) in chosen frames,
/// so that registration has too few markers: the way to test a plan's registration failure
/// policy end to end.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HiddenMarkers {
    /// Frame numbers (1-based count of frames rendered, i.e. of read-outs that were not
    /// dropped) whose markers are covered.
    #[serde(default)]
    pub frames: Vec<u64>,
    /// Probability that any other frame's markers are covered, in `[0, 1]`. Drawn from the
    /// frame's noise seed, so a resumed run covers the same captures.
    #[serde(default)]
    pub probability: f64,
    /// Ids of the markers covered; empty (default): all of them.
    #[serde(default)]
    pub markers: Vec<u32>,
}

impl HiddenMarkers {
    /// Does the scenario hide anything?
    pub fn is_active(&self) -> bool {
        !self.frames.is_empty() || self.probability > 0.0
    }
}

/// A fault scenario: the contents of one `sim/faults/*.toml` file.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultScenario {
    /// What the scenario exercises.
    #[serde(default)]
    pub description: String,
    /// Operation timeouts (`[[timeouts]]`).
    #[serde(default)]
    pub timeouts: Vec<TimeoutFault>,
    /// Disconnects (`[[disconnects]]`).
    #[serde(default)]
    pub disconnects: Vec<DisconnectFault>,
    /// Fatal, non-retryable device errors (`[[failures]]`).
    #[serde(default)]
    pub failures: Vec<FailureFault>,
    /// Frames that never arrive (`[dropped_frames]`): the read-out times out.
    #[serde(default)]
    pub dropped_frames: FrameFault,
    /// Frames that arrive damaged (`[corrupt_frames]`): bits flip on the link, the checksum
    /// check fails.
    #[serde(default)]
    pub corrupt_frames: FrameFault,
    /// LEDs stuck on or off (`[[stuck_leds]]`).
    #[serde(default)]
    pub stuck_leds: Vec<StuckLed>,
    /// Lamp output drift (`[lamp_drift]`).
    #[serde(default)]
    pub lamp_drift: Option<LampDrift>,
    /// Plate markers covered in chosen frames (`[hidden_markers]`); applied by
    /// [`MarkerOccluder`], a wrapper of the rig's frame source.
    #[serde(default)]
    pub hidden_markers: HiddenMarkers,
}

impl FaultScenario {
    /// No faults.
    pub fn none() -> Self {
        Self::default()
    }

    /// Parses and validates a scenario; `origin` names the file in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let s: FaultScenario = toml::from_str(text)
            .map_err(|e| ConfigError::Parse { path: origin.to_string(), message: e.to_string() })?;
        let mut errors = Vec::new();
        s.validate(&mut errors);
        ConfigError::from_list(errors)?;
        Ok(s)
    }

    /// Appends every out-of-range value to `errors` (fields prefixed `faults.`).
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        let prob = |errors: &mut Vec<ConfigError>, field: String, p: f64| {
            if !(0.0..=1.0).contains(&p) {
                errors.push(ConfigError::out_of_range(&field, p, "[0, 1]"));
            }
        };
        let calls = |errors: &mut Vec<ConfigError>, field: String, list: &[u64]| {
            if let Some(i) = list.iter().position(|&c| c == 0) {
                errors.push(ConfigError::out_of_range(&format!("{field}[{i}]"), 0, "1.. (calls count from 1)"));
            }
        };
        for (i, t) in self.timeouts.iter().enumerate() {
            prob(errors, format!("faults.timeouts[{i}].probability"), t.probability);
            calls(errors, format!("faults.timeouts[{i}].calls"), &t.calls);
        }
        for (i, f) in self.failures.iter().enumerate() {
            calls(errors, format!("faults.failures[{i}].calls"), &f.calls);
        }
        for (i, d) in self.disconnects.iter().enumerate() {
            if d.at_call == 0 {
                errors.push(ConfigError::out_of_range(&format!("faults.disconnects[{i}].at_call"), 0, "1.."));
            }
            if d.reconnect_after_calls == Some(0) {
                errors.push(ConfigError::out_of_range(
                    &format!("faults.disconnects[{i}].reconnect_after_calls"),
                    0,
                    "1.. (omit for never)",
                ));
            }
        }
        prob(errors, "faults.hidden_markers.probability".into(), self.hidden_markers.probability);
        calls(errors, "faults.hidden_markers.frames".into(), &self.hidden_markers.frames);
        for (name, f) in [("dropped_frames", &self.dropped_frames), ("corrupt_frames", &self.corrupt_frames)] {
            prob(errors, format!("faults.{name}.probability"), f.probability);
            calls(errors, format!("faults.{name}.frames"), &f.frames);
        }
        if let Some(d) = &self.lamp_drift {
            if !(0.0..=1.0).contains(&d.start_fraction) {
                errors.push(ConfigError::out_of_range("faults.lamp_drift.start_fraction", d.start_fraction, "[0, 1]"));
            }
            if !(d.warm_up_tau_s > 0.0 && d.warm_up_tau_s <= 86_400.0) {
                errors.push(ConfigError::out_of_range(
                    "faults.lamp_drift.warm_up_tau_s",
                    d.warm_up_tau_s,
                    "(0, 86400] s",
                ));
            }
            if !(d.drift_delay_s.is_finite() && (0.0..=86_400.0).contains(&d.drift_delay_s)) {
                errors.push(ConfigError::out_of_range(
                    "faults.lamp_drift.drift_delay_s",
                    d.drift_delay_s,
                    "[0, 86400] s",
                ));
            }
            // Up to 10 per hour: a short simulated run (minutes) can then drift by percents.
            if !(-10.0..=10.0).contains(&d.drift_per_hour) {
                errors.push(ConfigError::out_of_range(
                    "faults.lamp_drift.drift_per_hour",
                    d.drift_per_hour,
                    "[-10, 10] per hour",
                ));
            }
        }
    }

    /// Checks the scenario against the devices a rig has: every named device exists and
    /// every stuck LED index is below the LED count (0 when there is no LED array).
    pub fn validate_for_rig(&self, present: &[DeviceRole], led_count: usize, errors: &mut Vec<ConfigError>) {
        let allowed = present.iter().map(|r| r.as_str()).collect::<Vec<_>>().join(", ");
        let mut need = |field: String, role: DeviceRole| {
            if !present.contains(&role) {
                errors.push(ConfigError::Unknown { field, value: role.as_str().into(), allowed: allowed.clone() });
            }
        };
        for (i, t) in self.timeouts.iter().enumerate() {
            need(format!("faults.timeouts[{i}].device"), t.device);
        }
        for (i, d) in self.disconnects.iter().enumerate() {
            need(format!("faults.disconnects[{i}].device"), d.device);
        }
        for (i, f) in self.failures.iter().enumerate() {
            need(format!("faults.failures[{i}].device"), f.device);
        }
        for (i, s) in self.stuck_leds.iter().enumerate() {
            if s.index >= led_count {
                errors.push(ConfigError::out_of_range(
                    &format!("faults.stuck_leds[{i}].index"),
                    s.index,
                    &format!("0..{led_count} (the rig's LED count)"),
                ));
            }
        }
    }
}

/// Derives an independent seed for `stream` of `name` from the rig seed (SplitMix64
/// finaliser over a mix of the inputs) so each device and purpose gets its own stream.
pub fn derive_seed(seed: u64, name: &str, stream: u64) -> u64 {
    let mut h: u64 = seed ^ stream.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    for b in name.bytes() {
        h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
    }
    let mut z = h.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A seed from `seed` and a list of 64-bit words (SplitMix64 finaliser after each word):
/// randomness keyed by WHAT happens (a target, a state) rather than by how many calls came
/// before, so a resumed run draws exactly what an uninterrupted one drew at the same step.
pub fn seed_for(seed: u64, words: &[u64]) -> u64 {
    let mut z = seed;
    for &w in words {
        z = (z ^ w).wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
    }
    z
}

/// Timeout of calls that take no timeout argument (status queries, settings), seconds.
pub const COMMAND_TIMEOUT_S: f64 = 5.0;

/// Applies a scenario's call faults to one device: counts calls, answers disconnects and
/// injected timeouts.
#[derive(Debug)]
pub(crate) struct FaultGate {
    name: String,
    calls: u64,
    timeouts: Vec<TimeoutFault>,
    disconnects: Vec<DisconnectFault>,
    failures: Vec<u64>,
    rng: ChaCha8Rng,
    world: SimWorld,
    clock: SharedClock,
}

impl FaultGate {
    pub fn new(role: DeviceRole, scenario: &FaultScenario, seed: u64, world: SimWorld) -> Self {
        let name = role.as_str();
        FaultGate {
            name: name.to_string(),
            calls: 0,
            timeouts: scenario.timeouts.iter().filter(|t| t.device == role).cloned().collect(),
            disconnects: scenario.disconnects.iter().filter(|d| d.device == role).cloned().collect(),
            failures: scenario.failures.iter().filter(|f| f.device == role).flat_map(|f| f.calls.clone()).collect(),
            rng: ChaCha8Rng::seed_from_u64(derive_seed(seed, name, 1)),
            clock: world.clock().clone(),
            world,
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Starts call `op`: fails with `Disconnected` during an outage, or waits `timeout_s`
    /// and fails with `Timeout` when a timeout is injected.
    pub async fn begin(&mut self, op: &str, timeout_s: f64) -> Result<u64, DeviceError> {
        self.calls += 1;
        let n = self.calls;
        for d in &self.disconnects {
            let back = d.reconnect_after_calls.map(|k| d.at_call + k);
            if n >= d.at_call && back.is_none_or(|b| n < b) {
                self.world.log_fault(&self.name, n, FaultKind::Disconnected);
                let when = match back {
                    Some(b) => format!("link expected back at call {b}"),
                    None => "link will not come back".to_string(),
                };
                return Err(DeviceError::new(
                    &self.name,
                    ErrorKind::Disconnected,
                    format!("{op} (call {n}): device not answering since call {}; {when}", d.at_call),
                ));
            }
        }
        if self.failures.contains(&n) {
            self.world.log_fault(&self.name, n, FaultKind::Failure);
            return Err(DeviceError::new(
                &self.name,
                ErrorKind::Other,
                format!("{op} (call {n}): the device reports an internal fault (injected) and needs an operator"),
            ));
        }
        let mut hit = false;
        for t in &self.timeouts {
            // Draw only for probabilistic rules so a scenario without them uses no randomness.
            hit |= t.calls.contains(&n) || (t.probability > 0.0 && self.rng.gen_bool(t.probability));
        }
        if hit {
            self.world.log_fault(&self.name, n, FaultKind::Timeout);
            self.clock.sleep_s(timeout_s).await;
            return Err(DeviceError::new(
                &self.name,
                ErrorKind::Timeout,
                format!("{op} (call {n}): no answer within {timeout_s} s"),
            ));
        }
        Ok(n)
    }
}

/// Decides which frame read-outs are dropped or corrupted.
#[derive(Debug)]
pub(crate) struct FrameFaults {
    dropped: FrameFault,
    corrupt: FrameFault,
    rng: ChaCha8Rng,
}

/// What happens to one read-out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum FrameFate {
    Delivered,
    Dropped,
    Corrupted,
}

impl FrameFaults {
    pub fn new(scenario: &FaultScenario, seed: u64) -> Self {
        FrameFaults {
            dropped: scenario.dropped_frames.clone(),
            corrupt: scenario.corrupt_frames.clone(),
            rng: ChaCha8Rng::seed_from_u64(derive_seed(seed, "camera-frames", 2)),
        }
    }

    pub fn fate(&mut self, readout: u64) -> FrameFate {
        let hit = |f: &FrameFault, rng: &mut ChaCha8Rng| {
            f.frames.contains(&readout) || (f.probability > 0.0 && rng.gen_bool(f.probability))
        };
        if hit(&self.dropped, &mut self.rng) {
            FrameFate::Dropped
        } else if hit(&self.corrupt, &mut self.rng) {
            FrameFate::Corrupted
        } else {
            FrameFate::Delivered
        }
    }

    /// Flips `count` random bits below `bit_depth` in random samples: the values stay in
    /// range and the length stays right, so only the checksum reveals the damage.
    pub fn corrupt(&mut self, data: &mut [u16], bit_depth: u8, count: usize) {
        if data.is_empty() {
            return;
        }
        for _ in 0..count {
            let i = self.rng.gen_range(0..data.len());
            let bit = self.rng.gen_range(0..bit_depth.clamp(1, 16));
            data[i] ^= 1 << bit;
        }
    }
}

/// Checks `[hidden_markers]` against the rig's plate: every named id must be on it.
pub fn validate_hidden_markers(h: &HiddenMarkers, plate: &PlateConfig, errors: &mut Vec<ConfigError>) {
    let n = plate.marker_count();
    for (i, &id) in h.markers.iter().enumerate() {
        if id >= n {
            errors.push(ConfigError::out_of_range(
                &format!("faults.hidden_markers.markers[{i}]"),
                id,
                &format!("0..{n} (the ids of the plate's markers)"),
            ));
        }
    }
}

/// A frame source that covers the holder plate's markers in chosen frames with a dark
/// object ([`HiddenMarkers`]): every covered marker's square, enlarged by half its side in
/// each direction (so its white quiet zone goes too), is painted at the black level in the
/// raw frame, using the TRUE pose of the frame.
pub struct MarkerOccluder {
    inner: Arc<dyn FrameSource>,
    scene: Arc<RigScene>,
    hidden: HiddenMarkers,
    markers: Vec<MarkerPlacement>,
    seed: u64,
    rendered: AtomicU64,
    covered: AtomicU64,
}

impl MarkerOccluder {
    /// Wraps `inner`, whose frames show `scene` with the plate `plate`; `seed` is the rig's.
    /// Fails if `hidden` names a marker the plate does not have.
    pub fn new(
        inner: Arc<dyn FrameSource>,
        scene: Arc<RigScene>,
        plate: &PlateConfig,
        hidden: HiddenMarkers,
        seed: u64,
    ) -> Result<Self, ConfigError> {
        let mut errors = Vec::new();
        validate_hidden_markers(&hidden, plate, &mut errors);
        ConfigError::from_list(errors)?;
        let all = plate.marker_placements();
        let markers = if hidden.markers.is_empty() {
            all
        } else {
            all.into_iter().filter(|m| hidden.markers.contains(&m.id)).collect()
        };
        Ok(MarkerOccluder {
            inner,
            scene,
            hidden,
            markers,
            seed,
            rendered: AtomicU64::new(0),
            covered: AtomicU64::new(0),
        })
    }

    /// Frames whose markers were covered so far.
    pub fn covered(&self) -> u64 {
        self.covered.load(Ordering::Relaxed)
    }
}

impl FrameSource for MarkerOccluder {
    fn format(&self) -> SensorFormat {
        self.inner.format()
    }

    fn render(&self, truth: &TrueState, settings: &btfrig_hw::CaptureSettings, seed: u64) -> RawFrame {
        let mut frame = self.inner.render(truth, settings, seed);
        let n = self.rendered.fetch_add(1, Ordering::Relaxed) + 1;
        let h = &self.hidden;
        // Keyed by the frame's own seed (what is captured), not by the call count.
        let hit = h.frames.contains(&n)
            || (h.probability > 0.0
                && ChaCha8Rng::seed_from_u64(seed_for(derive_seed(self.seed, "hidden-markers", 3), &[seed]))
                    .gen_bool(h.probability));
        if hit {
            self.covered.fetch_add(1, Ordering::Relaxed);
            let pose = self.scene.pose(&truth.joints);
            cover_markers(&mut frame, self.scene.camera().model(), &pose, &self.markers);
        }
        frame
    }
}

/// Paints each of `markers`, enlarged by half its side in each direction, at the frame's
/// black level, as seen by `camera` with the plate at `pose` (integer pixel coordinates are
/// pixel centres).
pub fn cover_markers(frame: &mut RawFrame, camera: &CameraModel, pose: &ScenePose, markers: &[MarkerPlacement]) {
    let to_cam = pose.camera_to_world.inverse() * pose.sample_to_world;
    let dark = frame.meta.black_level;
    for m in markers {
        let c = m.corners_sample_m.iter().fold(Point2::origin(), |a, p| a + p.coords / 4.0);
        // Enlarged about the centre by 2x: the marker plus a border half its side wide.
        let quad: Option<Vec<Point2<f64>>> = m
            .corners_sample_m
            .iter()
            .map(|p| {
                let q = c + (p - c) * 2.0;
                camera.project(&(to_cam * Point3::new(q.x, q.y, 0.0)))
            })
            .collect();
        let Some(quad) = quad else { continue };
        let (x0, x1) = quad.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.x), b.max(p.x)));
        let (y0, y1) = quad.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.y), b.max(p.y)));
        let clamp = |v: f64, hi: usize| v.clamp(0.0, hi as f64 - 1.0) as usize;
        if x1 < 0.0 || y1 < 0.0 || x0 > frame.width as f64 || y0 > frame.height as f64 {
            continue;
        }
        // The projected quad is convex (a plane seen through a lens with mild distortion):
        // inside when on the same side of all four edges.
        let inside = |x: f64, y: f64| {
            let mut sign = 0.0f64;
            for k in 0..4 {
                let (a, b) = (quad[k], quad[(k + 1) % 4]);
                let cross = (b.x - a.x) * (y - a.y) - (b.y - a.y) * (x - a.x);
                if cross != 0.0 {
                    if sign != 0.0 && cross.signum() != sign {
                        return false;
                    }
                    sign = cross.signum();
                }
            }
            true
        };
        for y in clamp(y0.floor(), frame.height)..=clamp(y1.ceil(), frame.height) {
            for x in clamp(x0.floor(), frame.width)..=clamp(x1.ceil(), frame.width) {
                if inside(x as f64, y as f64) {
                    frame.data[y * frame.width + x] = dark;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::FlatFrameSource;
    use btfrig_core::config::RigConfig;
    use btfrig_core::plan::BUILTIN_RIGS;
    use btfrig_core::Direction;
    use btfrig_hw::CaptureSettings;
    use btfrig_render::material::MaterialSpec;

    fn setup() -> (RigConfig, Arc<RigScene>, TrueState) {
        let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "builtin rig").unwrap();
        let scene = Arc::new(RigScene::new(&cfg, &MaterialSpec::builtin("leather").unwrap()).unwrap());
        let joints = scene.gonio().ik(Direction::from_degrees(45.0, 0.0), Direction::from_degrees(30.0, 90.0)).unwrap();
        let truth = TrueState {
            joints,
            lamp_on: true,
            lamp_shutter_open: true,
            lamp_intensity: 1.0,
            leds: Vec::new(),
            time_s: 0.0,
        };
        (cfg, scene, truth)
    }

    const SETTINGS: CaptureSettings = CaptureSettings { exposure_s: 0.1, gain: 1.0, f_number: None };

    #[test]
    fn covering_a_marker_paints_its_projected_enlarged_square_at_the_black_level_and_nothing_else() {
        let (cfg, scene, truth) = setup();
        let cam = scene.camera().model();
        let flat = FlatFrameSource::new(cam.width, cam.height, 10_000.0);
        let mut frame = flat.render(&truth, &SETTINGS, 0);
        let lit = frame.data[0];
        let pose = scene.pose(&truth.joints);
        let marker = cfg.plate.marker_placements()[5].clone();
        cover_markers(&mut frame, cam, &pose, std::slice::from_ref(&marker));
        let painted = frame.data.iter().filter(|&&v| v == frame.meta.black_level).count();
        assert!(frame.data.iter().all(|&v| v == lit || v == frame.meta.black_level));
        // Independent area: the shoelace area of the projected enlarged corners (the lens
        // barely bends a 4 cm square), against the count of painted pixel centres.
        let to_cam = pose.camera_to_world.inverse() * pose.sample_to_world;
        let c = marker.corners_sample_m.iter().fold(Point2::origin(), |a, p| a + p.coords / 4.0);
        let q: Vec<Point2<f64>> = marker
            .corners_sample_m
            .iter()
            .map(|p| {
                let e = c + (p - c) * 2.0;
                cam.project(&(to_cam * Point3::new(e.x, e.y, 0.0))).unwrap()
            })
            .collect();
        let area = (0..4).map(|k| q[k].x * q[(k + 1) % 4].y - q[(k + 1) % 4].x * q[k].y).sum::<f64>().abs() / 2.0;
        let perimeter: f64 = (0..4).map(|k| (q[(k + 1) % 4] - q[k]).norm()).sum();
        assert!(area > 1000.0, "a marker is tens of pixels wide at this view: {area}");
        assert!(
            (painted as f64 - area).abs() < perimeter,
            "painted {painted}, area {area:.0}, perimeter {perimeter:.0}"
        );
        // The marker's own centre is covered; the plate centre (the sample) is not.
        let centre = cam.project(&(to_cam * Point3::new(c.x, c.y, 0.0))).unwrap();
        let at = |p: Point2<f64>| frame.data[p.y.round() as usize * frame.width + p.x.round() as usize];
        assert_eq!(at(centre), frame.meta.black_level);
        let sample = cam.project(&(to_cam * Point3::origin())).unwrap();
        assert_eq!(at(sample), lit);
    }

    #[test]
    fn the_occluder_covers_the_chosen_frames_and_draws_probabilities_from_the_frame_seed() {
        let (cfg, scene, truth) = setup();
        let cam = scene.camera().model();
        let flat: Arc<dyn FrameSource> = Arc::new(FlatFrameSource::new(cam.width, cam.height, 10_000.0));
        let clean = flat.render(&truth, &SETTINGS, 0);
        let hidden = HiddenMarkers { frames: vec![2], probability: 0.0, markers: vec![0, 7] };
        let occ = MarkerOccluder::new(flat.clone(), scene.clone(), &cfg.plate, hidden, 1).unwrap();
        let covered: Vec<bool> = (0..4).map(|_| occ.render(&truth, &SETTINGS, 0) != clean).collect();
        assert_eq!(covered, [false, true, false, false]);
        assert_eq!(occ.covered(), 1);

        // With a probability, the decision follows the frame's seed, not the call count.
        let hidden = HiddenMarkers { frames: vec![], probability: 0.5, markers: vec![] };
        let occ = MarkerOccluder::new(flat.clone(), scene.clone(), &cfg.plate, hidden, 1).unwrap();
        let first: Vec<bool> = (0..64).map(|s| occ.render(&truth, &SETTINGS, s) != clean).collect();
        let again: Vec<bool> = (0..64).rev().map(|s| occ.render(&truth, &SETTINGS, s) != clean).collect();
        assert!(first.iter().eq(again.iter().rev()));
        let n = first.iter().filter(|&&c| c).count();
        assert!((16..=48).contains(&n), "{n} of 64 covered at p = 0.5");

        let bad = HiddenMarkers { frames: vec![0], probability: 1.5, markers: vec![99] };
        let e = MarkerOccluder::new(flat.clone(), scene.clone(), &cfg.plate, bad.clone(), 1).err().unwrap().to_string();
        assert!(e.contains("faults.hidden_markers.markers[0]") && e.contains("0..12"), "{e}");
        let mut errors = Vec::new();
        FaultScenario { hidden_markers: bad, ..FaultScenario::none() }.validate(&mut errors);
        let all: Vec<String> = errors.iter().map(|e| e.to_string()).collect();
        assert!(all.iter().any(|e| e.contains("faults.hidden_markers.probability")), "{all:?}");
        assert!(all.iter().any(|e| e.contains("faults.hidden_markers.frames[0]")), "{all:?}");
    }
}
