//! Render time of a 1600x1200 frame with a 256x256-texel sample, skips on and off, side by
//! side. Run: `cargo bench -p btfrig-render --bench render`. Prints a table (best of N runs).

use std::time::Instant;

use btfrig_core::config::plate::PlateConfig;
use btfrig_core::pose::ScenePose;
use btfrig_core::Direction;
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::{Pinhole, RenderOptions, RenderStats, Renderer};

fn resolver(name: &str) -> Result<([f64; 3], [f64; 3]), String> {
    let x = name.strip_prefix("flat:").and_then(|v| v.parse().ok()).unwrap_or(0.4);
    Ok(([x, 0.9 * x, 0.7 * x], [x; 3]))
}

fn best_of(n: usize, f: impl Fn() -> RenderStats) -> (f64, RenderStats) {
    let mut best = f64::INFINITY;
    let mut stats = RenderStats::default();
    for _ in 0..n {
        let t = Instant::now();
        stats = f();
        best = best.min(t.elapsed().as_secs_f64());
    }
    (best, stats)
}

fn main() {
    let runs: usize = std::env::var("BTFRIG_BENCH_RUNS").ok().and_then(|v| v.parse().ok()).unwrap_or(3);
    // The 0.2 m plate spans ~1070 px from 1.5 m: the 0.1 m sample covers ~535 x 535 px, about
    // two pixels per texel, as a rig would frame it.
    let cam = Pinhole { width: 1600, height: 1200, fx: 8000.0, fy: 8000.0, cx: 799.5, cy: 599.5 };
    println!(
        "1600x1200 frame, 256x256-texel sample, {} rayon threads, best of {runs} with skips, 1 run without",
        rayon::current_num_threads()
    );
    println!(
        "{:<15} {:>14} {:>10} {:>10} {:>7} | {:>9} {:>11} {:>11} {:>11} {:>9}",
        "material",
        "light/view",
        "skips on",
        "skips off",
        "ratio",
        "traced",
        "march cells",
        "shadow rays",
        "skipped",
        "shadowed"
    );
    for name in ["lacquered-wood", "corduroy", "glazed-tile", "leather"] {
        let spec = MaterialSpec::builtin(name).unwrap().with_texels(256);
        let r = Renderer::new(&PlateConfig::default(), &spec, 1000.0, &resolver).unwrap();
        for ((lt, lp), (vt, vp)) in
            [((45.0, 0.0), (0.0, 0.0)), ((60.0, 30.0), (45.0, 180.0)), ((75.0, 0.0), (60.0, 90.0))]
        {
            let pose =
                ScenePose::looking_at(Direction::from_degrees(lt, lp), Direction::from_degrees(vt, vp), 1.5, 2.0);
            let (t_on, s_on) = best_of(runs, || r.render_with_stats(&pose, &cam, &RenderOptions::with_skips(true)).1);
            let (t_off, s_off) = best_of(1, || r.render_with_stats(&pose, &cam, &RenderOptions::with_skips(false)).1);
            println!(
                "{:<15} {:>14} {:>9.3}s {:>9.3}s {:>6.2}x | {:>9} {:>11} {:>11} {:>11} {:>9}",
                name,
                format!("{lt}/{lp} {vt}/{vp}"),
                t_on,
                t_off,
                t_off / t_on,
                format!("{}", s_on.pixels_traced),
                format!("{}", s_on.march_cells),
                format!("{}", s_on.shadow_rays),
                format!("{}", s_on.shadow_rays_skipped),
                format!("{}", s_on.shadowed),
            );
            println!(
                "{:<15} {:>14} {:>10} {:>10} {:>7} | {:>9} {:>11} {:>11} {:>11} {:>9}",
                "",
                "(skips off)",
                "",
                "",
                "",
                s_off.pixels_traced,
                s_off.march_cells,
                s_off.shadow_rays,
                s_off.shadow_rays_skipped,
                s_off.shadowed
            );
        }
    }
}
