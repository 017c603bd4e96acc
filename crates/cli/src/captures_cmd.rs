//! `btfrig sim captures`: a handful of captures on the embedded simulated
//! gonioreflectometer, through the device traits on virtual time, each written as raw frame,
//! preview and ground-truth texture (issue 2's demo; `btfrig demo` now runs a whole plan).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use btfrig_core::Direction;
use btfrig_sim::capture::{self, CaptureError};
use btfrig_sim::FaultScenario;
use serde_json::json;

use crate::args::CapturesArgs;
use crate::sim_cmd::{deg, saturated_fraction, write_preview, AUTO_EXPOSURE_WHITE_FRACTION};

/// Ground-truth texture size written per capture.
const DEMO_TEXTURE: usize = 256;

/// (light, view) pairs in degrees: frontal, oblique, grazing, a back-scatter pair, and
/// light == view, which the camera would block (to show a visible skip).
const DEMO_PAIRS: [((f64, f64), (f64, f64)); 6] = [
    ((45.0, 0.0), (0.0, 0.0)),
    ((30.0, 120.0), (45.0, 0.0)),
    ((75.0, 90.0), (30.0, 270.0)),
    ((60.0, 18.0), (75.0, 195.0)),
    ((15.0, 60.0), (60.0, 54.0)),
    ((30.0, 30.0), (30.0, 30.0)),
];

/// Runs `btfrig sim captures`.
pub fn run(args: &CapturesArgs) -> anyhow::Result<()> {
    let cfg = crate::rig::load(args.rig.as_deref())?;
    let material = crate::material::load(args.material.as_deref())?;
    let out = prepare_output(args.out.clone(), "btfrig-captures")?;
    let started = Instant::now();
    let rt = crate::session::virtual_time_runtime()?;
    let mut rows = Vec::new();
    let mut skipped = Vec::new();
    let (hardware_s, setup_s, render_totals) = rt.block_on(async {
        let mut s = crate::session::build(&cfg, &material, &FaultScenario::none())?;
        let clock = s.rig.world.clock().clone();
        capture::prepare(&mut s.rig).await?;
        let setup_s = clock.now_s();
        let (lo, hi) = s.rig.camera.capabilities().exposure_range_s;
        let exposure = s.scene.exposure_for_white(AUTO_EXPOSURE_WHITE_FRACTION, lo, hi);
        for (i, ((lt, lp), (vt, vp))) in DEMO_PAIRS.iter().enumerate() {
            let (light, view) = (Direction::from_degrees(*lt, *lp), Direction::from_degrees(*vt, *vp));
            let t0 = Instant::now();
            match capture::capture_pair(&mut s.rig, s.scene.gonio(), light, view, exposure).await {
                Err(CaptureError::Unreachable { reason, .. }) => {
                    skipped.push(json!({"light": deg(light), "view": deg(view), "reason": reason.to_string()}));
                    continue;
                }
                Err(e) => return Err(e.into()),
                Ok(cap) => {
                    let stem = format!("{i:02}_l{lt:03.0}_{lp:03.0}_v{vt:03.0}_{vp:03.0}");
                    btfrig_imageio::write_raw_frame(&out.join(format!("{stem}.raw.png")), &cap.frame)?;
                    write_preview(&s.scene, &cap.frame, &out.join(format!("{stem}.preview.png")))?;
                    let gt = s.scene.ground_truth(&cap.truth.joints, cap.truth.lamp_intensity, DEMO_TEXTURE);
                    btfrig_imageio::write_rgb_exr(
                        &out.join(format!("{stem}.truth.exr")),
                        gt.width,
                        gt.height,
                        &gt.data,
                    )?;
                    let (l2, v2) = s.scene.gonio().fk(&cap.truth.joints);
                    rows.push(json!({
                        "file": stem,
                        "light": deg(light),
                        "view": deg(view),
                        "pose_error_deg": [light.angle_to(l2).to_degrees(), view.angle_to(v2).to_degrees()],
                        "hardware_s": cap.hardware_s,
                        "wall_s": t0.elapsed().as_secs_f64(),
                        "saturated_percent": 100.0 * saturated_fraction(&cap.frame),
                    }));
                }
            }
        }
        anyhow::Ok((clock.now_s(), setup_s, s.source.totals()))
    })?;
    let (frames, st) = render_totals;
    let summary = json!({
        "rig": cfg.rig.name,
        "material": material.name,
        "captures": rows.len(),
        "skipped": skipped,
        "hardware_s": hardware_s,
        "setup_s": setup_s,
        "wall_s": started.elapsed().as_secs_f64(),
        "renderer": {
            "frames": frames,
            "pixels": st.pixels,
            "pixels_traced": st.pixels_traced,
            "shadow_rays": st.shadow_rays,
            "shadow_rays_skipped": st.shadow_rays_skipped,
        },
        "texture_size": DEMO_TEXTURE,
        "output": out.display().to_string(),
        "frames": rows,
    });
    std::fs::write(out.join("summary.json"), serde_json::to_string_pretty(&summary)? + "\n")
        .with_context(|| format!("cannot write {}", out.join("summary.json").display()))?;
    if args.json {
        println!("{summary}");
        return Ok(());
    }
    println!("btfrig sim captures: rig {}, material {}", cfg.rig.name, material.name);
    println!(
        "{:<26} {:<16} {:<16} {:>14} {:>10} {:>8}",
        "capture", "light (deg)", "view (deg)", "pose err (deg)", "hw (s)", "wall (s)"
    );
    for r in &rows {
        println!(
            "{:<26} {:<16} {:<16} {:>6.3} {:>6.3} {:>10.2} {:>8.2}",
            r["file"].as_str().unwrap_or(""),
            r["light"].as_str().unwrap_or(""),
            r["view"].as_str().unwrap_or(""),
            r["pose_error_deg"][0].as_f64().unwrap_or(0.0),
            r["pose_error_deg"][1].as_f64().unwrap_or(0.0),
            r["hardware_s"].as_f64().unwrap_or(0.0),
            r["wall_s"].as_f64().unwrap_or(0.0),
        );
    }
    for s in &skipped {
        println!(
            "skipped: light ({}) view ({}): {}",
            s["light"].as_str().unwrap_or(""),
            s["view"].as_str().unwrap_or(""),
            s["reason"].as_str().unwrap_or("")
        );
    }
    println!(
        "{} captures, {} skipped; simulated hardware time {:.1} s (of which homing and lamp warm-up {:.1} s); wall {:.2} s",
        rows.len(),
        skipped.len(),
        hardware_s,
        setup_s,
        started.elapsed().as_secs_f64()
    );
    println!(
        "renderer: traced {:.1}% of {} pixels (the rest lie outside the plate); {} shadow rays traced, {} proven unneeded",
        100.0 * st.pixels_traced as f64 / st.pixels.max(1) as f64,
        st.pixels,
        st.shadow_rays,
        st.shadow_rays_skipped
    );
    println!("wrote raw frames, previews and ground-truth textures to {}", out.display());
    Ok(())
}

/// The output directory: the one given (created; it must be empty so nothing is
/// overwritten) or a new one under the system's temporary directory.
pub fn prepare_output(out: Option<PathBuf>, prefix: &str) -> anyhow::Result<PathBuf> {
    let dir = match out {
        Some(d) => d,
        None => {
            let stamp =
                std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_millis()).unwrap_or(0);
            std::env::temp_dir().join(format!("{prefix}-{stamp}-{}", std::process::id()))
        }
    };
    if dir.exists() {
        let mut entries = std::fs::read_dir(&dir).with_context(|| format!("--out {}: cannot read", dir.display()))?;
        anyhow::ensure!(
            entries.next().is_none(),
            "--out {}: directory is not empty; this command writes only into a new or empty directory so nothing is overwritten",
            dir.display()
        );
    }
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}
