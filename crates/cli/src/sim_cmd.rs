//! `btfrig sim render` and `btfrig sim materials`.

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_render::renderer::RenderOptions;
use btfrig_sim::capture;
use btfrig_sim::FaultScenario;

use crate::args::{parse_direction, RenderArgs};

/// Fraction of full scale at which automatic exposure puts a white reflector facing the lamp.
pub const AUTO_EXPOSURE_WHITE_FRACTION: f64 = 0.6;

/// `btfrig sim materials`.
pub fn materials() -> anyhow::Result<()> {
    for name in crate::material::names() {
        let spec = crate::material::load(Some(name))?;
        let default = if name == crate::material::DEFAULT_MATERIAL { " (default)" } else { "" };
        println!("{name:<16} {}{default}", spec.description);
    }
    Ok(())
}

/// `btfrig sim render`.
pub fn render(args: &RenderArgs) -> anyhow::Result<()> {
    let light = parse_direction("light", &args.light).map_err(anyhow::Error::msg)?;
    let view = parse_direction("view", &args.view).map_err(anyhow::Error::msg)?;
    check_extension(&args.out, &["exr", "png"], "--out")?;
    if let Some(p) = &args.preview {
        check_extension(p, &["png"], "--preview")?;
    }
    if let Some(p) = &args.ground_truth {
        check_extension(p, &["exr"], "--ground-truth")?;
    }
    anyhow::ensure!(
        (1..=8192).contains(&args.texture_size),
        "--texture-size {}: allowed 1..=8192 texels",
        args.texture_size
    );
    let mut cfg = crate::rig::load(args.rig.as_deref())?;
    let material = crate::material::load(args.material.as_deref())?;
    // One seed drives every random process of the simulated rig: noise and positioning error.
    let seed = args.seed.unwrap_or(cfg.rig.seed);
    cfg.rig.seed = seed;

    let rt = crate::session::virtual_time_runtime()?;
    let started = Instant::now();
    let (frame, truth_joints, commanded, lamp_intensity, hardware_s, scene) = rt.block_on(async {
        let mut session = crate::session::build(&cfg, &material, &FaultScenario::none())?;
        let (lo, hi) = session.rig.camera.capabilities().exposure_range_s;
        let exposure = match args.exposure {
            Some(e) => {
                anyhow::ensure!(e >= lo && e <= hi, "--exposure {e}: allowed {lo}..={hi} s for this camera");
                e
            }
            None => session.scene.exposure_for_white(AUTO_EXPOSURE_WHITE_FRACTION, lo, hi),
        };
        if args.nominal {
            let joints = session.scene.gonio().ik(light, view).map_err(|r| anyhow::anyhow!("pair unreachable: {r}"))?;
            let (frame, _) = session.scene.capture(&joints, 1.0, exposure, 1.0, seed, &RenderOptions::default())?;
            return Ok((frame, joints, joints, 1.0, 0.0, session.scene));
        }
        capture::prepare(&mut session.rig).await?;
        let cap = capture::capture_pair(&mut session.rig, session.scene.gonio(), light, view, exposure).await?;
        anyhow::Ok((
            cap.frame,
            cap.truth.joints,
            cap.commanded,
            cap.truth.lamp_intensity,
            cap.hardware_s,
            session.scene,
        ))
    })?;
    let render_s = started.elapsed().as_secs_f64();

    btfrig_imageio::write_raw_frame(&args.out, &frame)?;
    if let Some(p) = &args.preview {
        write_preview(&scene, &frame, p)?;
    }
    let gt_started = Instant::now();
    if let Some(p) = &args.ground_truth {
        let gt = scene.ground_truth(&truth_joints, lamp_intensity, args.texture_size);
        btfrig_imageio::write_rgb_exr(p, gt.width, gt.height, &gt.data)?;
    }
    let gt_s = gt_started.elapsed().as_secs_f64();

    let (l_true, v_true) = scene.gonio().fk(&truth_joints);
    println!("requested    light ({}) view ({})", deg(light), deg(view));
    println!("commanded    {}", joints(&commanded));
    println!("true pose    {}", joints(&truth_joints));
    println!(
        "achieved     light ({}) view ({}): off by {:.4} / {:.4} deg",
        deg(l_true),
        deg(v_true),
        light.angle_to(l_true).to_degrees(),
        view.angle_to(v_true).to_degrees()
    );
    println!(
        "frame        {}x{} {}-bit, exposure {:.4} s, {:.3}% saturated, seed {seed}",
        frame.width,
        frame.height,
        frame.meta.bit_depth,
        frame.meta.exposure_s,
        100.0 * saturated_fraction(&frame)
    );
    println!("hardware     {hardware_s:.2} s simulated (home, warm-up excluded), {render_s:.2} s wall");
    if args.ground_truth.is_some() {
        println!("ground truth {0}x{0} texels in {gt_s:.2} s", args.texture_size);
    }
    println!("wrote        {}", args.out.display());
    for p in args.preview.iter().chain(&args.ground_truth) {
        println!("wrote        {}", p.display());
    }
    Ok(())
}

/// Writes an 8-bit sRGB preview whose white is a white reflector facing the lamp.
pub fn write_preview(scene: &btfrig_render::rig_scene::RigScene, frame: &RawFrame, path: &Path) -> anyhow::Result<()> {
    let white = scene.white_signal_dn(frame.meta.exposure_s, frame.meta.gain);
    let rgb = scene.preview(frame, white);
    Ok(btfrig_imageio::write_srgb8_png(path, frame.width, frame.height, &rgb)?)
}

/// Fraction of photosites at the white level.
pub fn saturated_fraction(frame: &RawFrame) -> f64 {
    let n = frame.data.iter().filter(|&&v| v >= frame.meta.white_level).count();
    n as f64 / frame.data.len().max(1) as f64
}

fn check_extension(path: &Path, allowed: &[&str], flag: &str) -> anyhow::Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
    if allowed.contains(&ext.as_str()) {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            anyhow::ensure!(dir.is_dir(), "{flag} {}: directory {} does not exist", path.display(), dir.display());
        }
        Ok(())
    } else {
        Err(anyhow::anyhow!("{flag} {}: allowed extensions {}", path.display(), allowed.join(", ")))
            .context("bad output path")
    }
}

/// `theta, phi` in degrees.
pub fn deg(d: btfrig_core::Direction) -> String {
    let (t, p) = d.to_degrees();
    format!("{t:.2}, {p:.2}")
}

/// Joint values in degrees.
pub fn joints(j: &JointState) -> String {
    let r = j.robot.map(f64::to_degrees);
    format!("rail {:.3} deg, robot [pan {:.3}, tilt {:.3}, roll {:.3}] deg", j.rail.to_degrees(), r[0], r[1], r[2])
}
