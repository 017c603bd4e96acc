//! Independent check of the Bonn export: both files written by `btfrig dataset export`
//! (`ubo-dfmf`, `!DFMF08FCR`, and `ubo-fmf`, `!FMF12FCER`) are loaded by the PyPI package
//! btf-extractor (its `Ubo2014` class, i.e. zeroeffects/btf's `btf.hh`): the light and view
//! directions it reports must lie within 0.1 deg of the dataset's (its keys are rounded to
//! 0.1 deg), one per dataset direction, and every texel it returns for a sample of (light,
//! view) pairs must match btfrig's own decoder of the file within 1e-5 relative (both decode
//! the same f16 factors in f32; only the summation order differs). btf-extractor comes from
//! the venv `target/pydeps/btf` that `tests/install-deps.sh` makes; the test FAILS without it.

mod support;

use btfrig_compress::dataset::write_dataset;
use btfrig_compress::ubo::Ubo;
use btfrig_compress::Layout;
use btfrig_core::sampling::Sampling;
use support::{btfrig, ok, repo, scratch};

#[test]
fn btf_extractor_reads_our_dfmf_and_fmf_exports_with_the_dataset_directions() {
    let dir = scratch("compress-extractor");
    let s =
        |n: &str| Sampling::from_list(n, Sampling::bonn81().directions().iter().take(19).copied().collect()).unwrap();
    let (w, h) = (10usize, 14usize);
    let mut l = Layout::full(s("light"), s("view"), w, h);
    for i in 0..19 {
        let a = l.index(i, i);
        l.measured[a] = false;
    }
    let tex = |a: usize| -> Vec<[f32; 3]> {
        let (li, vi) = l.pair(a);
        let (ld, vd) = (l.light.get(li).to_vector(), l.view.get(vi).to_vector());
        (0..w * h)
            .map(|x| {
                let (c, r) = ((x % w) as f64, (x / w) as f64);
                let v = (0.2 + 0.05 * c + 0.02 * r) * ld.z + 0.3 * (ld + vd).normalize().z.powi(30) * (1.0 + 0.1 * r);
                [v as f32, (0.7 * v) as f32, (0.4 * v + 0.01 * c) as f32]
            })
            .collect()
    };
    let ds = dir.join("ds");
    write_dataset(&ds, &l, &mut |a| tex(a), "synthetic", "btf-extractor check", true).unwrap();
    ok(btfrig().arg("compress").arg(&ds).args(["--method", "pcmf", "--clusters", "3", "--terms", "5"]));
    let deg = |s: &Sampling| -> Vec<[f64; 2]> {
        s.directions().iter().map(|d| [d.theta.to_degrees(), d.phi.to_degrees()]).collect()
    };
    let target = std::env::var_os("CARGO_TARGET_DIR").map(std::path::PathBuf::from).unwrap_or_else(|| repo("target"));
    let python = target.join("pydeps/btf/bin/python");
    assert!(python.exists(), "no btf-extractor venv at {}: run tests/install-deps.sh", python.display());
    for format in ["ubo-dfmf", "ubo-fmf"] {
        let btf = dir.join(format!("ds.{format}.btf"));
        ok(btfrig().args(["dataset", "export"]).arg(&ds).args(["--format", format, "--rank", "24", "--out"]).arg(&btf));
        // The reference: our decoder of the exported file at a sample of pairs.
        let u = Ubo::read(&btf).unwrap();
        let samples: Vec<(usize, usize)> = vec![(0, 3), (5, 0), (7, 12), (18, 17), (11, 4), (3, 9)];
        let mut data = Vec::new();
        for &(li, vi) in &samples {
            for row in 0..h {
                for col in 0..w {
                    for c in u.texel(li, vi, col, row) {
                        data.extend_from_slice(&c.to_le_bytes());
                    }
                }
            }
        }
        let data_name = format!("reference.{format}.f32");
        std::fs::write(dir.join(&data_name), &data).unwrap();
        let reference = serde_json::json!({
            "width": w, "height": h, "light": deg(&l.light), "view": deg(&l.view),
            "samples": samples.iter().map(|&(a, b)| serde_json::json!({"light": a, "view": b})).collect::<Vec<_>>(),
            "data": data_name, "rel_tol": 1e-5, "max_angle_deg": 0.1,
        });
        let ref_path = dir.join(format!("reference.{format}.json"));
        std::fs::write(&ref_path, reference.to_string()).unwrap();
        let out = std::process::Command::new(&python)
            .arg(repo("tests/compress/check_btf_extractor.py"))
            .arg(&btf)
            .arg(&ref_path)
            .output()
            .expect("the venv's python runs");
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "btf-extractor check of the {format} export failed:\n{text}");
        eprintln!("{text}");
        assert!(text.contains("within") && text.contains("match btfrig's decoder"), "{text}");
    }
}
