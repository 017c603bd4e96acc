//! `btfrig compress` and `btfrig dataset export` on datasets of the dome rigs (issue 25): a
//! small LED dome run (one camera at two turntable rotations under all 198 LEDs) and small
//! camera-array runs (a 7-camera array made from the Bonn camera array's config), each with
//! the real binary. Checked: the per-capture (light, view) directions of the model against
//! the dome geometry computed here from the rig config (LED and camera positions turned by
//! the turntable angle); the model's error against the stored textures, recomputed here; the
//! configured terms and the compression ratio against the file's size; the streaming sink fed
//! the dataset's own step ids; the Bonn export: refused for the dome (its lights move in the
//! sample frame with the turntable), refused for a camera array measuring fewer cameras than
//! flashes, written for a camera array measuring every camera and read back.

mod support;

use std::path::{Path, PathBuf};

use btfrig_compress::dataset::DatasetSource;
use btfrig_compress::{file, ubo, Method, Model, ModelParams, RowSource};
use btfrig_core::config::RigConfig;
use btfrig_core::Direction;
use support::{btfrig, ok, repo, scratch, text};

/// The dome demo plan with one camera (2) at rotations 0 and 3 and 16 x 16 textures.
fn dome_plan(dir: &Path) -> PathBuf {
    let demo = std::fs::read_to_string(repo("rig-configs/plans/dome-demo.toml")).unwrap();
    let text = demo.replace("cameras = [2, 6]", "cameras = [2]").replace("texture_size = 32", "texture_size = 16");
    assert!(text.contains("cameras = [2]\n") && text.contains("rotations = [0, 3]"), "{text}");
    let p = dir.join("dome.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// A 7-camera array (the zenith camera and the 11-degree ring of 6 of the Bonn camera
/// array's config, each with its flash) and a plan over `cameras`.
fn camera_array_plan(dir: &Path, name: &str, cameras: &str) -> PathBuf {
    let cfg = std::fs::read_to_string(repo("rig-configs/bonn-camera-array-sim.toml")).unwrap();
    let start = cfg.find("camera_rings = [").unwrap();
    let end = start + cfg[start..].find("]\n").unwrap() + 2;
    let cfg = format!(
        "{}camera_rings = [\n  {{ theta_deg = 0.0, count = 1 }},\n  {{ theta_deg = 11.0, count = 6, phi_offset_deg = 15.0 }},\n]\n{}",
        &cfg[..start],
        &cfg[end..]
    )
    .replace("count = 151", "count = 7")
    .replace("name = \"bonn-camera-array-sim\"", "name = \"camera-array-7\"")
    // The shipped flash calibration is of all 151 flashes: this 7-flash array has none
    // (relative units, which compress as well).
    .replace("led_calibration = \"builtin:bonn-camera-array-sim-flashes\"", "");
    std::fs::write(dir.join("array7.toml"), cfg).unwrap();
    let demo = std::fs::read_to_string(repo("rig-configs/plans/camera-array-demo.toml")).unwrap();
    let text = demo
        .replace("config = \"builtin:bonn-camera-array-sim\"", "config = \"array7.toml\"")
        .replace("cameras = [0, 31, 103]", &format!("cameras = {cameras}"))
        .replace("texture_size = 32", "texture_size = 16")
        .replace("reference_leds = 4", "reference_leds = 0");
    let p = dir.join(format!("{name}.toml"));
    std::fs::write(&p, text).unwrap();
    p
}

fn run(plan: &Path, out: &Path) {
    ok(btfrig().arg("run").arg("--plan").arg(plan).arg("--out").arg(out));
}

/// Relative RMSE of the model against every stored texture, computed here.
fn error_against_textures(model: &Model, dir: &Path) -> f64 {
    let mut src = DatasetSource::open(dir).unwrap();
    let (mut e, mut t) = (0.0f64, 0.0f64);
    src.for_each(&mut |l, v, tex| {
        let m = model.texture(model.layout.index(l as usize, v as usize));
        for (p, q) in tex.iter().zip(&m) {
            for c in 0..3 {
                e += f64::from(p[c] - q[c]).powi(2);
                t += f64::from(p[c]).powi(2);
            }
        }
        Ok(())
    })
    .unwrap();
    (e / t).sqrt()
}

/// The least relative RMSE any model of the form "row mean + rank `k`" per RGB channel can
/// reach on the stored textures (an FMF in RGB): Eckart–Young on each channel's row-centred
/// captures x texels matrix, from a dense SVD here.
fn optimal_rel_error(dir: &Path, k: usize) -> f64 {
    let mut src = DatasetSource::open(dir).unwrap();
    let (m, n) = (src.layout().n_measured(), src.layout().texels());
    let mut b = vec![nalgebra::DMatrix::<f64>::zeros(m, n); 3];
    let mut row = 0;
    src.for_each(&mut |_, _, tex| {
        for (x, p) in tex.iter().enumerate() {
            for c in 0..3 {
                b[c][(row, x)] = f64::from(p[c]);
            }
        }
        row += 1;
        Ok(())
    })
    .unwrap();
    let (mut e, mut t) = (0.0, 0.0);
    for mut bc in b {
        t += bc.norm_squared();
        for mut r in bc.row_iter_mut() {
            let mean = r.mean();
            r.add_scalar_mut(-mean);
        }
        let mut s: Vec<f64> = bc.singular_values().iter().copied().collect();
        s.sort_by(|a, b| b.total_cmp(a));
        e += s.iter().skip(k).map(|x| x * x).sum::<f64>();
    }
    (e / t).sqrt()
}

fn compress_json(dir: &Path, args: &[&str]) -> serde_json::Value {
    let out = ok(btfrig().arg("compress").arg(dir).args(args).arg("--json"));
    serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"))
}

/// `direction` turned by `-angle_deg` about the sample normal: a world direction in the frame
/// of a sample that the turntable turned by `angle_deg`.
fn in_sample_frame(d: Direction, angle_deg: f64) -> Direction {
    let (t, p) = d.to_degrees();
    Direction::from_degrees(t, p - angle_deg)
}

#[test]
fn a_dome_dataset_compresses_with_each_captures_directions_and_its_export_is_refused() {
    let dir = scratch("compress-dome");
    let ds = dir.join("dome");
    run(&dome_plan(&dir), &ds);

    // FMF 8,4,4 terms (yuv, f16, the defaults but the terms): captures, layout and ratio as
    // configured.
    let j = compress_json(&ds, &["--terms", "8,4,4"]);
    assert_eq!(j["captures"], 396, "{j}");
    assert_eq!((j["lights"].as_u64(), j["views"].as_u64()), (Some(198), Some(2)), "{j}");
    // Dataset view id = rotation x 11 cameras + camera: camera 2 at rotations 0 and 3.
    assert_eq!(j["view_ids"], serde_json::json!([2, 35]), "{j}");
    assert_eq!(j["terms"], serde_json::json!([8, 4, 4]), "{j}");
    let path = PathBuf::from(j["model"].as_str().unwrap());
    let bytes = std::fs::metadata(&path).unwrap().len() as f64;
    let raw = (396 * 16 * 16 * 3 * 2) as f64;
    assert!((j["compression_ratio"].as_f64().unwrap() - raw / bytes).abs() < 1e-9, "{j}");
    let model = file::read(&path).unwrap();
    assert!(model.channels.iter().zip([8, 4, 4]).all(|(c, k)| c.parts.iter().all(|p| p.k == k)));
    // The error it reports is the error of the file against the textures, recomputed here.
    let rel = error_against_textures(&model, &ds);
    let reported = j["rel_rmse_vs_dataset"].as_f64().unwrap();
    assert!((rel - reported).abs() < 1e-6 * rel.max(1e-3), "recomputed {rel}, reported {reported}");

    // In RGB and f32 an FMF of 8 terms is within a bound of the best rank-8 fit (row mean +
    // rank 8 per channel, dense SVD here): the randomized SVD's 4 passes lose little.
    let out = dir.join("dome-rgb8.btfm");
    let j8 =
        compress_json(&ds, &["--color", "rgb", "--precision", "f32", "--terms", "8", "--out", out.to_str().unwrap()]);
    let rel8 = error_against_textures(&file::read(&out).unwrap(), &ds);
    let best = optimal_rel_error(&ds, 8);
    eprintln!("dome: FMF 8 rgb f32 relative RMSE {rel8}, best rank-8 {best}, yuv 8,4,4 f16 {rel}; {j8}");
    // Measured: 1.0066 x the optimum (0.3607 against 0.3584: the demo's textures are noisy);
    // bound 3 % above it.
    assert!(rel8 >= best * (1.0 - 1e-6) && rel8 <= 1.03 * best, "FMF 8 {rel8} vs best rank 8 {best}");

    // Each capture's directions in the sample frame, from the rig config's geometry here.
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ds.join("manifest.json")).unwrap()).unwrap();
    let rig = RigConfig::from_toml(manifest["rig"]["config_toml"].as_str().unwrap(), "manifest").unwrap();
    let dome = rig.dome.as_ref().unwrap();
    let leds = dome.led_directions();
    let caps = model.layout.captures.as_ref().expect("a dome layout has per-capture directions");
    assert_eq!(caps.view_ids, vec![2, 35]);
    for (light, view) in [(0usize, 0usize), (17, 1), (101, 0), (197, 1), (150, 1)] {
        let turntable_deg = if view == 0 { 0.0 } else { 360.0 * 3.0 / f64::from(dome.rotations) };
        let (want_l, want_v) =
            (in_sample_frame(leds[light], turntable_deg), in_sample_frame(dome.camera_direction(2), turntable_deg));
        let (got_l, got_v) = model.layout.directions(model.layout.index(light, view));
        assert!(
            got_l.angle_to(want_l).to_degrees() < 1e-6 && got_v.angle_to(want_v).to_degrees() < 1e-6,
            "light {light} view {view}: got {:?} {:?}, want {:?} {:?}",
            got_l.to_degrees(),
            got_v.to_degrees(),
            want_l.to_degrees(),
            want_v.to_degrees()
        );
    }

    // The streaming sink fed the dataset's step ids (as the pipeline commits them) builds
    // the same model as `btfrig compress` from the same passes.
    let mut params = ModelParams::new(Method::Fmf);
    params.terms = [8, 4, 4];
    let sink = btfrig_compress::sink::StreamingCompressor::new(&ds, params, 4).unwrap();
    let src = DatasetSource::open(&ds).unwrap();
    for &s in src.steps() {
        sink.accept(s.light, s.view, &src.read(s).unwrap());
    }
    let (streamed, report) = sink.finish().unwrap();
    assert_eq!((report.streamed, report.from_disk), (396, 0), "{report:?}");
    let rel_streamed = error_against_textures(&streamed, &ds);
    assert!((rel_streamed - rel).abs() < 0.02 * rel, "streamed {rel_streamed}, compress {rel}");

    // The Bonn readers take the first view's light list for every view: refused, no file.
    let btf = dir.join("dome.btf");
    for format in ["ubo-dfmf", "ubo-fmf"] {
        let o = btfrig()
            .args(["dataset", "export"])
            .arg(&ds)
            .args(["--format", format, "--model"])
            .arg(&path)
            .arg("--out")
            .arg(&btf)
            .output()
            .unwrap();
        let t = text(&o);
        assert!(!o.status.success(), "{t}");
        assert!(t.contains("first view's list for every view") && t.contains("the turntable turns"), "{t}");
        assert!(!btf.exists(), "a refused export left {}", btf.display());
    }
}

#[test]
fn a_camera_array_dataset_exports_when_every_camera_is_measured_and_is_refused_otherwise() {
    let dir = scratch("compress-camera-array");
    // Every camera of the 7-camera array: 7 flashes x 7 cameras, as many lights as views.
    let ds = dir.join("all");
    run(&camera_array_plan(&dir, "all", "[0, 1, 2, 3, 4, 5, 6]"), &ds);
    let j = compress_json(&ds, &["--color", "rgb", "--terms", "6", "--precision", "f32"]);
    assert_eq!((j["captures"].as_u64(), j["lights"].as_u64(), j["views"].as_u64()), (Some(49), Some(7), Some(7)));
    let path = PathBuf::from(j["model"].as_str().unwrap());
    let model = file::read(&path).unwrap();
    let rel = error_against_textures(&model, &ds);
    let best = optimal_rel_error(&ds, 6);
    eprintln!("camera array: FMF 6 rgb f32 relative RMSE {rel}, best rank-6 {best}; {j}");
    // Measured: 1.0107 x the optimum (0.4246 against 0.4201); bound 3 % above it.
    assert!(rel >= best * (1.0 - 1e-6) && rel <= 1.03 * best, "FMF 6 {rel} vs best rank 6 {best}");
    let btf = dir.join("all.btf");
    ok(btfrig().args(["dataset", "export"]).arg(&ds).args(["--format", "ubo-dfmf", "--f32", "--out"]).arg(&btf));
    // Read back: the container's directions are the captures' sample-frame directions (no
    // turntable: one light list), and its texels are the model's.
    let u = ubo::Ubo::read(&btf).unwrap();
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ds.join("manifest.json")).unwrap()).unwrap();
    let rig = RigConfig::from_toml(manifest["rig"]["config_toml"].as_str().unwrap(), "manifest").unwrap();
    let dome = rig.dome.as_ref().unwrap();
    for (i, &(t, p)) in u.light.iter().enumerate() {
        let want = Direction::from_vector(&dome.led_position(i).coords);
        let got = Direction::new(f64::from(t), f64::from(p));
        assert!(got.angle_to(want).to_degrees() < 1e-3, "flash {i}: {got:?} vs {want:?}");
    }
    for (c, &(t, p)) in u.view.iter().enumerate() {
        let got = Direction::new(f64::from(t), f64::from(p));
        assert!(got.angle_to(dome.camera_direction(c)).to_degrees() < 1e-3, "camera {c}");
    }
    let (mut e, mut tot) = (0.0f64, 0.0f64);
    for a in 0..model.layout.n_angular() {
        let (l, v) = model.layout.pair(a);
        let tex = model.texture(a);
        for row in 0..16 {
            for col in 0..16 {
                let (p, q) = (tex[row * 16 + col], u.texel(l, v, col, row));
                for c in 0..3 {
                    e += f64::from(p[c] - q[c]).powi(2);
                    tot += f64::from(p[c]).powi(2);
                }
            }
        }
    }
    assert!((e / tot).sqrt() < 1e-5, "the file differs from the model: {}", (e / tot).sqrt());

    // Two of the 7 cameras: 7 lights, 2 views; btf.hh needs as many of each. Refused, no file.
    let ds2 = dir.join("two");
    run(&camera_array_plan(&dir, "two", "[0, 3]"), &ds2);
    let btf2 = dir.join("two.btf");
    let o = btfrig()
        .args(["dataset", "export"])
        .arg(&ds2)
        .args(["--format", "ubo-dfmf", "--out"])
        .arg(&btf2)
        .output()
        .unwrap();
    let t = text(&o);
    assert!(!o.status.success() && t.contains("as many lights as views") && t.contains("7 lights, 2 views"), "{t}");
    assert!(!btf2.exists() && !t.contains("building"), "{t}");
}
