//! The plan's outputs through the pipeline: raw frames committed with their textures in one
//! journal record (also across crashes), raw-only runs, and the rate-limited live preview.

mod common;

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Instant;

use btfrig_core::capture::{CapturedFrame, StepKey, StepTimes};
use btfrig_core::config::RigConfig;
use btfrig_core::plan::BUILTIN_RIGS;
use btfrig_core::Direction;
use btfrig_imaging::{Filter, Region};
use btfrig_process::{tone_map_preview, Outputs, PipelineError, PreviewSettings, ProcessSettings, Processor, Totals};
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;
use btfrig_store::{
    content_hash, plan_hash, verify_in, Dataset, Manifest, MemStorage, Problem, RigInfo, Samplings, StepId, Storage,
    TextureFormat, TextureRegion, TextureSpec, PREVIEW_FILE,
};

const PLAN: &str = "[plan]\nname = \"outputs\"\n";

struct Fixture {
    scene: Arc<RigScene>,
    lights: Vec<Direction>,
    views: Vec<Direction>,
    frames: Vec<CapturedFrame>,
}

fn builtin_rig() -> RigConfig {
    RigConfig::from_toml(BUILTIN_RIGS[0].1, "builtin rig").unwrap()
}

/// 2 x 2 captures of the builtin rig (rendered once: the costly part).
fn fixture() -> Fixture {
    let cfg = RigConfig::from_toml(BUILTIN_RIGS[0].1, "builtin rig").unwrap();
    let scene = Arc::new(RigScene::new(&cfg, &MaterialSpec::builtin("lacquered-wood").unwrap()).unwrap());
    let lights = vec![Direction::from_degrees(30.0, 0.0), Direction::from_degrees(45.0, 0.0)];
    let views = vec![Direction::from_degrees(0.0, 0.0), Direction::from_degrees(30.0, 90.0)];
    let exposure = scene.exposure_for_white(0.5, 1e-4, 30.0);
    let mut frames = Vec::new();
    for (l, &light) in lights.iter().enumerate() {
        for (v, &view) in views.iter().enumerate() {
            let joints = scene.gonio().ik(light, view).unwrap();
            let seed = 100 + frames.len() as u64;
            let (mut frame, _) = scene.capture(&joints, 1.0, exposure, 1.0, seed, &RenderOptions::default()).unwrap();
            // A time stamp per frame: the truth probe knows exposures by it.
            frame.meta.timestamp_s = 1.0 + frames.len() as f64;
            let times = StepTimes {
                move_start_s: 0.0,
                move_end_s: 1.0,
                trigger_start_s: 1.0,
                trigger_end_s: 2.0,
                transfer_end_s: 3.0,
                bracket_s: 0.0,
            };
            let key = StepKey { light: l as u32, view: v as u32 };
            frames.push(CapturedFrame {
                index: frames.len(),
                key,
                frame,
                bracket: Vec::new(),
                attempts: 1,
                joints,
                times,
            });
        }
    }
    Fixture { scene, lights, views, frames }
}

fn manifest(f: &Fixture, size: usize, raw: bool, textures: bool) -> Manifest {
    let texture = TextureSpec {
        width: size as u32,
        height: size as u32,
        region: TextureRegion { center_m: [0.0, 0.0], size_m: [0.05, 0.05] },
        format: TextureFormat::ExrFloat,
    };
    let rig = RigInfo { name: "test".into(), config_toml: BUILTIN_RIGS[0].1.into() };
    let mut m = Manifest::new(rig, PLAN, Samplings::full(&f.lights, &f.views), texture, raw, 1);
    m.textures = textures;
    m
}

fn processor(f: &Fixture, size: usize, outputs: Outputs) -> Arc<Processor> {
    let settings = ProcessSettings {
        size,
        region: Region::centred_square(0.05),
        filter: Filter::Bilinear,
        registration: Default::default(),
    };
    let probe = common::KnownExposures::new(&f.scene, f.frames.iter().map(|c| (c.frame.meta.timestamp_s, c.joints)));
    let pr = Processor::new(common::truth_model(&builtin_rig(), &f.scene), settings).unwrap();
    Arc::new(pr.with_truth(Some(Arc::new(probe))).with_outputs(outputs))
}

fn run(ds: &Arc<Dataset<MemStorage>>, pr: &Arc<Processor>, frames: &[CapturedFrame]) -> Result<Totals, PipelineError> {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).build().unwrap();
    let frames = frames.to_vec();
    rt.block_on(async {
        let (tx, rx) = tokio::sync::mpsc::channel(1);
        let producer = async move {
            for f in frames {
                if tx.send(f).await.is_err() {
                    break; // the pipeline stopped at an error
                }
            }
        };
        let ((), totals) = tokio::join!(producer, btfrig_process::run(ds.clone(), pr.clone(), rx, |_| {}));
        totals
    })
}

fn step_of(f: &CapturedFrame) -> StepId {
    StepId { light: f.key.light, view: f.key.view }
}

fn raw_path(s: StepId) -> String {
    format!("raw/{}.exr", s.stem())
}

#[test]
fn raw_frames_round_trip_exactly_and_are_journaled_with_their_textures() {
    let f = fixture();
    let size = 16;
    let mut m = manifest(&f, size, true, true);
    m.texture_previews = true;
    let ds = Arc::new(Dataset::create_in(MemStorage::new(), m).unwrap());
    let out = Outputs { textures: true, raw_frames: true, texture_previews: true, preview: None };
    let totals = run(&ds, &processor(&f, size, out), &f.frames).unwrap();
    assert_eq!(totals.committed, 4);
    assert_eq!(totals.previews, 0);
    assert!(totals.stage_s["write_raw"] > 0.0 && totals.stage_s["write"] > 0.0, "{:?}", totals.stage_s);
    for cf in &f.frames {
        let s = step_of(cf);
        let rec = ds.step_record(s).unwrap();
        let paths: BTreeSet<&str> = rec.files.iter().map(|r| r.path.as_str()).collect();
        let raw = raw_path(s);
        let (tex_name, preview_name) = (format!("textures/{}.exr", s.stem()), format!("previews/{}.png", s.stem()));
        assert_eq!(paths, BTreeSet::from([raw.as_str(), tex_name.as_str(), preview_name.as_str()]));
        let bytes = ds.storage().read(&raw).unwrap();
        let file = rec.files.iter().find(|r| r.path == raw).unwrap();
        assert_eq!(file.hash, content_hash(&bytes));
        assert_eq!(file.size, bytes.len() as u64);
        // Every DN and the metadata needed to reprocess (exposure, gain, levels, CFA, sequence, time).
        let back = btfrig_imageio::decode_raw_exr(raw.as_ref(), &bytes).unwrap();
        assert_eq!(back, cf.frame);
        assert!(cf.frame.meta.bayer.is_some() && cf.frame.meta.white_level > cf.frame.meta.black_level);
        // Processing the stored raw frame gives the texture processing the live one gave.
        let tex_path = format!("textures/{}.exr", s.stem());
        let tex = ds.storage().read(&tex_path).unwrap();
        let p = processor(&f, size, Outputs::default());
        let again = p.process(s, &back, &cf.joints, None).unwrap().texels;
        let dir = std::env::temp_dir().join(format!("btfrig-pipeline-outputs-{}-{}", std::process::id(), s.stem()));
        std::fs::write(&dir, &tex).unwrap();
        let (_, _, stored) = btfrig_imageio::read_rgb_exr(&dir).unwrap();
        std::fs::remove_file(&dir).unwrap();
        assert_eq!(stored, again, "{s}");
        // The texture's 8-bit preview is the sRGB encoding of the stored texels.
        let png = ds.storage().read(&preview_name).unwrap();
        let (w, h, rgb) = btfrig_imageio::decode_srgb8_png(preview_name.as_ref(), &png).unwrap();
        assert_eq!((w, h), (size, size));
        assert_eq!(rgb, btfrig_imageio::linear_to_srgb8(&stored, 1.0));
    }
    let rep = verify_in(ds.storage());
    assert!(rep.is_ok(), "{rep}");
    assert_eq!(rep.files_checked, 12);
}

#[test]
fn raw_frames_only_writes_no_textures_and_skips_processing() {
    let f = fixture();
    let size = 16;
    let ds = Arc::new(Dataset::create_in(MemStorage::new(), manifest(&f, size, true, false)).unwrap());
    let out = Outputs { textures: false, raw_frames: true, texture_previews: false, preview: None };
    let totals = run(&ds, &processor(&f, size, out), &f.frames).unwrap();
    assert_eq!(totals.committed, 4);
    // Nothing was rectified, so nothing was compared with the truth.
    assert_eq!(totals.without_truth, 4);
    assert!(totals.texture_rel_rmse().is_none());
    assert_eq!(totals.stage_s.keys().collect::<Vec<_>>(), vec!["write_raw"]);
    assert!(!ds.storage().files().iter().any(|p| p.starts_with("textures/")), "{:?}", ds.storage().files());
    let rep = verify_in(ds.storage());
    assert!(rep.is_ok(), "{rep}");
    assert_eq!(rep.files_checked, 4);
}

#[test]
fn a_crash_between_the_writes_and_the_commit_never_counts_a_raw_frame_without_its_texture() {
    let f = fixture();
    let size = 8;
    let out = Outputs {
        textures: true,
        raw_frames: true,
        texture_previews: false,
        preview: Some(PreviewSettings { min_side: 16, min_interval_s: 0.0, max_share: 1.0 }),
    };
    let mut uncommitted_raw_seen = 0;
    let mut failures = 0;
    // Cut the power at every mutating operation of a two-step run in turn (each step: raw
    // frame and texture 5 operations each, the journal record 2, the preview 3).
    let frames = &f.frames[..2];
    for n in 0..32 {
        let st = MemStorage::new();
        let ds = Arc::new(Dataset::create_in(st.clone(), manifest(&f, size, true, true)).unwrap());
        st.fail_after(n);
        let result = run(&ds, &processor(&f, size, out), frames);
        st.disarm();
        let Err(_) = result else {
            // Past the end of the run.
            assert_eq!(ds.completed().len(), 2);
            continue;
        };
        failures += 1;
        let committed = ds.completed();
        // Before the crash: a raw frame on disk whose step does not count.
        if st.files().iter().any(|p| p.starts_with("raw/l") && !committed.iter().any(|s| *p == raw_path(*s))) {
            uncommitted_raw_seen += 1;
        }
        drop(ds);
        st.crash(None);
        let (ds, resume) = Dataset::open_for_resume_in(st.clone(), &plan_hash(PLAN)).unwrap();
        // Whatever counts has both files, whole; nothing else is left.
        let data: BTreeSet<String> =
            st.files().into_iter().filter(|p| p.starts_with("raw/") || p.starts_with("textures/")).collect();
        let mut named = BTreeSet::new();
        for s in &resume.completed {
            let rec = ds.step_record(*s).unwrap();
            assert_eq!(rec.files.len(), 2, "n = {n}, {s}");
            for r in &rec.files {
                assert_eq!(content_hash(&st.read(&r.path).unwrap()), r.hash, "n = {n}");
                named.insert(r.path.clone());
            }
            let cf = f.frames.iter().find(|cf| step_of(cf) == *s).unwrap();
            let raw = raw_path(*s);
            assert_eq!(btfrig_imageio::decode_raw_exr(raw.as_ref(), &st.read(&raw).unwrap()).unwrap(), cf.frame);
        }
        assert_eq!(data, named, "n = {n}: files without a record survived the resume");
        let rep = verify_in(&st);
        assert!(rep.problems.iter().all(|p| matches!(p, Problem::Incomplete { .. })), "n = {n}: {rep}");
        // The resumed run finishes the rest, each step exactly once.
        let rest: Vec<CapturedFrame> =
            frames.iter().filter(|cf| !resume.completed.contains(&step_of(cf))).cloned().collect();
        let ds = Arc::new(ds);
        let totals = run(&ds, &processor(&f, size, out), &rest).unwrap();
        assert_eq!(totals.committed as usize, rest.len());
        let rep = verify_in(&st);
        assert!(rep.problems.iter().all(|p| matches!(p, Problem::Incomplete { .. })), "n = {n}: {rep}");
        assert_eq!(rep.done, 2, "n = {n}");
    }
    assert!(failures > 20, "{failures}");
    assert!(uncommitted_raw_seen > 0, "no cut fell between a raw write and its commit");
}

#[test]
fn the_preview_shows_the_latest_capture_is_not_journaled_and_is_rate_limited() {
    let f = fixture();
    let size = 16;
    let every = PreviewSettings { min_side: 100, min_interval_s: 0.0, max_share: 1.0 };
    let ds = Arc::new(Dataset::create_in(MemStorage::new(), manifest(&f, size, false, true)).unwrap());
    let pr = processor(&f, size, Outputs { preview: Some(every), ..Outputs::default() });
    let mut rx = pr.subscribe_preview();
    assert!(pr.latest_preview().is_none());
    let t = Instant::now();
    let totals = run(&ds, &pr, &f.frames).unwrap();
    let wall = t.elapsed().as_secs_f64();
    // Unlimited, but never two at once: of two frames in flight one may make a preview. The
    // frame received after a preview was written always makes one, so 2..=4 of 4.
    assert!((2..=4).contains(&totals.previews), "{}", totals.previews);
    assert_eq!(totals.preview_failures, 0);
    assert!(rx.has_changed().unwrap());
    let latest = rx.borrow_and_update().clone().unwrap();
    assert!(ds.completed().contains(&latest.step));
    // 16 texels enlarged by the smallest whole factor reaching 100 px: 7, so 112 px.
    assert_eq!((latest.width, latest.height), (112, 112));
    let file = ds.storage().read(PREVIEW_FILE).unwrap();
    assert_eq!(file, latest.png);
    let (w, h, rgb) = btfrig_imageio::decode_srgb8_png(PREVIEW_FILE.as_ref(), &file).unwrap();
    assert_eq!((w, h), (112, 112));
    // It is the tone-mapped texture of that capture, as stored (float EXR: exact).
    let tex = ds.storage().read(&format!("textures/{}.exr", latest.step.stem())).unwrap();
    let tmp = std::env::temp_dir().join(format!("btfrig-pipeline-preview-{}.exr", std::process::id()));
    std::fs::write(&tmp, &tex).unwrap();
    let (_, _, texels) = btfrig_imageio::read_rgb_exr(&tmp).unwrap();
    std::fs::remove_file(&tmp).unwrap();
    assert_eq!(tone_map_preview(&texels, size, size, 100), (w, h, rgb.clone()));
    assert!(rgb.iter().any(|&b| b > 100), "a lit capture is not black");
    // Not data: in no journal record, and verify accepts it.
    for s in ds.completed() {
        assert!(ds.step_record(s).unwrap().files.iter().all(|r| r.path != PREVIEW_FILE));
    }
    let rep = verify_in(ds.storage());
    assert!(rep.is_ok(), "{rep}");
    let per_preview = totals.stage_s["preview"] / totals.previews as f64;
    let per_frame: f64 =
        ["demosaic", "rectify", "radiometry", "write"].iter().map(|k| totals.stage_s[*k]).sum::<f64>() / 4.0;
    eprintln!(
        "preview {size}px -> 112px: {:.2} ms each; processing {:.2} ms per frame; run wall {wall:.2} s",
        per_preview * 1e3,
        per_frame * 1e3
    );

    // The minimum interval: one preview in a run shorter than it.
    for limit in [
        PreviewSettings { min_side: 100, min_interval_s: 3600.0, max_share: 1.0 },
        // The share: a preview costing c seconds holds the next back by c / 1e-7 (hours).
        PreviewSettings { min_side: 100, min_interval_s: 0.0, max_share: 1e-7 },
    ] {
        let ds = Arc::new(Dataset::create_in(MemStorage::new(), manifest(&f, size, false, true)).unwrap());
        let pr = processor(&f, size, Outputs { preview: Some(limit), ..Outputs::default() });
        let totals = run(&ds, &pr, &f.frames).unwrap();
        assert_eq!(totals.previews, 1, "{limit:?}");
        assert!(ds.storage().read(PREVIEW_FILE).is_ok());
        assert_eq!(pr.latest_preview().unwrap().png, ds.storage().read(PREVIEW_FILE).unwrap());
    }
}

#[test]
fn tone_mapping_exposes_the_99th_percentile_to_90_percent_and_enlarges_by_whole_factors() {
    // A flat 0.45 texture: gain 2, 0.9 linear -> sRGB 0.9547 -> 243.
    let (w, h, rgb) = tone_map_preview(&[[0.45; 3]; 6], 3, 2, 7);
    // The short side 2 needs factor 4 to reach 7.
    assert_eq!((w, h), (12, 8));
    assert!(rgb.iter().all(|&b| b == 243), "{rgb:?}");
    // A gradient: nearest-neighbour blocks, monotone, brightest texels (above the 99th
    // percentile) clipped, negatives and NaN black.
    let mut tex: Vec<[f32; 3]> = (0..100).map(|i| [i as f32 / 100.0, 0.0, 0.0]).collect();
    tex[0] = [-1.0, f32::NAN, 0.0];
    let (w, h, rgb) = tone_map_preview(&tex, 10, 10, 20);
    assert_eq!((w, h), (20, 20));
    let px = |x: usize, y: usize| rgb[(y * w + x) * 3];
    for ty in 0..10 {
        for tx in 0..10 {
            let v = px(2 * tx, 2 * ty);
            assert_eq!([px(2 * tx + 1, 2 * ty), px(2 * tx, 2 * ty + 1), px(2 * tx + 1, 2 * ty + 1)], [v; 3]);
        }
    }
    assert_eq!(&rgb[..3], &[0, 0, 0]);
    let reds: Vec<u8> = (0..100).map(|i| px(2 * (i % 10), 2 * (i / 10))).collect();
    assert!(reds.windows(2).all(|p| p[0] <= p[1]));
    // p99 is texel 98 (0.98): it maps to 0.9 linear; texel 99 (0.99) to 0.909.
    let srgb = |l: f64| ((1.055 * l.powf(1.0 / 2.4) - 0.055) * 255.0).round() as u8;
    // (within 1 of 255: the curve is tabulated at 12-bit input steps)
    let near = |a: u8, b: u8| a.abs_diff(b) <= 1;
    assert!(near(reds[98], srgb(0.9)), "{} vs {}", reds[98], srgb(0.9));
    assert!(near(reds[50], srgb(0.5 * 0.9 / 0.98)), "{} vs {}", reds[50], srgb(0.5 * 0.9 / 0.98));
    assert!(near(reds[99], srgb(0.99 * 0.9 / 0.98)));
    // A black frame stays black-ish: the gain is capped at 16.
    let (_, _, rgb) = tone_map_preview(&[[0.001; 3]; 4], 2, 2, 1);
    assert!(rgb.iter().all(|&b| near(b, srgb(0.016))), "{rgb:?}");
}
