//! What the manifest asks of each step (texture, raw frame, or both) is enforced at commit and
//! checked by `verify`; the live preview is neither data nor an orphan.

mod common;

use btfrig_store::{
    plan_hash, verify_in, Dataset, MemStorage, Problem, StepId, StepTiming, Storage, StoreError, TextureFormat,
    PREVIEW_FILE,
};
use common::{manifest, raw_frame, texels, H, W};

const PLAN: &str = "[plan]\nname = \"outputs\"\n";

#[test]
fn a_step_of_a_raw_frame_dataset_commits_only_with_its_raw_frame_and_verify_checks_it() {
    let ds = Dataset::create_in(MemStorage::new(), manifest(PLAN, TextureFormat::ExrHalf, true)).unwrap();
    let s = StepId { light: 0, view: 0 };
    let t = ds.write_texture(s, &texels(s), W, H).unwrap();
    let err = ds.commit_step(s, vec![t.clone()], 1, StepTiming::default()).unwrap_err();
    assert!(
        matches!(&err, StoreError::BadInput { what, reason } if what.contains("raw/l000_v000.exr") && reason.contains("raw_frames = true")),
        "{err}"
    );
    assert!(ds.completed().is_empty());
    let r = ds.write_raw(s, &raw_frame(s)).unwrap();
    ds.commit_step(s, vec![t, r.clone()], 1, StepTiming::default()).unwrap();
    let rec = ds.step_record(s).unwrap();
    assert!(rec.files.contains(&r));
    let back = btfrig_imageio::decode_raw_exr(r.path.as_ref(), &ds.storage().read(&r.path).unwrap()).unwrap();
    assert_eq!(back, raw_frame(s));

    // Damage the raw frame: verify names it (hash), like any journaled file.
    let st = ds.storage().clone();
    st.corrupt_byte(&r.path, r.size as usize / 2).unwrap();
    let rep = verify_in(&st);
    assert!(rep.problems.iter().any(|p| matches!(p, Problem::WrongHash { path, .. } if *path == r.path)), "{rep}");
}

#[test]
fn raw_frames_only_writes_no_texture_and_verify_accepts_it_but_not_a_record_without_the_raw_frame() {
    let mut m = manifest(PLAN, TextureFormat::ExrHalf, true);
    m.textures = false;
    let ds = Dataset::create_in(MemStorage::new(), m.clone()).unwrap();
    assert!(!ds.storage().files().iter().any(|f| f.starts_with("textures")));
    let s = StepId { light: 0, view: 0 };
    let err = ds.write_texture(s, &texels(s), W, H).unwrap_err();
    assert!(err.to_string().contains("textures = false"), "{err}");
    for s in ds.expected_steps().clone() {
        let r = ds.write_raw(s, &raw_frame(s)).unwrap();
        ds.commit_step(s, vec![r], 1, StepTiming::default()).unwrap();
    }
    let rep = verify_in(ds.storage());
    assert!(rep.is_ok(), "{rep}");
    assert_eq!(rep.files_checked, ds.expected_steps().len());

    // Both off is no dataset at all.
    m.raw_frames = false;
    let err = Dataset::create_in(MemStorage::new(), m).unwrap_err();
    assert!(err.to_string().contains("both false"), "{err}");
}

#[test]
fn verify_reports_a_done_step_whose_record_lacks_a_file_the_manifest_asks_for() {
    // A dataset written without raw frames whose manifest is then edited to claim them: the
    // records name textures only.
    let st = MemStorage::new();
    let ds = Dataset::create_in(st.clone(), manifest(PLAN, TextureFormat::ExrHalf, false)).unwrap();
    for s in ds.expected_steps().clone() {
        let t = ds.write_texture(s, &texels(s), W, H).unwrap();
        ds.commit_step(s, vec![t], 1, StepTiming::default()).unwrap();
    }
    assert!(verify_in(&st).is_ok());
    let mut m = ds.manifest().clone();
    m.raw_frames = true;
    st.create("manifest.json").unwrap();
    st.append("manifest.json", &serde_json::to_vec(&m).unwrap()).unwrap();
    let rep = verify_in(&st);
    let unrecorded: Vec<_> = rep.problems.iter().filter(|p| matches!(p, Problem::Unrecorded { .. })).collect();
    assert_eq!(unrecorded.len(), 5, "{rep}");
    assert!(rep.to_string().contains("raw/l000_v000.exr: the manifest asks for it"), "{rep}");
}

#[test]
fn the_preview_is_replaced_atomically_not_journaled_and_not_an_orphan() {
    let st = MemStorage::new();
    let ds = Dataset::create_in(st.clone(), manifest(PLAN, TextureFormat::ExrHalf, false)).unwrap();
    for s in ds.expected_steps().clone() {
        let t = ds.write_texture(s, &texels(s), W, H).unwrap();
        ds.commit_step(s, vec![t], 1, StepTiming::default()).unwrap();
    }
    ds.write_preview(b"first").unwrap();
    ds.write_preview(b"second").unwrap();
    assert_eq!(st.read(PREVIEW_FILE).unwrap(), b"second");
    assert!(!st.files().iter().any(|f| f.ends_with(".tmp")), "{:?}", st.files());
    assert!(ds.completed().iter().all(|s| ds.step_record(*s).unwrap().files.iter().all(|f| f.path != PREVIEW_FILE)));
    let rep = verify_in(&st);
    assert!(rep.is_ok(), "{rep}");

    // A run killed while replacing it leaves the temporary name: not data, and resume removes it.
    st.create(".preview.png.tmp").unwrap();
    st.append(".preview.png.tmp", b"par").unwrap();
    st.fsync(".preview.png.tmp").unwrap();
    st.fsync("").unwrap();
    assert!(verify_in(&st).is_ok());
    drop(ds);
    let (_ds, resume) = Dataset::open_for_resume_in(st.clone(), &plan_hash(PLAN)).unwrap();
    assert_eq!(resume.removed_orphans, vec![".preview.png.tmp".to_string()]);
}

#[test]
fn texture_previews_are_journaled_with_their_texture_and_encode_the_texture_in_srgb() {
    let mut m = manifest(PLAN, TextureFormat::ExrFloat, false);
    m.texture_previews = true;
    let ds = Dataset::create_in(MemStorage::new(), m.clone()).unwrap();
    let s = StepId { light: 0, view: 1 };
    let tex: Vec<[f32; 3]> = (0..W * H).map(|i| [i as f32 / (W * H - 1) as f32, 0.18, 2.0]).collect();
    let t = ds.write_texture(s, &tex, W, H).unwrap();
    let err = ds.commit_step(s, vec![t.clone()], 1, StepTiming::default()).unwrap_err();
    assert!(err.to_string().contains("previews/l000_v001.png") && err.to_string().contains("texture_previews = true"));
    let p = ds.write_texture_preview(s, &tex, W, H).unwrap();
    ds.commit_step(s, vec![t, p.clone()], 1, StepTiming::default()).unwrap();
    let (w, h, rgb) = btfrig_imageio::decode_srgb8_png(p.path.as_ref(), &ds.storage().read(&p.path).unwrap()).unwrap();
    assert_eq!((w, h), (W, H));
    // Red ramps 0..1 (0 -> 0, 1 -> 255), green is mid grey (linear 0.18 -> sRGB 118), blue
    // (linear 2) clips.
    assert_eq!(&rgb[..3], &[0, 118, 255]);
    assert_eq!(rgb[3 * (W * H - 1)], 255);
    assert!(rgb.chunks(3).all(|px| px[1] == 118 && px[2] == 255));
    assert!(rgb.chunks(3).map(|px| px[0]).collect::<Vec<_>>().windows(2).all(|w| w[0] < w[1]));

    // A preview is data like a texture: a damaged one is named by verify.
    let st = ds.storage().clone();
    st.corrupt_byte(&p.path, p.size as usize / 2).unwrap();
    assert!(verify_in(&st).problems.iter().any(|q| matches!(q, Problem::WrongHash { path, .. } if *path == p.path)));

    // Previews without textures is refused; a dataset without previews refuses to write one.
    let mut bad = m.clone();
    bad.textures = false;
    bad.raw_frames = true;
    let err = Dataset::create_in(MemStorage::new(), bad).unwrap_err();
    assert!(err.to_string().contains("texture_previews is true but textures is false"), "{err}");
    let plain = Dataset::create_in(MemStorage::new(), manifest(PLAN, TextureFormat::ExrHalf, false)).unwrap();
    let err = plain.write_texture_preview(s, &tex, W, H).unwrap_err();
    assert!(err.to_string().contains("texture_previews = false"), "{err}");
}
