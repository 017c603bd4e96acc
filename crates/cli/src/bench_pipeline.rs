//! `btfrig bench pipeline`: arguments and display of `btfrig_bench::pipeline`'s measurements:
//! per-stage ms per frame of btfrig's raw-to-texture path and of the OpenCV pipeline on the
//! same frames, a memory pass as the floor, frames per second against the rig's capture
//! floor, texel and texture error against the truth, and the HDR merge before and after.

use std::process::Command;

use anyhow::Context;
use btfrig_bench::opencv::run_opencv;
use btfrig_bench::pipeline::{capture_floor_s, hdr, memory_pass, run_ours, run_whole_frame, Stages};
use btfrig_bench::registration::{Agg, Bench};

/// `btfrig bench pipeline`.
#[derive(Debug, clap::Args)]
pub struct BenchPipelineArgs {
    /// Rig config files, one table each (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Vec<std::path::PathBuf>,
    /// Views as THETA,PHI in degrees (light at 45,0); default 0,0 45,90 75,90 80,90 (grazing
    /// included).
    #[arg(long, num_args = 1.., value_parser = |s: &str| crate::args::parse_direction("views", s))]
    pub views: Vec<btfrig_core::Direction>,
    /// Texels per side of the texture over the sample.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    /// Timed repetitions of each stage (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Seed of positioning error and sensor noise (frame k uses seed + k).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Material of the sample.
    #[arg(long, default_value = "lacquered-wood")]
    pub material: String,
    /// Exposure ratio of the HDR bracket (the second frame's exposure over the first's).
    #[arg(long, default_value_t = 4.0)]
    pub hdr_ratio: f64,
    /// Rays per photosite side where a pixel sees a marker edge (the simulated sensor's
    /// integration of the hard edges, multi-jittered; the renderer's default is 4, which
    /// leaves a little sampling noise on each edge pixel). Allowed 1..=32.
    #[arg(long, default_value_t = 4)]
    pub marker_supersampling: u32,
    /// Run the OpenCV pipeline too (tests/markers/bench_opencv.py in the venv that
    /// tests/install-deps.sh makes).
    #[arg(long)]
    pub opencv: bool,
}

const DEFAULT_VIEWS: [(f64, f64); 4] = [(0.0, 0.0), (45.0, 90.0), (75.0, 90.0), (80.0, 90.0)];

fn add(a: &mut Stages, b: &Stages, n: f64) {
    a.demosaic_ms += b.demosaic_ms / n;
    a.detect_ms += b.detect_ms / n;
    a.register_ms += b.register_ms / n;
    a.rectify_ms += b.rectify_ms / n;
    a.radiometry_ms += b.radiometry_ms / n;
}

/// Runs the benchmark and prints one table per rig.
pub fn bench(a: &BenchPipelineArgs) -> anyhow::Result<()> {
    anyhow::ensure!((1..=100).contains(&a.repeat), "--repeat {}: allowed 1..=100", a.repeat);
    anyhow::ensure!(
        (1..=32).contains(&a.marker_supersampling),
        "--marker-supersampling {}: allowed 1..=32",
        a.marker_supersampling
    );
    anyhow::ensure!(a.hdr_ratio > 1.0 && a.hdr_ratio <= 1000.0, "--hdr-ratio {}: allowed (1, 1000]", a.hdr_ratio);
    let (views, rigs) = crate::bench_cmd::views_and_rigs(&a.views, &DEFAULT_VIEWS, &a.rig)?;
    let material = crate::material::load(Some(&a.material))?;
    let python = crate::bench_cmd::opencv_if_asked(a.opencv);
    println!(
        "pipeline benchmark: {} view(s) {:?} (light 45,0), {}x{} texels, material {}, seed {}, median of {} repeat(s), \
         {} rayon threads, marker edges rendered with {}x{} rays per photosite",
        views.len(),
        views,
        a.size,
        a.size,
        a.material,
        a.seed,
        a.repeat,
        rayon::current_num_threads(),
        a.marker_supersampling,
        a.marker_supersampling
    );
    for (label, cfg) in rigs {
        let mut b = Bench::new(cfg.clone(), &material, a.size).with_context(|| format!("rig {label}"))?;
        b.render.marker_supersampling = a.marker_supersampling;
        let (w, h) = (b.camera().width, b.camera().height);
        let n = views.len() as f64;
        let (mut ours, mut cv, mut before) = (Stages::default(), Stages::default(), Stages::default());
        let mut equal_to_before = 0usize;
        let (mut floor_ms, mut cv_frames) = (0.0, 0usize);
        let (mut agg_ours, mut agg_cv) = (Agg::default(), Agg::default());
        let (mut windowed, mut fallbacks, mut searched) = (0usize, 0usize, 0.0);
        let mut exposure_s = 0.0;
        let mut hdr_result = None;
        // Detection with every region searched at full resolution (the binned frames redone).
        let (mut full_res_detect, mut binned_views, mut max_shift, mut same_markers) = (0.0, 0usize, 0.0f64, true);
        println!("\n== rig {label}: {w}x{h} ==");
        for (k, &view) in views.iter().enumerate() {
            let frame = b.frame(view, a.seed + k as u64).with_context(|| format!("view {view:?}"))?;
            exposure_s = frame.raw.meta.exposure_s;
            // The path before the in-place mosaic first: it reads the registrar's learned
            // windows without changing them, so both search the same windows.
            let (old_stages, old_texture) = run_whole_frame(&b, &frame, a.repeat)?;
            add(&mut before, &old_stages, n);
            let o = run_ours(&b, &frame, a.repeat)?;
            add(&mut ours, &o.stages, n);
            let same = o.texture_data.iter().zip(&old_texture).all(|(p, q)| p.map(f32::to_bits) == q.map(f32::to_bits))
                && o.texture_data.len() == old_texture.len();
            equal_to_before += usize::from(same);
            floor_ms += memory_pass(&frame.raw, a.repeat) / n;
            windowed += usize::from(!o.search.whole_frame || o.search.fallback.is_some());
            fallbacks += usize::from(o.search.fallback.is_some());
            searched += o.search.pixels as f64 / o.search.frame_pixels as f64 / n;
            agg_ours.texel_mean.push(o.texel.0);
            agg_ours.texel_max = agg_ours.texel_max.max(o.texel.1);
            agg_ours.area = (agg_ours.area.0 + o.texture.0, agg_ours.area.1 + o.texture.1);
            if let Some(c) = o.corner_rms_px {
                agg_ours.corner_sq += c * c * 4.0 * 12.0;
                agg_ours.corner_n += 4 * 12;
            }
            let mut line = format!(
                "view {},{}: btfrig {:.1} ms (before: {:.1}; detect {:.1}, {} window(s), {:.1} % of the frame{}), {} \
                 markers, corner RMS {:.3} px, texel {:.4}/{:.3}, texture rel_rmse {:.4}{}",
                view.0,
                view.1,
                o.stages.total_ms(),
                old_stages.total_ms(),
                o.stages.detect_ms,
                o.search.windows,
                100.0 * o.search.pixels as f64 / o.search.frame_pixels as f64,
                o.search.fallback.as_ref().map_or(String::new(), |f| format!(", whole frame after: {f}")),
                o.markers,
                o.corner_rms_px.unwrap_or(f64::NAN),
                o.texel.0,
                o.texel.1,
                Agg::rel(o.texture),
                if same { "" } else { ", TEXTURE DIFFERS from the whole-frame demosaic's" }
            );
            match o.full_resolution_regions {
                Some(f) => {
                    full_res_detect += f.detect_ms / n;
                    binned_views += 1;
                    max_shift = max_shift.max(f.max_corner_shift_px);
                    same_markers &= f.same_markers;
                    line += &format!(
                        "; regions on {0}x{0} means (at full resolution: detect {1:.1} ms, corners {2:.1e} px apart{3})",
                        o.region_bin,
                        f.detect_ms,
                        f.max_corner_shift_px,
                        if f.same_markers { "" } else { ", OTHER MARKERS" }
                    );
                }
                None => full_res_detect += o.stages.detect_ms / n,
            }
            if let Some(py) = python.as_ref() {
                let mut cmd = Command::new(py.get_program());
                for (key, val) in py.get_envs() {
                    if let Some(v) = val {
                        cmd.env(key, v);
                    }
                }
                match run_opencv(&mut cmd, &b, &frame, a.repeat, k, true) {
                    Ok((s, _version, demosaic_s)) => {
                        let f = s.filters.first();
                        let st = Stages {
                            demosaic_ms: demosaic_s * 1e3,
                            detect_ms: s.detect_s * 1e3,
                            register_ms: s.register_s * 1e3,
                            rectify_ms: f.map_or(f64::NAN, |f| f.rectify_s * 1e3),
                            // The radiometric conversion is btfrig's on both sides.
                            radiometry_ms: o.stages.radiometry_ms,
                        };
                        add(&mut cv, &st, 1.0);
                        cv_frames += 1;
                        agg_cv.texel_mean.push(s.texel.0);
                        agg_cv.texel_max = agg_cv.texel_max.max(s.texel.1);
                        if let Some(f) = f {
                            agg_cv.area = (agg_cv.area.0 + f.area.0, agg_cv.area.1 + f.area.1);
                        }
                        if let Some(c) = s.corner_rms_px {
                            agg_cv.corner_sq += c * c * 4.0 * 12.0;
                            agg_cv.corner_n += 4 * 12;
                        }
                        line += &format!("; OpenCV {:.1} ms, texel {:.4}/{:.3}", st.total_ms(), s.texel.0, s.texel.1);
                        if let Some(e) = s.error {
                            line += &format!(" (OpenCV failed: {e})");
                        }
                    }
                    Err(e) => line += &format!("; OpenCV run failed: {e:#}"),
                }
            }
            println!("{line}");
            if k == 0 {
                hdr_result = Some(hdr(&b, &cfg, &frame, a.hdr_ratio, a.repeat)?);
            }
        }
        if cv_frames > 0 {
            let m = cv_frames as f64;
            cv = Stages {
                demosaic_ms: cv.demosaic_ms / m,
                detect_ms: cv.detect_ms / m,
                register_ms: cv.register_ms / m,
                rectify_ms: cv.rectify_ms / m,
                radiometry_ms: cv.radiometry_ms / m,
            };
        }
        let have_cv = cv_frames > 0;
        let row = |name: &str, o: f64, c: f64| {
            if have_cv && o < 0.05 {
                // Nothing measurable on btfrig's side (the demosaic is done in place).
                println!("{name:<28} {o:>10.1} {c:>10.1} {:>12}", "-");
            } else if have_cv {
                println!("{name:<28} {o:>10.1} {c:>10.1} {:>12.2}", c / o);
            } else {
                println!("{name:<28} {o:>10.1} {:>10} {:>12}", "-", "-");
            }
        };
        println!("{:<28} {:>10} {:>10} {:>12}", "stage (ms per frame)", "btfrig", "OpenCV", "OpenCV/btfrig");
        row("demosaic", ours.demosaic_ms, cv.demosaic_ms);
        row("marker detection", ours.detect_ms, cv.detect_ms);
        row("registration / homography", ours.register_ms, cv.register_ms);
        row("rectification", ours.rectify_ms, cv.rectify_ms);
        row("radiometry (btfrig's, both)", ours.radiometry_ms, cv.radiometry_ms);
        row("total", ours.total_ms(), cv.total_ms());
        println!(
            "memory pass (read every photosite, write it as f32): {floor_ms:.1} ms; btfrig total / floor = {:.2}",
            ours.total_ms() / floor_ms
        );
        if binned_views > 0 {
            println!(
                "region search on binned pixels in {binned_views} of {} view(s) (every marker's modules {} px or \
                 more): detection {:.1} ms against {full_res_detect:.1} ms with every region at full resolution \
                 ({:.2}x faster), total / floor {:.2} at full resolution; corners at most {max_shift:.1e} px apart, \
                 {} markers",
                views.len(),
                btfrig_bench::pipeline::BIN_MIN_MODULE_PX,
                ours.detect_ms,
                full_res_detect / ours.detect_ms,
                (ours.total_ms() - ours.detect_ms + full_res_detect) / floor_ms,
                if same_markers { "the same" } else { "OTHER" }
            );
        }
        println!(
            "before (whole-frame demosaic, green copied out, separate vignetting map; same run): demosaic {:.1}, \
             detection {:.1}, registration {:.1}, rectification {:.1}, radiometry {:.1}, total {:.1} ms = {:.2}x \
             btfrig's now, {:.2}x the floor; textures equal bit for bit on {equal_to_before} of {} view(s)",
            before.demosaic_ms,
            before.detect_ms,
            before.register_ms,
            before.rectify_ms,
            before.radiometry_ms,
            before.total_ms(),
            before.total_ms() / ours.total_ms(),
            before.total_ms() / floor_ms,
            views.len()
        );
        let capture = capture_floor_s(&cfg, exposure_s, w, h);
        println!(
            "frames per second: btfrig {:.1}{}; the rig captures at most {:.3} per second (trigger + exposure + \
             read-out + transfer = {capture:.2} s): processing takes {:.2} % of a capture's time",
            1e3 / ours.total_ms(),
            if have_cv { format!(", OpenCV {:.1}", 1e3 / cv.total_ms()) } else { String::new() },
            1.0 / capture,
            100.0 * ours.total_ms() * 1e-3 / capture
        );
        let rms = |g: &Agg| if g.corner_n > 0 { (g.corner_sq / g.corner_n as f64).sqrt() } else { f64::NAN };
        println!(
            "against the truth: btfrig texel {:.4} / {:.3} (mean / max), texture rel_rmse {:.4}, corner RMS {:.3} px",
            btfrig_bench::registration::mean(&agg_ours.texel_mean),
            agg_ours.texel_max,
            Agg::rel(agg_ours.area),
            rms(&agg_ours)
        );
        if have_cv {
            println!(
                "                  OpenCV texel {:.4} / {:.3}, texture rel_rmse {:.4}, corner RMS {:.3} px",
                btfrig_bench::registration::mean(&agg_cv.texel_mean),
                agg_cv.texel_max,
                Agg::rel(agg_cv.area),
                rms(&agg_cv)
            );
        }
        println!(
            "marker search: {windowed} of {} frame(s) searched in predicted windows ({fallbacks} fell back to the \
             whole frame), {:.1} % of the pixels on average",
            views.len(),
            100.0 * searched
        );
        if let Some(r) = hdr_result {
            println!(
                "HDR merge of a 2-frame bracket (exposures 1 : {}) on the first view: before (merge_bracket_reference) \
                 {:.1} ms, after (merge_bracket_into, planes reused) {:.1} ms, {:.2}x faster; largest relative difference {:.1e}, same \
                 exposures used {}, {} photosites saturated in both",
                a.hdr_ratio,
                r.reference_ms,
                r.fast_ms,
                r.reference_ms / r.fast_ms,
                r.max_rel_diff,
                r.same_used,
                r.saturated_everywhere
            );
        }
    }
    println!(
        "\nbtfrig: the raw mosaic read in place (bilinear demosaic computed only at the pixels read: the demosaic row \
         is wrapping the frame), its green filled in the windows of PlateRegistrar::register_grey's search (predicted \
         from the nominal pose, learned tolerance, whole frame on a miss) + RANSAC/LM, bilinear rectification with \
         the vignetting map from the same projections, radiometric conversion. OpenCV: cvtColor demosaic of the raw uint16 frame, ArUco \
         (CORNER_REFINE_SUBPIX) on its green channel (8-bit conversion untimed), undistortPoints + findHomography \
         (RANSAC), remap (undistortion maps untimed) + warpPerspective INTER_LINEAR, btfrig's radiometric conversion."
    );
    Ok(())
}
