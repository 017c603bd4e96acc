//! The pipeline loop: frames in, committed textures out, into an in-memory dataset.

mod common;

use std::sync::Arc;

use btfrig_core::capture::{CapturedFrame, StepKey, StepTimes};
use btfrig_core::config::RigConfig;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_core::Direction;
use btfrig_imaging::{Filter, Region};
use btfrig_process::{ProcessSettings, Processor};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_store::{Dataset, Manifest, MemStorage, RigInfo, Samplings, TextureFormat, TextureRegion, TextureSpec};

#[test]
fn every_frame_is_written_and_committed_once_and_the_dataset_verifies() {
    let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "builtin rig").unwrap();
    let scene = Arc::new(RigScene::new(&cfg, &MaterialSpec::builtin("leather").unwrap()).unwrap());
    let lights = [Direction::from_degrees(30.0, 0.0), Direction::from_degrees(45.0, 0.0)];
    let views = [Direction::from_degrees(0.0, 0.0), Direction::from_degrees(30.0, 90.0)];
    let size = 16;
    let texture = TextureSpec {
        width: size as u32,
        height: size as u32,
        region: TextureRegion { center_m: [0.0, 0.0], size_m: [0.05, 0.05] },
        format: TextureFormat::ExrHalf,
    };
    let rig = RigInfo { name: "test".into(), config_toml: BUILTIN_RIGS[0].1.into() };
    let manifest = Manifest::new(rig, "plan", Samplings::full(&lights, &views), texture, false, 1);
    let ds = Arc::new(Dataset::create_in(MemStorage::new(), manifest).unwrap());
    let settings = ProcessSettings {
        size,
        region: Region::centred_square(0.05),
        filter: Filter::Bilinear,
        registration: Default::default(),
    };

    let exposure = scene.exposure_for_white(0.5, 1e-4, 30.0);
    let mut frames = Vec::new();
    for (l, &light) in lights.iter().enumerate() {
        for (v, &view) in views.iter().enumerate() {
            let joints = scene.gonio().ik(light, view).unwrap();
            let (mut frame, _) = scene.capture(&joints, 1.0, exposure, 1.0, 5, &RenderOptions::default()).unwrap();
            // A time stamp per frame: the truth probe knows exposures by it.
            frame.meta.timestamp_s = 1.0 + frames.len() as f64;
            let t = StepTimes {
                move_start_s: 0.0,
                move_end_s: 1.0,
                trigger_start_s: 1.0,
                trigger_end_s: 2.0,
                transfer_end_s: 3.0,
                bracket_s: 0.0,
            };
            let key = StepKey { light: l as u32, view: v as u32 };
            // The second frame took a retry.
            let attempts = if frames.len() == 1 { 2 } else { 1 };
            frames.push(CapturedFrame {
                index: frames.len(),
                key,
                frame,
                bracket: Vec::new(),
                attempts,
                joints,
                times: t,
            });
        }
    }
    let probe = common::KnownExposures::new(&scene, frames.iter().map(|c| (c.frame.meta.timestamp_s, c.joints)));
    let processor = Arc::new(
        Processor::new(common::truth_model(&cfg, &scene), settings).unwrap().with_truth(Some(Arc::new(probe))),
    );
    let rt = tokio::runtime::Builder::new_current_thread().enable_time().build().unwrap();
    let (totals, seen) = rt.block_on(async {
        // Capacity 1: the pipeline's receive loop is the only thing draining it.
        let (tx, rx) = tokio::sync::mpsc::channel(1);
        let mut seen = Vec::new();
        let producer = async move {
            for f in frames {
                tx.send(f).await.unwrap();
            }
        };
        let consumer = btfrig_process::run(ds.clone(), processor, rx, |t| seen.push(t.committed));
        let ((), totals) = tokio::join!(producer, consumer);
        (totals.unwrap(), seen)
    });
    assert_eq!(totals.committed, 4);
    assert_eq!(seen, vec![1, 2, 3, 4]);
    assert_eq!(totals.retries, 1);
    assert_eq!(totals.without_truth, 0);
    let r = totals.texture_rel_rmse().unwrap();
    // Leather is dark (noise weighs more) and 16 bilinear texels alias: 0.20 measured; a broken
    // geometry or radiometric scale gives 0.5 and more.
    assert!(r > 0.0 && r < 0.3, "rel_rmse {r}");
    let report = btfrig_store::verify_in(ds.storage());
    assert!(report.is_ok(), "{report}");
    assert_eq!(report.done, 4);
}
