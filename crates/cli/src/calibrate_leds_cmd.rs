//! `btfrig calibrate leds`: the LED calibration of a dome (or the flash calibration of a
//! camera array): a white reference tile photographed under one light at a time, or under
//! Hadamard patterns demultiplexed (`--multiplexed`), gives each light's power and colour;
//! captured through the devices (`btfrig_measurement::captured_calibration::capture_leds`),
//! fitted by `btfrig_calibrate::leds`; prints the estimates (on a simulated rig against its
//! truth, `btfrig_sim_calibration::leds::led_truth`) and writes the file (docs/rig-config.md,
//! "LED calibration").

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use btfrig_calibrate::leds::LedFitOptions;
use btfrig_measurement::captured_calibration::{capture_leds, CalibrationSession, LedCaptureOptions};
use btfrig_sim_calibration::leds::led_truth;

/// `btfrig calibrate leds`.
#[derive(Debug, clap::Args)]
pub struct CalibrateLedsArgs {
    /// Rig config file or embedded rig name (`bonn-dome-sim`, `dome`, `camera-array`).
    #[arg(long)]
    pub rig: PathBuf,
    /// Calibration file to write (default: `<rig name>-leds.toml` in the current directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Seed of the sensor noise (default: the rig's `[rig] seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Frames per light (default: 2 per LED, 64 per flash).
    #[arg(long)]
    pub repeats: Option<usize>,
    /// Light the tile by Hadamard S-matrix patterns (about half the LEDs each) and
    /// demultiplex, instead of one LED at a time (LED domes).
    #[arg(long)]
    pub multiplexed: bool,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Runs the command.
pub fn leds(a: &CalibrateLedsArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let cfg = crate::rig::load(Some(&a.rig))?;
    let Some(dome) = cfg.dome.as_ref() else {
        bail!("calibrate leds needs an LED dome or a camera array; {} is a {}", a.rig.display(), cfg.rig.kind.as_str());
    };
    let light = if dome.is_flash() { "flash" } else { "LED" };
    let seed = a.seed.unwrap_or(cfg.rig.seed);
    let mut opts = LedCaptureOptions {
        repeats: if dome.is_flash() { 64 } else { 2 },
        multiplexed: a.multiplexed,
        exposure_fraction: 0.5,
        fit: LedFitOptions { seed: Some(seed), ..LedFitOptions::default() },
    };
    if let Some(r) = a.repeats {
        if !(1..=64).contains(&r) {
            bail!("--repeats {r}: allowed 1..=64 frames per light");
        }
        opts.repeats = r;
    }
    let rig_path = crate::rig::builtin(&a.rig).is_none().then_some(a.rig.as_path());
    let camera = btfrig_calibrate::processing_camera(&cfg, rig_path).context("the processing camera")?;
    let session = CalibrationSession::installed(&cfg, seed);
    let mut cap = capture_leds(&session, &camera, &opts).context("LED calibration failed")?;
    cap.file.source.method = format!(
        "{} (btfrig calibrate leds --rig {} --seed {seed}{}{}: captured through the devices)",
        cap.file.source.method,
        a.rig.display(),
        a.repeats.map_or(String::new(), |r| format!(" --repeats {r}")),
        if a.multiplexed { " --multiplexed" } else { "" }
    );
    if !crate::rig::all_simulated(&cfg) {
        cap.file.source.date = "captured".into();
    }
    let (true_power, true_colour, true_reference_rate) = if crate::rig::all_simulated(&cfg) {
        led_truth(&cfg)?
    } else {
        let n = cap.file.leds.len();
        (vec![f64::NAN; n], vec![[f64::NAN; 3]; n], f64::NAN)
    };
    let r = Captured { file: cap.file, exposure_s: cap.exposure_s, true_power, true_colour, true_reference_rate };
    let suffix = if dome.is_flash() { "flashes" } else { "leds" };
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from(format!("{}-{suffix}.toml", cfg.rig.name)));
    std::fs::write(&out, r.file.to_toml())
        .with_context(|| format!("cannot write LED calibration {}", out.display()))?;
    let pct = |a: f64, b: f64| 100.0 * (a / b - 1.0);
    let power_err: Vec<f64> = r.file.leds.iter().zip(&r.true_power).map(|(e, t)| pct(e.power, *t)).collect();
    let colour_err: Vec<[f64; 3]> =
        r.file.leds.iter().zip(&r.true_colour).map(|(e, t)| std::array::from_fn(|c| pct(e.colour[c], t[c]))).collect();
    let rms = |v: &mut dyn Iterator<Item = f64>| {
        let (s, n) = v.fold((0.0, 0usize), |a, x| (a.0 + x * x, a.1 + 1));
        (s / n.max(1) as f64).sqrt()
    };
    let power_rms = rms(&mut power_err.iter().copied());
    // |error| / stated sigma, per LED: the stated uncertainty should cover the error.
    let power_z: Vec<f64> =
        r.file.leds.iter().zip(&r.true_power).map(|(e, t)| (e.power - t).abs() / e.power_sigma.max(1e-300)).collect();
    let power_max_err = power_err.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    let power_sigma_rms = rms(&mut r.file.leds.iter().map(|e| 100.0 * e.power_sigma / e.power));
    let colour_rms = rms(&mut colour_err.iter().flat_map(|c| [c[0], c[2]]));
    let reference_err = pct(r.file.reference_rate, r.true_reference_rate);
    if a.json {
        let v = serde_json::json!({
            "rig": cfg.rig.name,
            "light": light,
            "lights": r.file.leds.len(),
            "frames_per_light": r.file.source.frames_per_light,
            "exposure_s": r.exposure_s,
            "reference_rate": r.file.reference_rate,
            "true_reference_rate": r.true_reference_rate,
            "reference_rate_err_pct": reference_err,
            "power_err_rms_pct": power_rms,
            "power_err_max_pct": power_max_err,
            "power_sigma_rms_pct": power_sigma_rms,
            "power_z_max": power_z.iter().fold(0.0f64, |m, z| m.max(*z)),
            "multiplexed": a.multiplexed,
            "colour_err_rms_pct": colour_rms,
            "power": r.file.leds.iter().map(|l| l.power).collect::<Vec<_>>(),
            "true_power": r.true_power,
            "wall_s": t0.elapsed().as_secs_f64(),
            "out": out.display().to_string(),
        });
        println!("{v}");
        return Ok(());
    }
    println!(
        "{} calibration of {} ({} {}, {} frame(s) each at {:.4} s, seed {seed}):",
        light,
        cfg.rig.name,
        r.file.leds.len(),
        if dome.is_flash() { "flashes" } else { "LEDs" },
        r.file.source.frames_per_light,
        r.exposure_s
    );
    println!(
        "  reference rate {:.1} (true {:.1}, {:+.2} %)",
        r.file.reference_rate, r.true_reference_rate, reference_err
    );
    println!("  {light:>5}  power  (true)    err %   colour R/G  B/G  (true)");
    for (j, (e, (tp, tc))) in r.file.leds.iter().zip(r.true_power.iter().zip(&r.true_colour)).enumerate() {
        println!(
            "  {j:>5}  {:.4} ({:.4}) {:+6.2}   {:.4} {:.4} ({:.4} {:.4})",
            e.power, tp, power_err[j], e.colour[0], e.colour[2], tc[0], tc[2]
        );
    }
    println!(
        "  RMS error: power {power_rms:.3} % (max {power_max_err:.3} %, stated sigma {power_sigma_rms:.3} % rms, \
         max |error|/sigma {:.2}), colour {colour_rms:.3} %",
        power_z.iter().fold(0.0f64, |m, z| m.max(*z))
    );
    println!("wrote {} ({:.1} s)", out.display(), t0.elapsed().as_secs_f64());
    Ok(())
}

/// A captured LED calibration with the simulator's truth next to it (NaN on a real rig).
struct Captured {
    file: btfrig_calibrate::leds::LedCalibrationFile,
    exposure_s: f64,
    true_power: Vec<f64>,
    true_colour: Vec<[f64; 3]>,
    true_reference_rate: f64,
}
