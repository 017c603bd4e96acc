//! `btfrig compress`, `dataset info|export`, `sparse select|reconstruct` and the plan's
//! `[sparse]` table with the real binary: synthetic datasets, and a sparse acquisition end
//! to end on the small-camera simulated rig (a basis from a full 7 x 7 run, a subset chosen
//! on it, `btfrig run` of the plan with `[sparse]`, the reconstruction against the full run).

mod support;

use btfrig_compress::dataset::write_dataset;
use btfrig_compress::Layout;
use btfrig_core::sampling::Sampling;
use support::{btfrig, ok, repo, scratch, text};

fn layout(w: usize) -> Layout {
    let s =
        |n: &str| Sampling::from_list(n, Sampling::bonn81().directions().iter().take(19).copied().collect()).unwrap();
    let mut l = Layout::full(s("light"), s("view"), w, w);
    for i in 0..19 {
        let a = l.index(i, i);
        l.measured[a] = false; // as on the rig: the camera blocks the lamp
    }
    l
}

/// A smooth synthetic BTF: albedo pattern times a cosine lobe and a view term.
fn texture(l: &Layout, a: usize) -> Vec<[f32; 3]> {
    let (li, vi) = l.pair(a);
    let (ld, vd) = (l.light.get(li).to_vector(), l.view.get(vi).to_vector());
    let h = (ld + vd).normalize();
    (0..l.texels())
        .map(|x| {
            let (c, r) = ((x % l.width) as f64, (x / l.width) as f64);
            let alb = 0.3 + 0.2 * (0.7 * c).sin() * (0.4 * r).cos();
            let spec = 0.5 * h.z.powf(20.0 + 10.0 * (c / 4.0).floor());
            let v = (alb * ld.z + spec) as f32;
            [v, 0.8 * v, 0.6 * v + 0.01 * (x % 3) as f32]
        })
        .collect()
}

#[test]
fn compress_info_export_and_refusals() {
    let dir = scratch("compress-cli");
    let ds = dir.join("synth");
    let l = layout(12);
    write_dataset(&ds, &l, &mut |a| texture(&l, a), "synthetic", "tests/compress.rs", true).unwrap();
    let out = ok(btfrig().arg("compress").arg(&ds).args(["--method", "pcmf", "--clusters", "4", "--terms", "4"]));
    assert!(out.contains("342 captures") && out.contains("8 passes") && out.contains("relative RMSE"), "{out}");
    let model = dir.join("synth.pcmf.btfm");
    assert!(model.exists(), "{out}");
    // No silent overwrite.
    let o = btfrig().arg("compress").arg(&ds).args(["--method", "pcmf", "--clusters", "4"]).output().unwrap();
    assert!(!o.status.success() && text(&o).contains("already exists: refusing to overwrite"), "{}", text(&o));
    // info lists the model next to the dataset, and reads a model file directly.
    let info = ok(btfrig().args(["dataset", "info"]).arg(&ds));
    assert!(info.contains("model") && info.contains("pcmf 4 clusters") && info.contains("ratio"), "{info}");
    let minfo = ok(btfrig().args(["dataset", "info"]).arg(&model));
    assert!(minfo.contains("19 light x 19 view, 12x12 texels"), "{minfo}");
    // The dataset is untouched.
    ok(btfrig().args(["dataset", "verify"]).arg(&ds));
    // Two models next to it: export asks which.
    let fmf = dir.join("synth.fmf.btfm");
    ok(btfrig().arg("compress").arg(&ds).args([
        "--method",
        "fmf",
        "--color",
        "rgb",
        "--terms",
        "8",
        "--precision",
        "f32",
    ]));
    let btf = dir.join("synth.btf");
    let o = btfrig()
        .args(["dataset", "export"])
        .arg(&ds)
        .args(["--format", "ubo-dfmf", "--out"])
        .arg(&btf)
        .output()
        .unwrap();
    assert!(!o.status.success() && text(&o).contains("several models"), "{}", text(&o));
    let e = ok(btfrig()
        .args(["dataset", "export"])
        .arg(&ds)
        .args(["--format", "ubo-dfmf", "--model"])
        .arg(&fmf)
        .arg("--out")
        .arg(&btf));
    assert!(e.contains("factors converted") && e.contains("9 terms"), "{e}");
    let bytes = std::fs::read(&btf).unwrap();
    assert_eq!(&bytes[..10], b"!DFMF08FCR");
    let e = ok(btfrig()
        .args(["dataset", "export"])
        .arg(&ds)
        .args(["--format", "ubo-fmf", "--rank", "12", "--model"])
        .arg(&model)
        .arg("--out")
        .arg(dir.join("synth-fmf1.btf")));
    assert!(e.contains("re-encoded") && e.contains("12 terms"), "{e}");
    let o = btfrig()
        .args(["dataset", "export"])
        .arg(&ds)
        .args(["--format", "ubo-xyz", "--out"])
        .arg(dir.join("x.btf"))
        .output()
        .unwrap();
    assert!(!o.status.success() && text(&o).contains("allowed ubo-dfmf, ubo-fmf"));
    let o = btfrig().arg("compress").arg(&ds).args(["--method", "svd"]).output().unwrap();
    assert!(!o.status.success() && text(&o).contains("--method \"svd\": allowed fmf, pvmf, pcmf"), "{}", text(&o));
}

#[test]
fn shared_basis_pcmf_is_built_described_exported_and_bad_k_refused() {
    let dir = scratch("compress-shared");
    let ds = dir.join("synth");
    let l = layout(12);
    write_dataset(&ds, &l, &mut |a| texture(&l, a), "synthetic", "tests/compress.rs", true).unwrap();
    let args = ["--method", "pcmf", "--clusters", "4", "--terms", "4", "--shared-basis", "12"];
    let out = ok(btfrig().arg("compress").arg(&ds).args(args));
    // The FMF's passes only (2 + 2 x 1 power iteration), then clustering in memory.
    assert!(out.contains("342 captures") && out.contains("4 passes") && out.contains("pcmf-4/w12"), "{out}");
    let model = dir.join("synth.pcmf-w12.btfm");
    assert!(model.exists(), "{out}");
    let minfo = ok(btfrig().args(["dataset", "info"]).arg(&model));
    assert!(minfo.contains("pcmf 4 clusters, shared basis 12 terms (format version 2)"), "{minfo}");
    for (format, what) in [("ubo-dfmf", "re-encoded"), ("ubo-fmf", "re-encoded")] {
        let e = ok(btfrig()
            .args(["dataset", "export"])
            .arg(&ds)
            .args(["--format", format, "--model"])
            .arg(&model)
            .arg("--out")
            .arg(dir.join(format!("synth-{format}.btf"))));
        assert!(e.contains(what) && e.contains("relative RMS"), "{format}: {e}");
    }
    for (k, want) in [("3", "4..=1024"), ("400", "at most 144")] {
        let o = btfrig()
            .arg("compress")
            .arg(&ds)
            .args(["--method", "pcmf", "--clusters", "4", "--terms", "4", "--shared-basis", k, "--out"])
            .arg(dir.join("bad.btfm"))
            .output()
            .unwrap();
        assert!(
            !o.status.success() && text(&o).contains("shared_basis") && text(&o).contains(want),
            "K {k}: {}",
            text(&o)
        );
    }
    let o = btfrig().arg("compress").arg(&ds).args(["--method", "fmf", "--shared-basis", "16"]).output().unwrap();
    assert!(!o.status.success() && text(&o).contains("only for --method pcmf"), "{}", text(&o));
}

#[test]
fn a_nan_texel_is_refused_naming_the_capture() {
    let dir = scratch("compress-nan");
    let ds = dir.join("bad");
    let l = layout(6);
    let bad = l.index(4, 2);
    write_dataset(
        &ds,
        &l,
        &mut |a| {
            let mut t = texture(&l, a);
            if a == bad {
                t[7][2] = f32::NAN;
            }
            t
        },
        "synthetic",
        "NaN test",
        false,
    )
    .unwrap();
    let o = btfrig().arg("compress").arg(&ds).output().unwrap();
    let t = text(&o);
    assert!(!o.status.success(), "{t}");
    assert!(t.contains("capture (light 4, view 2): texel 7 (column 1, row 1) channel 2 is NaN"), "{t}");
    assert!(!dir.join("bad.fmf.btfm").exists());
}

#[test]
fn sparse_acquisition_end_to_end_on_the_small_rig() {
    let dir = scratch("compress-sparse");
    let full = dir.join("full");
    ok(btfrig().args(["run", "--plan"]).arg(repo("tests/data/sparse-small.toml")).arg("--out").arg(&full));
    let basis = dir.join("basis.btfm");
    ok(btfrig()
        .arg("compress")
        .arg(&full)
        .args(["--method", "fmf", "--color", "rgb", "--terms", "6", "--out"])
        .arg(&basis));
    // The copied plan's relative paths resolve against the new file: name the rig absolutely.
    let base_text = std::fs::read_to_string(repo("tests/data/sparse-small.toml")).unwrap();
    let rig = repo("rig-configs/bonn-gonio-sim-small.toml").canonicalize().unwrap();
    let base = dir.join("base.toml");
    std::fs::write(&base, base_text.replace("../../rig-configs/bonn-gonio-sim-small.toml", &rig.display().to_string()))
        .unwrap();
    let plan = dir.join("subset.toml");
    let sel = ok(btfrig()
        .args(["sparse", "select", "--basis"])
        .arg(&basis)
        .args(["--captures", "14", "--plan"])
        .arg(&base)
        .arg("--out")
        .arg(&plan)
        .arg("--overwrite"));
    assert!(sel.contains("selected  14 of 42 captures") && sel.contains("kappa(M U)"), "{sel}");
    let text_plan = std::fs::read_to_string(&plan).unwrap();
    assert!(text_plan.contains("[sparse]\npairs = ["), "{text_plan}");
    let show = ok(btfrig().args(["plan", "show"]).arg(&plan));
    assert!(show.contains("14") && show.contains("sparse"), "{show}");
    let sparse = dir.join("sparse");
    ok(btfrig().args(["run", "--plan"]).arg(&plan).arg("--out").arg(&sparse));
    let info = ok(btfrig().args(["dataset", "info"]).arg(&sparse));
    assert!(info.contains("14/14 done"), "{info}");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(sparse.join("manifest.json")).unwrap()).unwrap();
    let skipped = manifest["samplings"]["skipped"].as_array().unwrap();
    assert_eq!(skipped.iter().filter(|s| s["reason"] == "sparse").count(), 49 - 7 - 14, "{skipped:?}");
    let rec = dir.join("rec.btfm");
    let r = ok(btfrig().args(["sparse", "reconstruct"]).arg(&sparse).arg("--basis").arg(&basis).arg("--out").arg(&rec));
    assert!(r.contains("from 14 captures"), "{r}");
    // The reconstruction against the full measurement (every captured pair of the full run).
    let model = btfrig_compress::file::read(&rec).unwrap();
    let mut src = btfrig_compress::dataset::DatasetSource::open(&full).unwrap();
    let e = btfrig_compress::eval::error_against(&model, &mut src).unwrap().rel_rmse();
    let basis_model = btfrig_compress::file::read(&basis).unwrap();
    let e_full = btfrig_compress::eval::error_against(&basis_model, &mut src).unwrap().rel_rmse();
    eprintln!("sparse reconstruction from 14 of 42 captures: rel RMSE {e:.4} vs the full run (the full run's own 6-term model: {e_full:.4})");
    assert!(e < 0.1, "sparse reconstruction error {e} (full-data model {e_full})");
}

/// Issue 8: a plan's `outputs.compressed_model` builds the model during `btfrig run` (the
/// same file `btfrig compress` writes, read by `btfrig dataset info`), and a bad value is
/// refused naming the allowed ones.
#[test]
fn r8_plan_compressed_model_is_written_by_the_run() {
    let dir = scratch("compress-plan-model");
    let base_text = std::fs::read_to_string(repo("tests/data/sparse-small.toml")).unwrap();
    let rig = repo("rig-configs/bonn-gonio-sim-small.toml").canonicalize().unwrap();
    let base = base_text.replace("../../rig-configs/bonn-gonio-sim-small.toml", &rig.display().to_string());
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, format!("{base}\n[outputs]\ncompressed_model = \"zip\"\n")).unwrap();
    let out = btfrig().args(["run", "--plan"]).arg(&bad).arg("--out").arg(dir.join("bad")).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a bad compressed_model must be refused");
    assert!(
        err.contains("outputs.compressed_model")
            && err.contains("\"zip\"")
            && err.contains("\"fmf\", \"pvmf\", \"pcmf\""),
        "{err}"
    );
    let plan = dir.join("model.toml");
    std::fs::write(&plan, format!("{base}\n[outputs]\ncompressed_model = \"pcmf\"\n")).unwrap();
    let data = dir.join("data");
    let run = ok(btfrig().args(["run", "--plan"]).arg(&plan).arg("--out").arg(&data));
    let model = dir.join("data.pcmf.btfm");
    assert!(run.contains("compression       pcmf ->") && run.contains("process peak RSS"), "{run}");
    assert!(model.exists(), "{run}");
    let info = ok(btfrig().args(["dataset", "info"]).arg(&model));
    assert!(info.contains("pcmf"), "{info}");
    // The model of the run is as close to its textures as `btfrig compress` says.
    let m = btfrig_compress::file::read(&model).unwrap();
    let mut src = btfrig_compress::dataset::DatasetSource::open(&data).unwrap();
    let e = btfrig_compress::eval::error_against(&m, &mut src).unwrap().rel_rmse();
    assert!(e < 0.2, "model of the run: rel RMSE {e} against its textures");
    // The same plan again: the dataset is complete, nothing is captured or built.
    let again = ok(btfrig().args(["run", "--plan"]).arg(&plan).arg("--out").arg(&data));
    assert!(again.contains("nothing to do"), "{again}");
    // PCMF 32 x 8 in a shared basis of 32 terms, asked for by the flag (42 captures >= 32).
    let shared = dir.join("shared");
    let plain = dir.join("plain.toml");
    std::fs::write(&plain, &base).unwrap();
    let run =
        ok(btfrig().args(["run", "--plan"]).arg(&plain).arg("--out").arg(&shared).args(["--compress", "pcmf-shared"]));
    assert!(run.contains("compression       pcmf-w32 ->"), "{run}");
    let m = btfrig_compress::file::read(&dir.join("shared.pcmf-w32.btfm")).unwrap();
    assert_eq!(m.method, btfrig_compress::Method::pcmf_shared(32, 32));
    let mut src = btfrig_compress::dataset::DatasetSource::open(&shared).unwrap();
    let e = btfrig_compress::eval::error_against(&m, &mut src).unwrap().rel_rmse();
    assert!(e < 0.2, "shared-basis model of the run: rel RMSE {e} against its textures");
    // Too few captures for a basis of 32 terms: refused before anything is captured, by the
    // plan key and by the flag alike.
    let small = dir.join("small.toml");
    std::fs::write(
        &small,
        format!(
            "{base}
[skip]
max_captures = 12
[outputs]
compressed_model = \"pcmf-shared\"
"
        ),
    )
    .unwrap();
    for extra in [&[][..], &["--compress", "pcmf-shared"][..]] {
        let out_dir = dir.join(format!("small-{}", extra.len()));
        let out = btfrig().args(["run", "--plan"]).arg(&small).arg("--out").arg(&out_dir).args(extra).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "pcmf-shared on 12 captures must be refused");
        assert!(err.contains("pcmf-shared") && err.contains("32 terms") && err.contains("captures 12 pairs"), "{err}");
        assert!(
            !out_dir.join("journal.btfj").exists() && !out_dir.join("textures").exists(),
            "nothing may be captured: {err}"
        );
    }
}
