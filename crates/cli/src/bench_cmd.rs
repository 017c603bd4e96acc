//! `btfrig bench render` and `btfrig bench registration`: arguments and display of
//! `btfrig_bench::render`'s and `btfrig_bench::registration`'s measurements (with the OpenCV
//! peer, `btfrig_bench::opencv`).

use std::collections::BTreeMap;
use std::process::Command;

use anyhow::Context;
use btfrig_core::config::RigConfig;

use btfrig_bench::opencv::{python_with_opencv, run_opencv};
use btfrig_bench::registration::{mean, Agg, Bench, FILTERS};
use btfrig_bench::render::bench_material as render_material;

use crate::args::BenchRegistrationArgs;

/// Runs the benchmark and prints one row per (material, pose).
pub fn render(rig: Option<&std::path::Path>, materials: &[String], texels: usize, repeat: usize) -> anyhow::Result<()> {
    anyhow::ensure!((2..=4096).contains(&texels), "--texels {texels}: allowed 2..=4096");
    anyhow::ensure!((1..=100).contains(&repeat), "--repeat {repeat}: allowed 1..=100");
    let cfg = crate::rig::load(rig)?;
    let names: Vec<String> = if materials.is_empty() {
        crate::material::names().iter().map(|s| s.to_string()).collect()
    } else {
        materials.to_vec()
    };
    println!(
        "render benchmark: {}x{} frame, {texels}x{texels}-texel sample, {} rayon threads, median of {repeat}",
        cfg.camera.width_px,
        cfg.camera.height_px,
        rayon::current_num_threads()
    );
    println!(
        "{:<16} {:<8} {:>10} {:>10} {:>6} {:>10} {:>10} {:>12} {:>12} {:>10}",
        "material",
        "pose",
        "skips (s)",
        "none (s)",
        "ratio",
        "max diff",
        "traced %",
        "shadow rays",
        "skipped rays",
        "sensor (s)"
    );
    for name in &names {
        let material = crate::material::load(Some(name))?.with_texels(texels);
        for r in render_material(&cfg, &material, repeat)? {
            println!(
                "{:<16} {:<8} {:>10.3} {:>10.3} {:>6.2} {:>10.1e} {:>10.1} {:>12} {:>12} {:>10.3}",
                name,
                r.pose,
                r.skips_s,
                r.none_s,
                r.none_s / r.skips_s,
                r.max_diff,
                r.traced_pct,
                r.shadow_rays,
                r.skipped_rays,
                r.sensor_s
            );
        }
    }
    println!("max diff: largest |skips - none| over all pixels and channels, relative to the image's peak");
    Ok(())
}

// ---- `btfrig bench registration` ----

/// Views of the benchmark when none are given (theta, phi in degrees; light at 45, 0).
const DEFAULT_VIEWS: [(f64, f64); 6] =
    [(0.0, 0.0), (45.0, 90.0), (45.0, 270.0), (75.0, 90.0), (75.0, 270.0), (80.0, 90.0)];

/// Order of the settings in the tables.
const SETTINGS: [&str; 7] = ["nominal", "true", "dlt", "lm", "lm+prior", "lm-roi", "opencv"];

fn fmt(v: f64, prec: usize) -> String {
    if v.is_finite() {
        format!("{v:.prec$}")
    } else {
        "-".into()
    }
}

/// The Python with OpenCV when `--opencv` asks for it; without it (a note printed) the
/// benchmark runs btfrig's side only.
pub(crate) fn opencv_if_asked(opencv: bool) -> Option<std::process::Command> {
    if !opencv {
        return None;
    }
    python_with_opencv().map_err(|why| println!("OpenCV not available ({why}); running without it")).ok()
}

/// Views as (theta, phi) degrees, and rigs as (label, config).
type ViewsAndRigs = (Vec<(f64, f64)>, Vec<(String, RigConfig)>);

/// The views (degrees) and rigs a frame benchmark runs on: `views` or the defaults, `rigs` (each
/// by its path) or the embedded simulated gonioreflectometer.
pub(crate) fn views_and_rigs(
    views: &[btfrig_core::Direction],
    default_views: &[(f64, f64)],
    rigs: &[std::path::PathBuf],
) -> anyhow::Result<ViewsAndRigs> {
    let views = if views.is_empty() {
        default_views.to_vec()
    } else {
        views.iter().map(|d| (d.theta.to_degrees(), d.phi.to_degrees())).collect()
    };
    let rigs = if rigs.is_empty() {
        vec![("bonn-gonio-sim (embedded)".into(), crate::rig::load(None)?)]
    } else {
        rigs.iter().map(|p| Ok((p.display().to_string(), crate::rig::load(Some(p))?))).collect::<anyhow::Result<_>>()?
    };
    Ok((views, rigs))
}

/// Runs the benchmark and prints the tables.
pub fn registration(a: &BenchRegistrationArgs) -> anyhow::Result<()> {
    anyhow::ensure!((1..=100).contains(&a.repeat), "--repeat {}: allowed 1..=100", a.repeat);
    let (views, rigs) = crate::bench_cmd::views_and_rigs(&a.views, &DEFAULT_VIEWS, &a.rig)?;
    let material = crate::material::load(Some(&a.material))?;
    let mut python = crate::bench_cmd::opencv_if_asked(a.opencv);
    let mut opencv_version = None;
    println!(
        "registration benchmark: {} view(s) {:?} (light 45,0), {}x{} texels over the sample, material {}, seed {}, \
         median of {} repeat(s), {} rayon threads",
        views.len(),
        views,
        a.size,
        a.size,
        a.material,
        a.seed,
        a.repeat,
        rayon::current_num_threads()
    );
    // (rig label, image size, totals per (setting, filter)).
    type RigTotals = (String, String, BTreeMap<(usize, usize), Agg>);
    let mut all: Vec<RigTotals> = Vec::new();
    for (label, cfg) in rigs {
        let b = Bench::new(cfg, &material, a.size).with_context(|| format!("rig {label}"))?;
        let res = format!("{}x{}", b.camera().width, b.camera().height);
        println!("\n== rig {label}: {res} ==");
        let mut aggs: BTreeMap<(usize, usize), Agg> = BTreeMap::new();
        if a.per_view {
            println!(
                "{:<8} {:<9} {:>4} {:>9} {:>9} {:>8} {:>8} {:>8} {:>15} {:>9} {:>9} {:>9}",
                "view",
                "setting",
                "mk",
                "detect",
                "register",
                "tx mean",
                "tx max",
                "corner",
                "bias x,y",
                "pt bil",
                "area bil",
                "clean bil"
            );
        }
        for (k, &view) in views.iter().enumerate() {
            let frame = b.frame(view, a.seed + k as u64).with_context(|| format!("view {view:?}"))?;
            let mut results = b.run_ours(&frame, a.repeat)?;
            if let Some(w) = b.last_window_stats() {
                println!(
                    "view {},{}: lm-roi searched {} window(s) for {:.2} deg / {:.1} mm, {:.1} % of the frame{}; \
                     markers and corners {} the whole-frame search's",
                    frame.view_deg.0,
                    frame.view_deg.1,
                    w.windows,
                    w.tolerance.0,
                    w.tolerance.1 * 1e3,
                    100.0 * w.pixel_fraction,
                    if w.fell_back { ", then the whole frame (missed)" } else { "" },
                    if w.same_as_whole_frame { "equal to" } else { "DIFFER from" }
                );
            }
            if let Some(py) = python.as_mut() {
                let mut cmd = Command::new(py.get_program());
                for (key, val) in py.get_envs() {
                    if let Some(v) = val {
                        cmd.env(key, v);
                    }
                }
                match run_opencv(&mut cmd, &b, &frame, a.repeat, k, false) {
                    Ok((s, v, _)) => {
                        opencv_version = Some(v);
                        results.push(s);
                    }
                    Err(e) => println!("OpenCV run failed on view {view:?}: {e:#}"),
                }
            }
            for s in &results {
                let si = SETTINGS.iter().position(|n| *n == s.setting).unwrap_or(SETTINGS.len());
                if s.filters.is_empty() {
                    aggs.entry((si, 0)).or_default().add(s, None);
                }
                for f in &s.filters {
                    let fi = FILTERS
                        .iter()
                        .position(|g| btfrig_bench::registration::filter_name(*g) == f.filter)
                        .unwrap_or(0);
                    aggs.entry((si, fi)).or_default().add(s, Some(f));
                }
                if a.per_view {
                    let bias = s.corner_bias_px.map_or("-".into(), |(x, y)| format!("{x:+.3},{y:+.3}"));
                    let f0 = s.filters.first();
                    let pick = |g: fn(&btfrig_bench::registration::FilterResult) -> f64| f0.map_or(f64::NAN, g);
                    println!(
                        "{:<8} {:<9} {:>4} {:>9} {:>9} {:>8} {:>8} {:>8} {:>15} {:>9} {:>9} {:>9}{}",
                        format!("{},{}", frame.view_deg.0, frame.view_deg.1),
                        s.setting,
                        s.markers,
                        fmt(s.detect_s * 1e3, 1),
                        fmt(s.register_s * 1e3, 2),
                        fmt(s.texel.0, 4),
                        fmt(s.texel.1, 3),
                        s.corner_rms_px.map_or("-".into(), |c| fmt(c, 3)),
                        bias,
                        fmt(pick(|f| f.rel_point()), 4),
                        fmt(pick(|f| f.rel_area()), 4),
                        fmt(pick(|f| f.rel_clean()), 4),
                        s.error.as_ref().map_or(String::new(), |e| format!("  FAILED: {e}"))
                    );
                }
            }
        }
        println!(
            "{:<9} {:<13} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>8} {:>9} {:>9} {:>9} {:>5}",
            "setting",
            "filter",
            "detect",
            "register",
            "rectify",
            "total ms",
            "tx mean",
            "tx max",
            "corner",
            "rel_pt",
            "rel_area",
            "clean",
            "fail"
        );
        for ((si, _fi), g) in &aggs {
            let setting = SETTINGS.get(*si).copied().unwrap_or("?");
            let filter = if setting == "opencv" {
                "linear".to_string()
            } else {
                btfrig_bench::registration::filter_name(FILTERS[*_fi])
            };
            println!(
                "{:<9} {:<13} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>8} {:>9} {:>9} {:>9} {:>5}",
                setting,
                filter,
                fmt(1e3 * mean(&g.detect_s), 1),
                fmt(1e3 * mean(&g.register_s), 2),
                fmt(1e3 * mean(&g.rectify_s), 1),
                fmt(g.total_ms(), 1),
                fmt(mean(&g.texel_mean), 4),
                fmt(g.texel_max, 3),
                fmt(if g.corner_n > 0 { (g.corner_sq / g.corner_n as f64).sqrt() } else { f64::NAN }, 3),
                fmt(Agg::rel(g.point), 4),
                fmt(Agg::rel(g.area), 4),
                fmt(Agg::rel(g.clean), 4),
                g.failed
            );
        }
        all.push((label, res, aggs));
    }
    if all.len() > 1 {
        println!("\n== side by side: total ms per frame | texel mean / max | rel_rmse area-averaged truth ==");
        print!("{:<9} {:<13}", "setting", "filter");
        for (_, res, _) in &all {
            print!(" | {:^32}", res);
        }
        println!();
        let keys: std::collections::BTreeSet<(usize, usize)> =
            all.iter().flat_map(|(_, _, m)| m.keys().copied()).collect();
        for key in keys {
            let setting = SETTINGS.get(key.0).copied().unwrap_or("?");
            let filter = if setting == "opencv" {
                "linear".to_string()
            } else {
                btfrig_bench::registration::filter_name(FILTERS[key.1])
            };
            print!("{setting:<9} {filter:<13}");
            for (_, _, m) in &all {
                match m.get(&key) {
                    Some(g) => print!(
                        " | {:>8} {:>7}/{:<6} {:>8}",
                        fmt(g.total_ms(), 1),
                        fmt(mean(&g.texel_mean), 4),
                        fmt(g.texel_max, 3),
                        fmt(Agg::rel(g.area), 4)
                    ),
                    None => print!(" | {:^32}", "-"),
                }
            }
            println!();
        }
    }
    println!(
        "\ndetect/register/rectify: ms per frame (median of repeats, mean over views); total = their sum. \
         tx: texel position error (mean over views of the per-frame mean; max over all). corner: RMS distance of \
         detected corners from the projected true ones, px. rel_pt / rel_area: texture rel_rmse against the \
         point-sampled / {0}x{0}-area-averaged ground truth, pooled over views; clean: the same rectification of the \
         noise-free radiance image (no sensor noise, no demosaic) against the area-averaged truth.",
        btfrig_bench::registration::BOX_SAMPLES
    );
    println!(
        "settings: nominal = kinematic pose; dlt = normalised DLT on all detected corners (undistorted), decomposed, \
         no LM; lm = marker-pair RANSAC + LM on the whole-frame detections; lm-roi = lm on the detections in windows \
         predicted from the nominal pose within the estimator's gate (PlateRegistrar::register_image's default; \
         bilinear only); lm+prior = lm with a weak prior of \
         {:?} (deg, m); opencv = {} (aruco SUBPIX + undistortPoints + findHomography RANSAC; rectify = remap \
         undistort + warpPerspective INTER_LINEAR; times from Python's perf_counter around the cv2 calls).",
        btfrig_bench::registration::PRIOR_SIGMA,
        opencv_version.map_or("not run".to_string(), |v| format!("OpenCV {v}"))
    );
    Ok(())
}
