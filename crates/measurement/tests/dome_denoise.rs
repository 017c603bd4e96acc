//! Denoising a dome's demultiplexed textures by projection onto a linear basis (seed 001
//! §4.2), measured against the simulator's ground truth: the same view group with and
//! without `[dome] denoise_terms`.

use std::path::PathBuf;

use btfrig_measurement::dome::{run, DomeRunRequest, DomeRunSummary};

fn go(extra: &str, name: &str) -> DomeRunSummary {
    let plan = format!(
        "name = \"denoise\"\ntexture_size = 16\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\nmaterial = \"leather\"\n\
         [dome]\ncameras = [4]\nrotations = [1]\nreference_leds = 0\nsample_brightness = 0.1\n{extra}"
    );
    let out = std::env::temp_dir().join(format!("btfrig-dome-denoise-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let req = DomeRunRequest {
        plan_text: plan,
        plan_path: PathBuf::from("<test>"),
        out: out.clone(),
        faults: None,
        preview: false,
        compressed_model: None,
    };
    let s = run(&req, &mut |line| eprintln!("{line}")).unwrap_or_else(|e| panic!("{e}"));
    let report = btfrig_store::verify(&out);
    assert!(report.is_ok(), "{report:?}");
    let _ = std::fs::remove_dir_all(&out);
    s
}

/// The pipeline's own error against the truth (resampling at 16 texels, about 0.54 here) is
/// not noise and no projection removes it, so the noise part of an error `e` is taken as
/// `sqrt(e² − floor²)` with the floor measured on nearly noise-free captures (single light,
/// 10 s exposures: 200 times the photons of the 0.05 s the others use).
#[test]
fn projection_onto_the_groups_own_basis_removes_most_of_the_demultiplexing_noise() {
    btfrig_sim_backend::install();
    let floor = go("exposure_s = 10.0\nmultiplex = \"off\"\n", "floor").texture_rel_rmse.unwrap();
    let noise = |e: f64| (e * e - floor * floor).max(0.0).sqrt();
    let plain = go("", "plain");
    let (e0, mode) = (plain.texture_rel_rmse.unwrap(), plain.mode.clone());
    assert_eq!((mode.as_str(), plain.denoise_terms), ("s-matrix 199", None));
    assert!(noise(e0) > 0.5 * floor, "the test needs noise that matters: {e0} against the floor {floor}");
    for terms in [32usize, 16, 4] {
        let s = go(&format!("denoise_terms = {terms}\n"), &format!("k{terms}"));
        let e = s.texture_rel_rmse.unwrap();
        let kept = s.denoise_energy_kept[0];
        eprintln!(
            "{mode}, {terms} terms: texture rel RMSE {e:.4} (noise part {:.4}) against {e0:.4} ({:.4}) without; \
             floor {floor:.4}; energy kept {kept:.4}; {:.2} s",
            noise(e),
            noise(e0),
            s.denoise_s
        );
        assert_eq!((s.denoise_terms, s.denoise_energy_kept.len(), s.textures), (Some(terms), 1, 198));
        assert!(e < e0, "{terms} terms: {e} against {e0} without denoising");
        assert!(kept > 0.5 && kept < 1.0, "{kept}");
        if terms <= 16 {
            assert!(noise(e) < 0.5 * noise(e0), "{terms} terms: noise part {} against {}", noise(e), noise(e0));
        }
    }
}
