//! The streaming compression model of a dome or camera-array run (issue 25, item 5): a dome
//! plan's `outputs.compressed_model` builds the model while the run captures, with the
//! per-capture (light, view) layout `btfrig compress` gives the same dataset, and its figures
//! agree with that offline build; the model is journaled in the dataset; a session that did
//! not finish builds none, its resume builds it (the earlier session's textures read back
//! from the dataset), and a run after that finds it journaled.

use std::path::{Path, PathBuf};

use btfrig_compress::dataset::DatasetSource;
use btfrig_compress::{build, eval, file, Model};
use btfrig_core::plan::CompressedModel;
use btfrig_measurement::dome::{run, run_controlled, DomeRunRequest, DomeRunSummary};
use btfrig_measurement::sinks::{stream_params, CompressionOutcome};
use btfrig_measurement::{RunControl, RunEvent, RunOutcome};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("btfrig-dome-compress-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// One dome camera at two rotations, 8 x 8 textures: 2 view groups of 198 textures (view ids
/// 1 x 11 + 4 = 15 and 5 x 11 + 4 = 59); 402 steps.
const DOME_PLAN: &str = "name = \"dome-compress\"\ntexture_size = 8\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\n\
                         material = \"leather\"\n[dome]\ncameras = [4]\nrotations = [1, 5]\n\
                         [outputs]\ncompressed_model = \"fmf\"\n";

fn request(plan: &str, out: &Path) -> DomeRunRequest {
    DomeRunRequest {
        plan_text: plan.into(),
        plan_path: PathBuf::from("<test>"),
        out: out.into(),
        faults: None,
        preview: false,
        compressed_model: None,
    }
}

fn figures(s: &DomeRunSummary) -> &serde_json::Value {
    match &s.compression {
        Some(CompressionOutcome::Built { figures, replaced_damaged: None }) => figures,
        other => panic!("the model was not built: {other:?}"),
    }
}

/// The model `btfrig compress` builds of the dataset with the run's parameters, and its
/// relative RMSE against the dataset.
fn offline(dir: &Path, m: CompressedModel) -> (Model, f64) {
    let mut src = DatasetSource::open(dir).unwrap();
    let (model, _) = build::<f32>(src.layout().clone(), &stream_params(m), &mut src).unwrap();
    let rel = eval::error_against(&model, &mut src).unwrap().rel_rmse();
    (model, rel)
}

/// The streamed model against the offline one of the same dataset: the same layout (lights,
/// view ids, every capture's directions in the sample frame, measured captures) and, from
/// the same data, the same relative RMSE; the figures'
/// RMSE is the file's against the textures.
fn agrees_with_offline(figures: &serde_json::Value, dir: &Path, m: CompressedModel) -> (f64, f64) {
    let path = PathBuf::from(figures["compression_model"].as_str().unwrap());
    let streamed = file::read(&path).unwrap();
    let (model, rel_offline) = offline(dir, m);
    let (a, b) = (&streamed.layout, &model.layout);
    assert_eq!((a.n_light(), a.n_view(), a.width, a.height), (b.n_light(), b.n_view(), b.width, b.height));
    assert_eq!(a.measured, b.measured);
    let (ca, cb) = (a.captures.as_ref().expect("per-capture directions"), b.captures.as_ref().unwrap());
    assert_eq!(ca.view_ids, cb.view_ids);
    for i in 0..a.n_angular() {
        let ((la, va), (lb, vb)) = (a.directions(i), b.directions(i));
        assert!(la.angle_to(lb) < 1e-9 && va.angle_to(vb) < 1e-9, "capture {i}");
    }
    let rel = figures["compression_rel_rmse"].as_f64().unwrap();
    let mut src = DatasetSource::open(dir).unwrap();
    let rel_file = eval::error_against(&streamed, &mut src).unwrap().rel_rmse();
    assert!((rel - rel_file).abs() < 1e-9, "figures {rel}, the file {rel_file}");
    // Measured: identical (a capture's rows of the sketches do not depend on the order).
    assert!(
        rel.is_finite() && rel > 0.0 && (rel / rel_offline - 1.0).abs() < 1e-6,
        "streamed {rel}, offline {rel_offline}"
    );
    (rel, rel_offline)
}

/// The model file the dataset's journal names for `label`, checked against the file.
fn journaled(dir: &Path, label: &str) -> PathBuf {
    let models = btfrig_store::journaled_models(dir).unwrap();
    let rec = models.iter().find(|m| m.method == label).unwrap_or_else(|| panic!("{label} not journaled: {models:?}"));
    let path = dir.parent().unwrap().join(&rec.file);
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!((bytes.len() as u64, btfrig_store::content_hash(&bytes)), (rec.size, rec.hash.clone()));
    path
}

#[test]
fn a_dome_plans_model_streams_every_texture_agrees_with_btfrig_compress_and_is_journaled() {
    btfrig_sim_backend::install();
    let dir = tmp("dome");
    let out = dir.join("data");
    let s = run(&request(DOME_PLAN, &out), &mut |l| eprintln!("{l}")).unwrap_or_else(|e| panic!("{e}"));
    assert!(s.stopped.is_none() && s.textures == 396, "{:?} {}", s.stopped, s.textures);
    let f = figures(&s);
    // Every texture reached the model while the run captured; none was read back.
    assert_eq!((f["compression_streamed"].as_u64(), f["compression_from_disk"].as_u64()), (Some(396), Some(0)), "{f}");
    assert_eq!(f["compression_method"], "fmf");
    let (rel, rel_offline) = agrees_with_offline(f, &out, CompressedModel::Fmf);
    eprintln!("dome FMF 16/8/8: streamed rel RMSE {rel}, btfrig compress {rel_offline}; {f}");
    let model = journaled(&out, "fmf");
    assert_eq!(model, PathBuf::from(f["compression_model"].as_str().unwrap()));
    assert_eq!(file::read(&model).unwrap().layout.captures.as_ref().unwrap().view_ids, vec![15, 59]);
    // The summary JSON carries the figures as a gonio run's does.
    let j = s.to_json();
    assert_eq!(j["compression_status"], "built");
    assert!(j["run_peak_rss_mib"].is_number() || j["run_peak_rss_mib"].is_null());
    let report = btfrig_store::verify(&out);
    assert!(report.is_ok(), "{report:?}");
}

#[test]
fn a_killed_dome_run_builds_its_model_on_resume_and_a_run_after_that_finds_it_journaled() {
    btfrig_sim_backend::install();
    let dir = tmp("resume");
    let out = dir.join("data");
    let req = request(DOME_PLAN, &out);
    // Aborted in the second view group (the first is 203 steps): its textures stay.
    let control = RunControl::new();
    let handle = control.clone();
    let a = run_controlled(&req, &control, true, &mut |l| eprintln!("{l}"), &mut |e| {
        if let RunEvent::Progress { done: 300, .. } = e {
            handle.abort().unwrap();
        }
    })
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((a.stopped.as_ref(), a.textures), (Some(&RunOutcome::Aborted), 198));
    assert_eq!(a.compression, Some(CompressionOutcome::NotFinished));
    assert_eq!(btfrig_store::journaled_models(&out).unwrap(), vec![]);
    assert!(!dir.join("data.fmf.btfm").exists());
    assert_eq!(a.to_json()["compression_status"], "not_finished");

    // The resume streams the second view group and reads the first back from the dataset.
    let b = run(&req, &mut |l| eprintln!("{l}")).unwrap_or_else(|e| panic!("{e}"));
    assert!(b.stopped.is_none() && b.textures == 198, "{:?} {}", b.stopped, b.textures);
    let f = figures(&b);
    assert_eq!(
        (f["compression_streamed"].as_u64(), f["compression_from_disk"].as_u64()),
        (Some(198), Some(198)),
        "{f}"
    );
    agrees_with_offline(f, &out, CompressedModel::Fmf);
    let model = journaled(&out, "fmf");

    // Everything is done and the model journaled intact: nothing is built again.
    let c = run(&req, &mut |l| eprintln!("{l}")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(c.textures, 0);
    assert_eq!(c.compression, Some(CompressionOutcome::BuiltEarlier { model }));
}

#[test]
fn a_camera_array_plans_model_is_built_per_view_with_each_captures_directions() {
    btfrig_sim_backend::install();
    let dir = tmp("camera-array");
    let out = dir.join("data");
    // Two of the array's 151 cameras under all 151 flashes; the request asks for PVMF (a
    // model per view) over the plan's FMF, as `btfrig run --compress pvmf` does.
    let plan = "name = \"array-compress\"\ntexture_size = 8\nfault_scenario = \"none\"\n[rig]\n\
                config = \"builtin:bonn-camera-array-sim\"\nmaterial = \"leather\"\n[dome]\ncameras = [0, 31]\n\
                exposure_s = 0.01\nreference_leds = 0\n[outputs]\ncompressed_model = \"fmf\"\n";
    let req = DomeRunRequest { compressed_model: Some(CompressedModel::Pvmf), ..request(plan, &out) };
    let s = run(&req, &mut |l| eprintln!("{l}")).unwrap_or_else(|e| panic!("{e}"));
    assert!(s.stopped.is_none() && s.textures == 2 * 151, "{:?} {}", s.stopped, s.textures);
    let f = figures(&s);
    assert_eq!(
        (f["compression_method"].as_str(), f["compression_streamed"].as_u64()),
        (Some("pvmf"), Some(302)),
        "{f}"
    );
    let (rel, rel_offline) = agrees_with_offline(f, &out, CompressedModel::Pvmf);
    eprintln!("camera array PVMF: streamed rel RMSE {rel}, btfrig compress {rel_offline}; {f}");
    let model = file::read(&journaled(&out, "pvmf")).unwrap();
    // A camera array's view id is the camera.
    assert_eq!(model.layout.captures.as_ref().unwrap().view_ids, vec![0, 31]);
    assert!(btfrig_store::journaled_models(&out).unwrap().iter().all(|m| m.method != "fmf"));
}
