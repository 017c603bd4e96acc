//! Which corner errors drive the texel error of one rendered gonio frame: the marker corners'
//! errors against the truth split across and along each marker's longer side, and the texel
//! error of the pose registered from them, from the corners with either part removed (an
//! oracle: only the simulator knows the truth), with and without the detector's module grid
//! fit. Used to find what limits registration at grazing views (docs/markers.md, step 6b).
//!
//! ```sh
//! cargo run --release -p btfrig-bench --example corner_errors -- THETA PHI SEED [RAYS]
//! ```
//!
//! THETA, PHI: the view in degrees (light at 45, 0); SEED: positioning error and sensor
//! noise; RAYS: the renderer's rays per edge photosite side (default 4). Run from the
//! repository root (it reads `rig-configs/bonn-gonio-sim.toml`).

use anyhow::Context;
use btfrig_bench::registration::Bench;
use btfrig_core::config::RigConfig;
use btfrig_markers::{Detection, GrayImage};
use btfrig_registration::{register, sample_to_camera, texel_position_error};
use btfrig_render::material::MaterialSpec;
use nalgebra::{Point2, Point3, Vector2};

fn main() -> anyhow::Result<()> {
    let usage = "usage: corner_errors THETA PHI SEED [RAYS] (degrees, seed, rays per edge photosite side 1..=32)";
    let args: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!((3..=4).contains(&args.len()), "{usage}");
    let num = |i: usize| args[i].parse::<f64>().with_context(|| format!("{:?} is not a number; {usage}", args[i]));
    let (theta, phi, seed) = (num(0)?, num(1)?, num(2)? as u64);
    let path = "rig-configs/bonn-gonio-sim.toml";
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {path}: run from the repository root"))?;
    let mut b = Bench::new(RigConfig::from_toml(&text, path)?, &MaterialSpec::builtin("lacquered-wood")?, 256)?;
    if args.len() == 4 {
        b.render.marker_supersampling = num(3)? as u32;
    }
    let frame = b.frame((theta, phi), seed)?;
    let nominal = b.scene.pose(&frame.commanded);
    let truth = b.scene.pose(&frame.truth);
    let to_camera = sample_to_camera(&truth);
    let cam = b.camera().clone();
    let img = GrayImage::new(frame.rgb.width, frame.rgb.height, &frame.green)?;
    println!(
        "view ({theta}, {phi}), seed {seed}, {} rays per edge photosite side: texel error mean / max of the pose",
        b.render.marker_supersampling
    );
    for grid in [true, false] {
        let mut registrar = b.registrar.clone();
        if !grid {
            registrar.detect.module_grid_below_px = 0.0;
        }
        let found = registrar.register_image(&img, &nominal)?;
        // The true corners of a detection, projected.
        let true_corners = |d: &Detection| -> Option<Vec<Point2<f64>>> {
            let m = registrar.markers().iter().find(|m| m.id == d.id)?;
            m.corners_sample_m.iter().map(|c| cam.project(&(to_camera * Point3::new(c.x, c.y, 0.0)))).collect()
        };
        let (mut across, mut along, mut n, mut across_sum) = (0.0, 0.0, 0.0, 0.0);
        let mut rows = Vec::new();
        for (name, keep_across, keep_along) in
            [("as detected", true, true), ("across error removed", false, true), ("along error removed", true, false)]
        {
            let mut dets = found.detections.clone();
            for d in &mut dets {
                let Some(tc) = true_corners(d) else { continue };
                let long = if (tc[1] - tc[0]).norm() >= (tc[2] - tc[1]).norm() { tc[1] - tc[0] } else { tc[2] - tc[1] };
                let u = long.normalize();
                let v = Vector2::new(-u.y, u.x);
                for (c, t) in d.corners.iter_mut().zip(&tc) {
                    let e = *c - t;
                    if keep_across && keep_along {
                        across += e.dot(&v).powi(2);
                        across_sum += e.dot(&v);
                        along += e.dot(&u).powi(2);
                        n += 1.0;
                    }
                    let a = if keep_across { e.dot(&v) } else { 0.0 };
                    let l = if keep_along { e.dot(&u) } else { 0.0 };
                    *c = t + v * a + u * l;
                }
            }
            let (corr, _, _) = registrar.correspondences(&dets);
            let pose = register(&corr, &cam, &nominal, &registrar.options)?.pose;
            let (mean, max) = texel_position_error(&truth, &pose, &cam, b.region, b.size);
            rows.push(format!("  {name}: {mean:.4} / {max:.4}"));
        }
        println!(
            "{}: {} markers, corner RMS across the long sides {:.4} px (mean {:+.4}), along {:.4} px",
            if grid { "module grid fit (default)" } else { "edge model only" },
            found.detections.len(),
            (across / n).sqrt(),
            across_sum / n,
            (along / n).sqrt()
        );
        for r in rows {
            println!("{r}");
        }
    }
    Ok(())
}
