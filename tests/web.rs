//! Browser tests of the operator page and the BTF viewer (crates/daemon/ui): `tests/web/run.sh`
//! starts the real `btfrig serve` on a loopback port with a temporary data directory and the
//! tokens of `tests/api/auth.toml`, and drives the pages in Debian's headless Chromium with
//! playwright-core.
//!
//! The operator page (`tests/web/ui.test.mjs`): a viewer is refused Start with the daemon's
//! message, an operator starts plan "demo", sees the progress bar advance and the preview image
//! change, the viewer's plots of the running dataset fill in as captures are committed, pauses
//! (the page shows "paused"), saves `target/web/screenshot.png`, aborts.
//!
//! The viewer (`tests/web/viewer.test.mjs`), on the dataset `btfrig demo` makes meanwhile: the
//! canvas equals btfrig's own render of the FMF model at three (light, view) pairs, moving the
//! light changes it, the coverage plot's counts equal report.json's, `btfrig dataset render`
//! gives the API's pixels, the frame rate with a synthetic 256 x 256, 81 x 81 FMF model is
//! printed, and `btfrig dataset report`'s file opens with no network and shows its plots.
//!
//! Chromium (Debian) and playwright-core (npm, into target/webdeps) come from
//! `tests/install-deps.sh`; without them the test FAILS naming that script.

mod support;

use std::path::Path;
use std::process::Command;

use btfrig_compress::{Channel, ColorModel, Layout, Method, Model, Part, PartRows, Precision};
use btfrig_core::sampling::Sampling;
use rand::{Rng, SeedableRng};
use support::repo;

/// A 256 x 256 texel FMF model over the Bonn 81 x 81 sampling with the default FMF terms
/// (32, 16, 16) and seeded random factors: the size the frame rate is quoted for, without
/// measuring 6561 captures. Written as dataset `fps-synthetic-256` (a manifest naming it so)
/// and its model `fps-synthetic-256.fmf.btfm`.
fn synthetic_model(dir: &Path) {
    let name = "fps-synthetic-256";
    std::fs::create_dir_all(dir.join(name)).expect("extra data dir");
    std::fs::write(
        dir.join(name).join("manifest.json"),
        r#"{"note": "a synthetic 256 x 256, 81 x 81 FMF model for the viewer's frame rate (tests/web.rs); no captures"}"#,
    )
    .expect("manifest");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(28);
    let layout = Layout::full(Sampling::bonn81(), Sampling::bonn81(), 256, 256);
    let (rows, texels) = (layout.n_angular(), layout.texels());
    let channels = [32usize, 16, 16]
        .iter()
        .enumerate()
        .map(|(c, &k)| {
            let mean =
                (0..rows).map(|_| if c == 0 { rng.gen_range(0.1..0.5) } else { rng.gen_range(-0.02..0.02) }).collect();
            let u = (0..rows * k).map(|_| rng.gen_range(-0.05..0.05)).collect();
            let sv = (0..texels * k).map(|_| rng.gen_range(-0.5..0.5)).collect();
            Channel::new(vec![Part { rows: PartRows::All, k, mean, u, s: vec![1.0; k], sv }])
        })
        .collect();
    let model = Model {
        method: Method::Fmf,
        color: ColorModel::Yuv,
        log_eps: 1e-3,
        precision: Precision::F32,
        layout,
        channels,
        clusters: None,
        cluster_col: Vec::new(),
    };
    let file = dir.join(format!("{name}.fmf.btfm"));
    btfrig_compress::file::write(&file, &model, serde_json::json!({"synthetic": "tests/web.rs"}), true)
        .expect("writes the synthetic model");
}

#[test]
fn operator_page_and_viewer_in_headless_chromium() {
    // The script's target folder: $CARGO_TARGET_DIR or the repository's target/.
    let target = std::env::var_os("CARGO_TARGET_DIR").map(std::path::PathBuf::from).unwrap_or_else(|| repo("target"));
    let extra = target.join("web/extra-data");
    let _ = std::fs::remove_dir_all(&extra);
    synthetic_model(&extra);
    let out = Command::new("bash")
        .arg(repo("tests/web/run.sh"))
        .arg(env!("CARGO_BIN_EXE_btfrig"))
        .env("BTFRIG_WEB_EXTRA", &extra)
        .output()
        .expect("bash runs");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "browser test failed ({:?}):\n{text}", out.status);
    eprintln!("{text}");
    // Both page tests ran and passed.
    assert_eq!(text.matches(" passed, 0 failed").count(), 2, "{text}");
    for shot in ["screenshot.png", "viewer-pair1.png", "viewer-pair3.png", "viewer-coverage.png", "report.png"] {
        let p = target.join("web").join(shot);
        assert!(p.exists(), "no screenshot at {}", p.display());
    }
}
