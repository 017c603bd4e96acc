//! `btfrig model ps` on synthetic datasets (docs/material-models.md): a Lambertian tilted plane
//! seen from two views under four lights gives its normal back through the whole path
//! (manifest directions, EXR textures, maps and descriptor written); too few lights, a view
//! without captures and a bad method are refused with what is missing. The demo dataset's
//! figures against the simulator's truth are checked in tests/cli.rs, on the demo run that
//! test makes anyway.

mod support;

use btfrig_compress::dataset::write_dataset;
use btfrig_compress::Layout;
use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;
use support::{btfrig, ok, scratch, text};

fn fails(cmd: &mut std::process::Command) -> String {
    let o = cmd.output().expect("btfrig runs");
    assert!(!o.status.success(), "{}", text(&o));
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A `w x w` dataset under `lights` seen from two views (the zenith and 30°, 45°), the
/// texture of each capture `texture(l, v)` (unit vectors, sample frame).
fn dataset(
    dir: &std::path::Path,
    lights: &[(f64, f64)],
    w: usize,
    texture: impl Fn([f64; 3], [f64; 3]) -> Vec<[f32; 3]>,
) {
    let ld: Vec<Direction> = lights.iter().map(|&(t, p)| Direction::from_degrees(t, p)).collect();
    let vd = vec![Direction::from_degrees(0.0, 0.0), Direction::from_degrees(30.0, 45.0)];
    let layout =
        Layout::full(Sampling::from_list("light", ld).unwrap(), Sampling::from_list("view", vd).unwrap(), w, w);
    let l2 = layout.clone();
    write_dataset(
        dir,
        &layout,
        &mut |a| {
            let (l, v) = l2.directions(a);
            let (l, v) = (l.to_vector(), v.to_vector());
            texture([l.x, l.y, l.z], [v.x, v.y, v.z])
        },
        "synthetic",
        "tests/model.rs",
        false,
    )
    .unwrap();
}

/// A `w x w` dataset of a Lambertian plane with normal `n` and albedo (0.6, 0.4, 0.2).
fn plane_dataset(dir: &std::path::Path, lights: &[(f64, f64)], n: [f64; 3], w: usize) {
    dataset(dir, lights, w, |l, _| {
        let s = (l[0] * n[0] + l[1] * n[1] + l[2] * n[2]).max(0.0) as f32;
        vec![[0.6 * s, 0.4 * s, 0.2 * s]; w * w]
    });
}

#[test]
fn model_ps_recovers_a_plane_and_names_what_is_missing() {
    let dir = scratch("model-ps");
    let t = 20f64.to_radians();
    let n = [t.sin() * 0.3f64.cos(), t.sin() * 0.3f64.sin(), t.cos()];
    let data = dir.join("plane");
    plane_dataset(&data, &[(0.0, 0.0), (30.0, 0.0), (30.0, 120.0), (30.0, 240.0)], n, 8);
    let out = dir.join("maps");
    let stdout = ok(btfrig().args(["model", "ps"]).arg(&data).arg("--out").arg(&out).arg("--json"));
    let d: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(d["method"], "robust", "{d}");
    assert_eq!(d["source"]["captures"], 8, "{d}");
    for f in ["normal.exr", "albedo.exr", "height.exr", "normal_sigma.exr", "height_sigma.exr", "model.json"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let (w, h, normal) = btfrig_imageio::read_rgb_exr(&out.join("normal.exr")).unwrap();
    assert_eq!((w, h), (8, 8));
    for p in &normal {
        let c = f64::from(p[0]) * n[0] + f64::from(p[1]) * n[1] + f64::from(p[2]) * n[2];
        assert!(c > (0.1f64).to_radians().cos(), "normal {p:?} against {n:?}");
    }
    let (_, _, albedo) = btfrig_imageio::read_rgb_exr(&out.join("albedo.exr")).unwrap();
    assert!(albedo.iter().all(|a| (a[0] - 0.6).abs() < 1e-3 && (a[2] - 0.2).abs() < 1e-3), "{:?}", albedo[0]);
    // A plane integrates to a plane: the height spans the tilt over the region.
    let hmax = d["maps"]["height"]["max"].as_f64().unwrap();
    assert!(hmax > 0.0, "{d}");
    // Lafortune lobes relative to those normals: a Lambertian plane needs no lobe.
    let lo = dir.join("lafortune");
    let stdout = ok(btfrig().args(["model", "lafortune"]).arg(&data).arg("--out").arg(&lo).arg("--json"));
    let d: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(d["rel_rmse_data"].as_f64().unwrap() < 1e-3, "{d}");
    for f in ["albedo.exr", "normal.exr", "lobe1.exr", "model.json"] {
        assert!(lo.join(f).is_file(), "{f} missing");
    }
    // Seed 003's maps on top: an unshadowed plane keeps factors and gain 1.
    let sm = dir.join("shadow-maps");
    let stdout = ok(btfrig().args(["model", "lafortune", "--shadow-maps", "--json"]).arg(&data).arg("--out").arg(&sm));
    let d: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(d["rel_rmse_data"].as_f64().unwrap() < 1e-3, "{d}");
    assert!(d["shadow_occlusion"]["light_dirs"].as_array().unwrap().len() >= 3, "{d}");
    for f in ["shadow.exr", "occlusion.exr", "gain.exr", "model.json"] {
        assert!(sm.join(f).is_file(), "{f} missing");
    }
    let e = fails(btfrig().args(["model", "lafortune"]).arg(&data).args(["--lobes", "4", "--out"]).arg(dir.join("l4")));
    assert!(e.contains("lobes = 4: 1, 2 or 3"), "{e}");
    // Nothing is overwritten.
    let e = fails(btfrig().args(["model", "ps"]).arg(&data).arg("--out").arg(&out));
    assert!(e.contains("not empty"), "{e}");

    // Two lights only: the message says how many there are and how many are needed.
    let two = dir.join("two");
    plane_dataset(&two, &[(0.0, 0.0), (30.0, 90.0)], n, 4);
    let e = fails(btfrig().args(["model", "ps"]).arg(&two).arg("--out").arg(dir.join("x")));
    assert!(e.contains("2 distinct light direction(s)") && e.contains("at least 3"), "{e}");
    assert!(!dir.join("x").exists(), "nothing written for a refused input");
    // Coplanar lights.
    let flat = dir.join("flat");
    plane_dataset(&flat, &[(30.0, 0.0), (0.0, 0.0), (30.0, 180.0)], n, 4);
    let e = fails(btfrig().args(["model", "ps"]).arg(&flat).arg("--out").arg(dir.join("y")));
    assert!(e.contains("coplanar"), "{e}");
    // A view without captures, a bad method.
    let e = fails(btfrig().args(["model", "ps"]).arg(&data).args(["--view", "7", "--out"]).arg(dir.join("z")));
    assert!(e.contains("no captures of view 7") && e.contains("[0, 1]"), "{e}");
    let e = fails(btfrig().args(["model", "ps"]).arg(&data).args(["--method", "magic", "--out"]).arg(dir.join("z")));
    assert!(e.contains("allowed: robust, least-squares"), "{e}");
    // Views up to an angle: the frontal view's 4 captures of the 8 (the other view is at 30 deg).
    let front = dir.join("front");
    let stdout =
        ok(btfrig().args(["model", "ps", "--json", "--max-view-theta", "15"]).arg(&data).arg("--out").arg(&front));
    let d: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(d["source"]["captures"], 4, "{d}");
    assert_eq!(d["source"]["max_view_theta_deg"], 15.0, "{d}");
    let e = fails(btfrig().args(["model", "ps", "--max-view-theta", "95"]).arg(&data).arg("--out").arg(dir.join("z")));
    assert!(e.contains("--max-view-theta 95: allowed 0 to 90"), "{e}");
}

#[test]
fn model_ptm_and_scaled_lafortune_write_their_maps_and_refuse_the_wrong_kind() {
    let dir = scratch("model-ptm");
    // Seven lights per view; per texel and view a biquadratic in (l_x, l_y) with a chroma.
    let lights = [(0.0, 0.0), (30.0, 0.0), (30.0, 72.0), (30.0, 144.0), (30.0, 216.0), (30.0, 288.0), (60.0, 45.0)];
    let w = 4;
    let data = dir.join("ptm-data");
    dataset(&data, &lights, w, |l, v| {
        (0..w * w)
            .map(|t| {
                let a5 = 0.5 + 0.02 * t as f64 + 0.2 * v[0];
                let lum = a5 + 0.1 * l[0] - 0.05 * l[1] - 0.2 * l[0] * l[0] + 0.1 * l[0] * l[1];
                [(1.2 * lum) as f32, lum as f32, (0.8 * lum) as f32]
            })
            .collect()
    });
    let out = dir.join("ptm");
    let d: serde_json::Value =
        serde_json::from_str(&ok(btfrig().args(["model", "ptm", "--json"]).arg(&data).arg("--out").arg(&out))).unwrap();
    assert!(d["rel_rmse_data"].as_f64().unwrap() < 1e-5, "{d}");
    assert_eq!(d["views"].as_array().unwrap().len(), 2, "{d}");
    assert!(d["worst_rcond"].as_f64().unwrap() > 0.0, "{d}");
    for f in ["ptm_quadratic.exr", "ptm_linear.exr", "ptm_chroma.exr"] {
        let (fw, fh, _) = btfrig_imageio::read_rgb_exr(&out.join(f)).unwrap();
        assert_eq!((fw, fh), (w, 2 * w), "{f}: one {w} x {w} map per view, stacked");
    }
    let (_, _, chroma) = btfrig_imageio::read_rgb_exr(&out.join("ptm_chroma.exr")).unwrap();
    assert!(chroma.iter().all(|c| (c[0] - 1.2).abs() < 1e-4 && (c[2] - 0.8).abs() < 1e-4), "{:?}", chroma[0]);

    // Scaled Lafortune lobes on a Lambertian plane: no lobe, every view scale 1.
    let n = [0.0, 0.0, 1.0];
    let plane = dir.join("plane");
    plane_dataset(&plane, &lights, n, w);
    let sl = dir.join("scaled");
    let d: serde_json::Value = serde_json::from_str(&ok(btfrig()
        .args(["model", "scaled-lafortune", "--json"])
        .arg(&plane)
        .arg("--out")
        .arg(&sl)))
    .unwrap();
    assert!(d["rel_rmse_data"].as_f64().unwrap() < 1e-3, "{d}");
    assert_eq!(d["view_dirs"].as_array().unwrap().len(), 2, "{d}");
    let (fw, fh, scale) = btfrig_imageio::read_rgb_exr(&sl.join("view_scale.exr")).unwrap();
    assert_eq!((fw, fh), (w, 2 * w));
    assert!(scale.iter().all(|s| (s[0] - 1.0).abs() < 1e-3), "{:?}", scale[0]);
    for f in ["albedo.exr", "normal.exr", "lobe1.exr", "model.json"] {
        assert!(sl.join(f).is_file(), "{f} missing");
    }

    // Too few lights per view for a PTM: the view and the counts are named.
    let four = dir.join("four");
    plane_dataset(&four, &lights[..4], n, w);
    let e = fails(btfrig().args(["model", "ptm"]).arg(&four).arg("--out").arg(dir.join("x")));
    assert!(e.contains("4 distinct light direction(s)") && e.contains("at least 6"), "{e}");
    assert!(!dir.join("x").exists(), "nothing written for a refused input");
    // The maps of another command, a model file, any file, a directory without a manifest.
    let e = fails(btfrig().args(["model", "ptm"]).arg(&out).arg("--out").arg(dir.join("x")));
    assert!(e.contains("the material maps of `btfrig model ptm`") && e.contains("not a dataset"), "{e}");
    let e = fails(btfrig().args(["model", "lafortune"]).arg(&sl).arg("--out").arg(dir.join("x")));
    assert!(e.contains("the material maps of `btfrig model scaled-lafortune`"), "{e}");
    ok(btfrig().arg("compress").arg(&plane).args(["--method", "fmf", "--terms", "2"]));
    let btfm = dir.join("plane.fmf.btfm");
    let e = fails(btfrig().args(["model", "scaled-lafortune"]).arg(&btfm).arg("--out").arg(dir.join("x")));
    assert!(e.contains("a compressed BTF model file (fmf") && e.contains("pass the dataset"), "{e}");
    let e = fails(btfrig().args(["model", "ps"]).arg(out.join("model.json")).arg("--out").arg(dir.join("x")));
    assert!(e.contains("a file, not a dataset"), "{e}");
    let e = fails(btfrig().args(["model", "ptm"]).arg(&dir).arg("--out").arg(dir.join("x")));
    assert!(e.contains("no manifest.json, so not a dataset"), "{e}");
    assert!(!dir.join("x").exists(), "nothing written for a refused input");
}

/// A `w x w` dataset of a textured Lambertian plane: a seeded random albedo pattern (smoothed
/// white noise, so it has an autocorrelation) under 4 lights, seen from 2 views.
fn textured_dataset(dir: &std::path::Path, w: usize) {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let noise: Vec<f32> = (0..w * w).map(|_| rng.gen_range(-1.0..1.0f32)).collect();
    let pattern: Vec<f32> = (0..w * w)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let at = |dx: usize, dy: usize| noise[((y + dy) % w) * w + (x + dx) % w];
            0.25 * (at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1))
        })
        .collect();
    let lights: Vec<Direction> = [(0.0, 0.0), (30.0, 0.0), (30.0, 120.0), (30.0, 240.0)]
        .iter()
        .map(|&(t, p)| Direction::from_degrees(t, p))
        .collect();
    let vd = vec![Direction::from_degrees(0.0, 0.0), Direction::from_degrees(30.0, 45.0)];
    let layout =
        Layout::full(Sampling::from_list("light", lights).unwrap(), Sampling::from_list("view", vd).unwrap(), w, w);
    let l2 = layout.clone();
    write_dataset(
        dir,
        &layout,
        &mut |a| {
            let s = l2.directions(a).0.to_vector().z as f32;
            pattern.iter().map(|p| [(0.5 + 0.2 * p) * s, (0.3 + 0.1 * p) * s, 0.2 * s]).collect()
        },
        "synthetic",
        "a textured Lambertian plane",
        false,
    )
    .unwrap();
}

#[test]
fn model_car_synthesises_any_size_and_names_bad_options() {
    let dir = scratch("model-car");
    let data = dir.join("textured");
    textured_dataset(&data, 16);
    let out = dir.join("car");
    let stdout = ok(btfrig()
        .args([
            "model",
            "car",
            "--size",
            "48x40",
            "--clusters",
            "2",
            "--radius",
            "1",
            "--light",
            "20,30",
            "--view",
            "10,-45",
        ])
        .arg(&data)
        .arg("--out")
        .arg(&out)
        .arg("--json"));
    let d: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(d["format"], "btfrig-car-model", "{d}");
    assert_eq!(d["source"]["captures"], 8, "{d}");
    assert!(d["model"]["subspaces"].as_array().unwrap().len() <= 2, "{d}");
    assert!(d["parameter_bytes"].as_u64().unwrap() > 0, "{d}");
    let (w, h, tex) = btfrig_imageio::read_rgb_exr(&out.join("texture.exr")).unwrap();
    assert_eq!((w, h), (48, 40));
    assert!(tex.iter().all(|p| p.iter().all(|v| v.is_finite())), "non-finite texel");
    // A texture, not a constant, around the measured mean colour (the light at 20°: ~0.47).
    let mean = tex.iter().map(|p| f64::from(p[0])).sum::<f64>() / tex.len() as f64;
    assert!((0.3..0.7).contains(&mean), "red mean {mean}");
    assert!(tex.iter().any(|p| (p[0] - tex[0][0]).abs() > 0.02), "no texture");
    for f in ["texture.png", "measured.png", "comparison.png", "height.exr", "model.json"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let (pw, ph, _) = btfrig_imageio::read_srgb8_png(&out.join("texture.png")).unwrap();
    assert_eq!((pw, ph), (48, 40));
    // Bad options name what is allowed.
    let e = fails(btfrig().args(["model", "car", "--size", "0x5"]).arg(&data).arg("--out").arg(dir.join("a")));
    assert!(e.contains("--size \"0x5\"") && e.contains("1 to 16384"), "{e}");
    let e = fails(btfrig().args(["model", "car", "--range", "tiles"]).arg(&data).arg("--out").arg(dir.join("b")));
    assert!(e.contains("allowed: car, mirror"), "{e}");
    let e = fails(
        btfrig().args(["model", "car", "--light", "95,0", "--view", "0,0"]).arg(&data).arg("--out").arg(dir.join("c")),
    );
    assert!(e.contains("--light \"95,0\"") && e.contains("0 <= THETA < 90"), "{e}");
    let e = fails(btfrig().args(["model", "car", "--radius", "9"]).arg(&data).arg("--out").arg(dir.join("d")));
    assert!(e.contains("radius-9 neighbourhood"), "{e}");
    assert!(!dir.join("d").exists(), "nothing written for a refused input");
}
