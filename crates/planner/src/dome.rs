//! Planning an LED dome measurement: views = (camera, rotation), lights = LEDs, and per view
//! group the capture mode chosen by the noise model (`btfrig_mux::noise::choose`).
//!
//! Every view group of a dome has the same sensor, the same LEDs and the same brightness
//! estimate, so the choice is made once and applies to every group (the plan's
//! `sample_brightness` is the estimate; a per-view estimate from a preview frame would make
//! it per group). The choice is between single light, one S-matrix over all LEDs (198 LEDs:
//! Paley 199 with one always-off slot) and grouped S-matrices (`Mode::Grouped`: the LEDs in
//! consecutive groups of `order`, each group multiplexed by its own S-matrix of that order,
//! slots past the last LED always off). A grouped code lights `(order + 1)/2` LEDs per frame
//! instead of about 100, so it wins where the full S-matrix's frames would saturate and its
//! exposure is cut (highlights far above the typical level, `brightness_max`). It does not
//! win on photon noise alone: without saturation an S-matrix's gain grows with its order
//! while `σ_p²/κ² < 2 − 4/(order + 1)`, and above that no S-matrix gains at all (codes with
//! `C*` lit sources over all LEDs would, but are not constructed: `docs/multiplexing.md`).
//! `multiplex = "on"` with `group_order = m` forces groups of order `m`.
//!
//! The noise model gets each light's own signal: the calibrated rate of a light facing the
//! sample at the nominal distance (the LED calibration divides the incidence out) times the
//! light's irradiance factor `cos θ · (d/r)²` from the rig config's nominal geometry
//! ([`light_irradiance`]; mean 0.54 over the Bonn dome's LEDs, 0.63 over the camera array's
//! flashes). Without it every lit light counts as facing the sample, and the photon noise of a
//! multiplexed frame is over-predicted by about the inverse of that mean.
//!
//! All cameras of the arc expose together, so a step is (rotation, pattern): turn the table
//! when the rotation changes, set the pattern, trigger every camera, read every camera.
//!
//! A camera array (`kind = "camera_array"`) is planned the same way with lights = flashes and
//! views = cameras (one rotation). A flash is a pulse: a frame's signal is
//! `flash energy x light_units(exposure)`, not a rate times the exposure, so the noise model
//! is fed the equivalent rate `e- per flash x light_units(exposure_s) / exposure_s`, where
//! saturation asks for less light the patterns fire the flashes at reduced power
//! (`pattern_scale`) instead of shortening the exposure (which would not reduce a flash), and
//! the time saved is counted in frames: single-flash capture reaches the multiplexed SNR only
//! by averaging `G²` frames per flash (a longer exposure collects no more of a flash), so it
//! saves `1 - 1/G²`.

use btfrig_core::config::dome::DomeConfig;
use btfrig_core::config::RigConfig;
use btfrig_core::plan::dome::{MultiplexPolicy, ValidatedDomePlan};
use btfrig_mux::{available_orders, choose, predict, Choice, ChooseParams, Mode, SMatrix, SceneLight, SensorNoise};

/// How a view group is captured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DomeMode {
    /// One LED per frame.
    Single,
    /// S-matrix patterns of `order` (`order - leds` always-off slots).
    Multiplexed {
        /// The S-matrix order.
        order: usize,
    },
    /// `groups` consecutive groups of `order` LEDs, each multiplexed by its own S-matrix of
    /// `order`: frames `g*order .. (g+1)*order` light only group `g` (LEDs
    /// `g*order .. (g+1)*order`; slots past the last LED always off).
    Grouped {
        /// The order of every group's S-matrix.
        order: usize,
        /// Number of groups.
        groups: usize,
    },
}

impl DomeMode {
    /// The noise model's mode.
    pub fn mux_mode(&self) -> Mode {
        match *self {
            DomeMode::Single => Mode::Single,
            DomeMode::Multiplexed { order } => Mode::SMatrix { order },
            DomeMode::Grouped { order, groups } => Mode::Grouped { order, groups },
        }
    }

    /// The dome mode that captures the noise model's mode.
    pub fn from_mux_mode(mode: Mode) -> DomeMode {
        match mode {
            Mode::Single => DomeMode::Single,
            Mode::SMatrix { order } => DomeMode::Multiplexed { order },
            Mode::Grouped { order, groups } => DomeMode::Grouped { order, groups },
        }
    }

    /// Short description (`Mode::describe`): `single-light`, `s-matrix 199`, `groups 29 x 7`.
    pub fn describe(&self) -> String {
        self.mux_mode().describe()
    }

    /// Whether frames light several LEDs (and are demultiplexed).
    pub fn is_multiplexed(&self) -> bool {
        !matches!(self, DomeMode::Single)
    }
}

/// What one step captures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DomeShot {
    /// Pattern `index` of the group's code (an LED index in single-light mode).
    Pattern(usize),
    /// A single-LED reference frame of LED `led` (measures the multiplexing gain; not stored).
    Reference(usize),
}

/// One step: all cameras capture one pattern at one rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DomeStep {
    /// Rotation index.
    pub rotation: u32,
    /// Turntable angle, radians.
    pub turntable_rad: f64,
    /// What is lit.
    pub shot: DomeShot,
}

/// The schedule of a dome plan.
#[derive(Debug, Clone)]
pub struct DomeSchedule {
    /// LEDs.
    pub leds: usize,
    /// The mode of every view group.
    pub mode: DomeMode,
    /// The noise model's evaluation (always made, so the report shows it even when the plan
    /// forces the mode).
    pub choice: Choice,
    /// The predicted SNR gain of the mode used over single light at equal total time.
    pub predicted_gain: f64,
    /// One line for the dry run and the report.
    pub reason: String,
    /// Exposure of every pattern frame, seconds.
    pub exposure_s: f64,
    /// Exposure of a single-light (and reference) frame, seconds.
    pub single_exposure_s: f64,
    /// LED intensities of each pattern (`leds` values each).
    pub patterns: Vec<Vec<f64>>,
    /// Steps in capture order.
    pub steps: Vec<DomeStep>,
    /// The noise model's inputs.
    pub sensor: SensorNoise,
    /// The noise model's inputs.
    pub scene: SceneLight,
    /// Fraction of the exposure time saved against single-light capture reaching the same
    /// SNR (0 when single light is used; for flashes, of the frames: module docs).
    pub time_saved_fraction: f64,
    /// Power every lit light of a pattern fires at (1, or below 1 for flashes when a pattern
    /// would saturate: module docs); already applied to `patterns`, and the demultiplexer's
    /// intensities must include it.
    pub pattern_scale: f64,
}

/// Errors of dome planning.
#[derive(Debug, thiserror::Error)]
pub enum DomePlanError {
    /// The noise model refused its inputs.
    #[error("noise model: {0}")]
    Mux(#[from] btfrig_mux::MuxError),
    /// The rig is not a dome.
    #[error(transparent)]
    Config(#[from] btfrig_core::ConfigError),
    /// The plan's `group_order` has no S-matrix.
    #[error("dome.group_order = {order} has no S-matrix construction: allowed {allowed}")]
    GroupOrder {
        /// The order asked for.
        order: usize,
        /// The orders that exist between 3 and the LED count, comma-separated.
        allowed: String,
    },
}

/// The single-light exposure that reaches `snr` for a signal of `rate` e-/s: solves
/// `q t / sqrt(κ0² + (q + d) t) = snr` for `t` (κ0² the read and quantisation noise, `d` the
/// dark current).
pub fn exposure_for_snr(sensor: &SensorNoise, rate: f64, snr: f64) -> f64 {
    let k0 = sensor.kappa2(0.0);
    let (a, b, c) = (rate * rate, snr * snr * (rate + sensor.dark_current_e_per_s), snr * snr * k0);
    (b + (b * b + 4.0 * a * c).sqrt()) / (2.0 * a)
}

/// Per light, the irradiance it gives the sample centre relative to a light facing the
/// sample at the nominal light distance `d` (the LED calibration's reference, which divides
/// this factor out: `btfrig_imaging::light`): `cos θ · (d/r)²` for the light at polar angle
/// `θ` and distance `r` in the nominal rig geometry (the turntable turns about the normal, so
/// it is the same at every rotation).
pub fn light_irradiance(dome: &DomeConfig) -> Vec<f64> {
    let d = dome.light_distance_m();
    (0..dome.led_count())
        .map(|j| {
            let l = dome.led_position(j).coords;
            let r2 = l.norm_squared();
            l.z / r2.sqrt() * d * d / r2
        })
        .collect()
}

/// Plans a dome measurement. `led_e_per_s` is the electrons per second one LED of nominal
/// power puts into a photosite imaging a white sample facing it at the nominal light distance
/// (the LED calibration's `reference_rate`); each light's own signal is this times its
/// [`light_irradiance`].
///
/// On a camera array `led_e_per_s` is electrons per flash (module docs).
pub fn plan_dome(rig: &RigConfig, v: &ValidatedDomePlan, led_e_per_s: f64) -> Result<DomeSchedule, DomePlanError> {
    let dome = rig.require_dome("dome planning")?;
    let d = &v.plan.dome;
    let leds = dome.led_count();
    let flash = dome.is_flash();
    // The rate that gives a frame of `exposure_s` its signal (the identity for LEDs).
    let led_e_per_s = led_e_per_s * dome.light_units(d.exposure_s) / d.exposure_s;
    let s = &rig.sensor;
    let sensor = SensorNoise {
        read_noise_e: s.read_noise_e,
        dn_per_e: d.gain / s.electrons_per_dn,
        full_well_e: s.full_well_e,
        dark_current_e_per_s: s.dark_current_e_per_s,
    };
    let scene = SceneLight {
        irradiance: light_irradiance(dome),
        led_e_per_s,
        brightness: d.sample_brightness,
        brightness_max: d.brightness_max,
        exposure_s: d.exposure_s,
        well_fraction: 0.9,
    };
    let choice = choose(&sensor, &scene, &ChooseParams::default())?;
    let (mode, pred, reason) = match d.multiplex {
        MultiplexPolicy::Off => {
            let p = predict(&sensor, &scene, Mode::Single)?;
            (
                DomeMode::Single,
                p,
                format!("multiplexing skipped: the plan says multiplex = \"off\" ({})", choice.reason),
            )
        }
        MultiplexPolicy::On => {
            let (mode, asked) = match d.group_order {
                None => (DomeMode::Multiplexed { order: SMatrix::for_sources(leds)?.s.order() }, String::new()),
                Some(m) => (grouped_mode(m, leds)?, format!(", group_order = {m}")),
            };
            let p = predict(&sensor, &scene, mode.mux_mode())?;
            let r = format!(
                "multiplexing with {} (the plan says multiplex = \"on\"{asked}): predicted gain {:.2}",
                mode.describe(),
                p.gain
            );
            (mode, p, r)
        }
        MultiplexPolicy::Auto => (DomeMode::from_mux_mode(choice.best.mode), choice.best, choice.reason.clone()),
    };
    let single = predict(&sensor, &scene, Mode::Single)?;
    // Where the noise model shortens the exposure against saturation, flashes fire at the
    // same fraction of their power instead (module docs).
    let (exposure_s, pattern_scale) = if flash {
        (single.exposure_s, (pred.exposure_s / single.exposure_s).min(1.0))
    } else {
        (pred.exposure_s, 1.0)
    };
    let patterns: Vec<Vec<f64>> = match mode {
        DomeMode::Single => (0..leds).map(|j| (0..leds).map(|i| f64::from(u8::from(i == j))).collect()).collect(),
        DomeMode::Multiplexed { order } => block_patterns(order, 1, leds, pattern_scale)?,
        DomeMode::Grouped { order, groups } => block_patterns(order, groups, leds, pattern_scale)?,
    };
    let mut steps = Vec::new();
    for (i, &k) in v.rotations.iter().enumerate() {
        let turntable_rad = dome.rotation_rad(k);
        for p in 0..patterns.len() {
            steps.push(DomeStep { rotation: k, turntable_rad, shot: DomeShot::Pattern(p) });
        }
        if i == 0 && mode.is_multiplexed() {
            // Reference LEDs spread over the dome, for the measured gain.
            let n = d.reference_leds.min(leds);
            for r in 0..n {
                steps.push(DomeStep {
                    rotation: k,
                    turntable_rad,
                    shot: DomeShot::Reference(r * leds / n + leds / (2 * n)),
                });
            }
        }
    }
    let gain = pred.gain;
    let time_saved_fraction = match mode {
        DomeMode::Single => 0.0,
        // Single flashes average G² frames each to reach the multiplexed SNR.
        _ if flash => (1.0 - 1.0 / (gain * gain)).max(0.0),
        _ => {
            // Single light needs this exposure per LED of the mean irradiance to reach the
            // multiplexed SNR.
            let mean_g = scene.irradiance.iter().sum::<f64>() / leds as f64;
            let t = exposure_for_snr(&sensor, led_e_per_s * d.sample_brightness * mean_g, pred.snr);
            let mux_time = pred.frames as f64 * pred.exposure_s;
            (1.0 - mux_time / (leds as f64 * t)).max(0.0)
        }
    };
    Ok(DomeSchedule {
        leds,
        mode,
        predicted_gain: gain,
        reason,
        exposure_s,
        single_exposure_s: single.exposure_s,
        choice,
        patterns,
        steps,
        sensor,
        scene,
        time_saved_fraction,
        pattern_scale,
    })
}

/// Groups of `order` for `leds` LEDs (as many as cover them), refusing an order without an
/// S-matrix or one that leaves a single group (the plan checks the range first: this is the
/// planner's own guard, naming the orders that exist).
fn grouped_mode(order: usize, leds: usize) -> Result<DomeMode, DomePlanError> {
    let allowed: Vec<usize> = available_orders(leds.saturating_sub(1)).into_iter().filter(|&m| m >= 3).collect();
    if !allowed.contains(&order) {
        let allowed = allowed.iter().map(|m| m.to_string()).collect::<Vec<_>>().join(", ");
        return Err(DomePlanError::GroupOrder { order, allowed });
    }
    Ok(DomeMode::Grouped { order, groups: leds.div_ceil(order) })
}

/// The block-diagonal patterns of `groups` S-matrices of `order` over `leds` LEDs, every lit
/// LED at `scale`: frame `g*order + r` lights LED `g*order + j` where row `r` of the S-matrix
/// has a 1 in column `j` (slots at or past `leds` are always off). One group is the full
/// S-matrix.
pub fn block_patterns(order: usize, groups: usize, leds: usize, scale: f64) -> Result<Vec<Vec<f64>>, DomePlanError> {
    let s = SMatrix::of_order(order)?;
    let pattern = |g: usize, r: usize| -> Vec<f64> {
        (0..leds)
            .map(|led| match led.checked_sub(g * order) {
                Some(j) if j < order => scale * f64::from(s.get(r, j)),
                _ => 0.0,
            })
            .collect()
    };
    Ok((0..groups).flat_map(|g| (0..order).map(move |r| (g, r))).map(|(g, r)| pattern(g, r)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::plan::dome::DomePlan;

    fn rig() -> RigConfig {
        let text = btfrig_core::plan::BUILTIN_RIGS.iter().find(|(n, _)| *n == "builtin:bonn-dome-sim").unwrap().1;
        RigConfig::from_toml(text, "dome").unwrap()
    }

    fn plan(extra: &str) -> ValidatedDomePlan {
        DomePlan::from_toml(&format!("[dome]\ncameras = [0]\nrotations = [0, 6]\n{extra}"), "p")
            .unwrap()
            .validate(&rig())
            .unwrap()
    }

    #[test]
    fn dim_leds_are_multiplexed_with_paley_199_and_bright_ones_are_not() {
        // 100 e-/s at 0.05 s and albedo 0.3: 1.5 e- per LED per frame against 12 e- read noise.
        let s = plan_dome(&rig(), &plan(""), 100.0).unwrap();
        assert_eq!(s.mode, DomeMode::Multiplexed { order: 199 });
        assert_eq!(s.patterns.len(), 199);
        assert!(s.patterns.iter().all(|p| p.len() == 198));
        assert_eq!(s.steps.len(), 2 * 199 + 4);
        assert!(s.predicted_gain > 3.0, "{}", s.predicted_gain);
        assert!(s.time_saved_fraction > 0.8, "{}", s.time_saved_fraction);
        // 1e6 e-/s: 15000 e- per LED per frame, photon-noise dominated.
        let b = plan_dome(&rig(), &plan(""), 1e6).unwrap();
        assert_eq!(b.mode, DomeMode::Single);
        assert!(b.reason.starts_with("multiplexing skipped"), "{}", b.reason);
        assert_eq!(b.patterns.len(), 198);
        assert_eq!(b.time_saved_fraction, 0.0);
    }

    #[test]
    fn single_light_at_the_solved_exposure_reaches_the_asked_snr() {
        let sensor = SensorNoise { read_noise_e: 12.0, dn_per_e: 0.4, full_well_e: 40000.0, dark_current_e_per_s: 0.5 };
        let t = exposure_for_snr(&sensor, 30.0, 10.0);
        let q = 30.0 * t;
        assert!((q / (sensor.kappa2(t) + q).sqrt() - 10.0).abs() < 1e-9);
    }

    fn array() -> RigConfig {
        let text =
            btfrig_core::plan::BUILTIN_RIGS.iter().find(|(n, _)| *n == "builtin:bonn-camera-array-sim").unwrap().1;
        RigConfig::from_toml(text, "camera array").unwrap()
    }

    #[test]
    fn dim_flashes_are_multiplexed_with_paley_151_and_bright_ones_are_not() {
        let rig = array();
        let v = DomePlan::from_toml(
            "[rig]\nconfig = \"builtin:bonn-camera-array-sim\"\n[dome]\ncameras = [0, 40]\nexposure_s = 0.01\n",
            "p",
        )
        .unwrap()
        .validate(&rig)
        .unwrap();
        // 90 e- per flash at a white photosite, 27 e- at albedo 0.3, 12 e- read noise.
        let s = plan_dome(&rig, &v, 90.0).unwrap();
        assert_eq!(s.mode, DomeMode::Multiplexed { order: 151 });
        assert!(s.reason.starts_with("multiplexing with s-matrix 151"), "{}", s.reason);
        assert_eq!((s.leds, s.patterns.len(), s.steps.len()), (151, 151, 151 + 4));
        // No always-off slot: 76 flashes per pattern.
        assert!(s.patterns.iter().all(|p| p.iter().filter(|&&x| x > 0.0).count() == 76));
        assert!(s.predicted_gain > 1.5 && s.pattern_scale == 1.0, "{}", s.predicted_gain);
        let g = s.predicted_gain;
        assert!((s.time_saved_fraction - (1.0 - 1.0 / (g * g))).abs() < 1e-12);
        // The exposure does not change a flash's signal: 0.02 s plans the same gain.
        let v2 = DomePlan::from_toml(
            "[rig]\nconfig = \"builtin:bonn-camera-array-sim\"\n[dome]\ncameras = [0]\nexposure_s = 0.02\n",
            "p",
        )
        .unwrap()
        .validate(&rig)
        .unwrap();
        let g2 = plan_dome(&rig, &v2, 90.0).unwrap().predicted_gain;
        assert!((g2 / g - 1.0).abs() < 0.01, "{g} vs {g2}");
        // A full-power flash (3e4 e- per flash): photon-noise dominated, one flash at a time.
        let b = plan_dome(&rig, &v, 3e4).unwrap();
        assert_eq!(b.mode, DomeMode::Single);
        assert!(b.reason.starts_with("multiplexing skipped"), "{}", b.reason);
        assert_eq!((b.patterns.len(), b.time_saved_fraction), (151, 0.0));
    }

    #[test]
    fn a_light_at_60_degrees_gives_half_the_irradiance_of_one_at_the_zenith() {
        use btfrig_core::config::dome::LedRing;
        let mut dome = rig().dome.unwrap();
        dome.led_rings = vec![
            LedRing { theta_deg: 0.0, count: 1, phi_offset_deg: 0.0 },
            LedRing { theta_deg: 60.0, count: 4, phi_offset_deg: 10.0 },
        ];
        let g = light_irradiance(&dome);
        assert_eq!(g.len(), 5);
        assert!((g[0] - 1.0).abs() < 1e-12 && g[1..].iter().all(|x| (x - 0.5).abs() < 1e-12), "{g:?}");
        // The shipped dome: the mean cos θ of its rings (all LEDs at the nominal distance).
        let dome = rig().dome.unwrap();
        let mean = light_irradiance(&dome).iter().sum::<f64>() / 198.0;
        assert!((mean - 0.5391).abs() < 1e-3, "{mean}");
        // The camera array's flashes sit 4 cm off their cameras: cos θ and (d/r)² of each.
        let array = array().dome.unwrap();
        let g = light_irradiance(&array);
        let mean = g.iter().sum::<f64>() / g.len() as f64;
        // 0.628 at the flashes, 0.589 at the cameras: each flash sits 4 cm nearer the zenith.
        assert!((mean - 0.628).abs() < 1e-3, "{mean}");
        for (j, x) in g.iter().enumerate() {
            let cos = array.led_directions()[j].theta.cos();
            let r = array.led_position(j).coords.norm();
            assert!((x / cos - (0.7 / r).powi(2)).abs() < 1e-9 && r > 0.7, "flash {j}: {x} vs cos θ {cos} at {r} m");
        }
    }

    #[test]
    fn grouped_patterns_are_block_diagonal_with_each_groups_s_matrix() {
        // 198 LEDs in 29 groups of 7: the last group has LEDs 196 and 197 and 5 always-off slots.
        let p = block_patterns(7, 29, 198, 1.0).unwrap();
        let s = SMatrix::of_order(7).unwrap();
        assert_eq!(p.len(), 7 * 29);
        assert!(p.iter().all(|f| f.len() == 198));
        for (frame, f) in p.iter().enumerate() {
            let (g, r) = (frame / 7, frame % 7);
            for (led, &x) in f.iter().enumerate() {
                let inside = led / 7 == g;
                let want = if inside { f64::from(s.get(r, led % 7)) } else { 0.0 };
                assert_eq!(x, want, "frame {frame} LED {led}");
            }
            let lit = f.iter().filter(|&&x| x > 0.0).count();
            let slots_lit = (0..7).filter(|&j| s.get(r, j) == 1 && g * 7 + j < 198).count();
            assert_eq!(lit, slots_lit, "frame {frame}");
            if g < 28 {
                assert_eq!(lit, 4, "a full group lights (7 + 1)/2 LEDs per frame");
            }
        }
        // Every LED is lit in 4 frames, all of its own group's.
        for led in 0..198 {
            let frames: Vec<usize> = (0..p.len()).filter(|&f| p[f][led] > 0.0).collect();
            assert_eq!(frames.len(), 4, "LED {led}");
            assert!(frames.iter().all(|f| f / 7 == led / 7), "LED {led}: {frames:?}");
        }
    }

    #[test]
    fn highlights_that_saturate_the_full_s_matrix_choose_a_grouped_code() {
        // 1800 e-/s at white, albedo 0.3 (27 e- per LED per frame facing it), but highlights 8x
        // white: the 100 most strongly lit LEDs (Σ cos θ = 78) at the highlight would overfill
        // the well at 64 % of the exposure, 30 do not.
        let v = plan("brightness_max = 8.0\n");
        let s = plan_dome(&rig(), &v, 1800.0).unwrap();
        let DomeMode::Grouped { order, groups } = s.mode else { panic!("{:?}: {}", s.mode, s.reason) };
        assert_eq!(groups, 198usize.div_ceil(order));
        assert!(s.reason.starts_with(&format!("multiplexing with groups {groups} x {order}")), "{}", s.reason);
        assert_eq!(s.patterns.len(), order * groups);
        assert_eq!(s.steps.len(), 2 * order * groups + 4);
        let gain = |m: Mode| s.choice.candidates.iter().find(|p| p.mode == m).unwrap().gain;
        let full = gain(Mode::SMatrix { order: 199 });
        assert!(s.predicted_gain > 1.5 && s.predicted_gain > 1.2 * full, "{} vs s-matrix {full}", s.predicted_gain);
        assert!(
            s.choice.candidates.iter().find(|p| p.mode == Mode::SMatrix { order: 199 }).unwrap().saturation_factor
                < 0.7
        );
        assert!(s.time_saved_fraction > 0.3, "{}", s.time_saved_fraction);
        // Without the highlights no code is cut by saturation, and the full S-matrix is as good
        // as the best within 2 % (with each LED's cos θ, two groups of 103, the upper rings
        // apart from the lower ones, keep the strongly lit LEDs' photon noise out of the weakly
        // lit ones' images and gain about 1 % more).
        let plain = plan_dome(&rig(), &plan(""), 1800.0).unwrap();
        let full = plain.choice.candidates.iter().find(|p| p.mode == Mode::SMatrix { order: 199 }).unwrap();
        assert!(plain.choice.best.saturation_factor > 0.999 && full.saturation_factor > 0.999, "{}", plain.reason);
        assert!(full.gain > 0.98 * plain.predicted_gain, "{} vs s-matrix {}", plain.predicted_gain, full.gain);
    }

    #[test]
    fn a_plan_can_force_groups_of_an_order_that_has_an_s_matrix() {
        let s = plan_dome(&rig(), &plan("multiplex = \"on\"\ngroup_order = 15\n"), 1800.0).unwrap();
        assert_eq!(s.mode, DomeMode::Grouped { order: 15, groups: 14 });
        assert!(
            s.reason
                .starts_with("multiplexing with groups 14 x 15 (the plan says multiplex = \"on\", group_order = 15)"),
            "{}",
            s.reason
        );
        assert_eq!(s.patterns.len(), 210);
        let e = plan_dome(&rig(), &plan("multiplex = \"on\"\ngroup_order = 9\n"), 1800.0).unwrap_err().to_string();
        assert!(
            e.starts_with("dome.group_order = 9 has no S-matrix construction: allowed 3, 7, 11, 15, 19, 23, 31,"),
            "{e}"
        );
    }
}
