//! Time against error of the rectification filters, per material and view angle.
//!
//! `cargo run --release -p btfrig-imaging --example rectify_bench [SIZE]` (default 256).
//! For each material and view (light at theta 45, phi 0; views at phi 90, off the specular direction), one seeded frame of the default
//! simulated rig is rectified with the nominal pose, converted to the radiance factor and
//! compared with the ground truth: point-sampled (the renderer's definition) and
//! area-averaged (4x4 points per texel). "clean" is the same rectification of the noise-free
//! radiance image (no sensor noise, no demosaic): what resampling and the colour matrix alone
//! cost. Times are the best of 3 of `rectify` alone (conversion excluded), 2 rayon threads.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::Instant;

use btfrig_imaging::{rectify, Filter};
use common::*;

fn main() {
    let size: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(256);
    let filters = [
        Filter::Bilinear,
        Filter::Supersample { n: 2 },
        Filter::Supersample { n: 4 },
        Filter::Footprint { max: 4 },
        Filter::Footprint { max: 8 },
        Filter::Ewa,
    ];
    println!(
        "texture {size}x{size}; light theta 45 deg; rel_rmse vs point / box ground truth; clean = noise-free frame"
    );
    println!(
        "{:<15} {:>6} {:<22} {:>9} {:>10} {:>10} {:>10} {:>10}",
        "material", "view", "filter", "time_ms", "rel_point", "rel_box", "clean_pt", "clean_box"
    );
    for material in ["lacquered-wood", "corduroy"] {
        let s = Setup::new(material);
        for view in [(0.0, 0.0), (45.0, 90.0), (75.0, 90.0)] {
            let joints = s.joints((45.0, 0.0), view);
            let shot = shoot(&s, joints, 7);
            let clean = noise_free(&s, joints);
            let gt = ground_truth(&s, &joints, size);
            let gt_box = ground_truth_box(&s, &joints, size, 4);
            let pose = s.scene.pose(&joints);
            let cam = s.scene.camera().model();
            for f in filters {
                let mut best = f64::INFINITY;
                for _ in 0..3 {
                    let t0 = Instant::now();
                    let t = rectify(&shot.image, cam, &pose, s.region(), size, f).unwrap();
                    best = best.min(t0.elapsed().as_secs_f64());
                    std::hint::black_box(t);
                }
                let t = rectified(&s, &shot, &joints, size, f);
                let c = rectified(&s, &clean, &joints, size, f);
                println!(
                    "{:<15} {:>6} {:<22} {:>9.2} {:>10.4} {:>10.4} {:>10.4} {:>10.4}",
                    material,
                    view.0,
                    format!("{f:?}"),
                    best * 1e3,
                    err(&t, &gt).rel_rmse,
                    err(&t, &gt_box).rel_rmse,
                    err(&c, &gt).rel_rmse,
                    err(&c, &gt_box).rel_rmse,
                );
            }
        }
    }
}
