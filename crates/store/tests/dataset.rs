//! The dataset store on the real file system: round trip, resume, refusals, and `verify`
//! naming each kind of damage.

mod common;

use std::collections::BTreeSet;

use btfrig_store::{
    info, plan_hash, verify, Dataset, Problem, RunReport, StepExtra, StepHdr, StepId, StepTiming, StoreError,
    TextureFormat, JOURNAL_FILE,
};
use common::{manifest, raw_frame, texels, TempDir, H, W};

const PLAN: &str = "[plan]\nname = \"test\"\n";

fn step(light: u32, view: u32) -> StepId {
    StepId { light, view }
}

fn timing() -> StepTiming {
    StepTiming { started_unix_s: 1.0e9, wall_s: 0.5, hardware_s: Some(2.0), ..StepTiming::default() }
}

/// Writes and commits every expected step (texture + raw) and finishes the run.
fn complete(dir: &std::path::Path) {
    let mut ds = Dataset::create(dir, manifest(PLAN, TextureFormat::ExrFloat, true)).unwrap();
    for s in ds.expected_steps().clone() {
        let t = ds.write_texture(s, &texels(s), W, H).unwrap();
        let r = ds.write_raw(s, &raw_frame(s)).unwrap();
        ds.commit_step(s, vec![t, r], 1 + s.view, timing()).unwrap();
    }
    ds.finish(&RunReport { captures: 5, wall_s: 3.0, hardware_s: Some(10.0), ..RunReport::default() }).unwrap();
}

#[test]
fn round_trip_create_write_commit_reopen() {
    let tmp = TempDir::new("roundtrip");
    let dir = tmp.path().join("ds");
    let ds = Dataset::create(&dir, manifest(PLAN, TextureFormat::ExrFloat, true)).unwrap();
    assert_eq!(ds.expected_steps().len(), 5);
    let (a, b) = (step(0, 1), step(1, 0));
    for s in [a, b] {
        let t = ds.write_texture(s, &texels(s), W, H).unwrap();
        let r = ds.write_raw(s, &raw_frame(s)).unwrap();
        ds.commit_step(s, vec![t, r], 2, timing()).unwrap();
    }
    // Written but not committed: must not count and must be removed on resume.
    let c = step(0, 0);
    ds.write_texture(c, &texels(c), W, H).unwrap();
    drop(ds);

    let (ds, resume) = Dataset::open_for_resume(&dir, &plan_hash(PLAN)).unwrap();
    assert_eq!(resume.completed, BTreeSet::from([a, b]));
    assert_eq!(resume.remaining, BTreeSet::from([step(0, 0), step(0, 2), step(1, 1)]));
    assert_eq!(resume.removed_orphans, vec![format!("textures/{}.exr", c.stem())]);
    assert!(resume.torn_tail.is_none());
    assert!(!dir.join("textures").join(format!("{}.exr", c.stem())).exists());
    assert_eq!(ds.completed(), BTreeSet::from([a, b]));

    // The files read back as written.
    let (w, h, back) = btfrig_imageio::read_rgb_exr(&dir.join("textures/l000_v001.exr")).unwrap();
    assert_eq!((w, h), (W, H));
    assert_eq!(back, texels(a));
    assert_eq!(btfrig_imageio::read_raw_exr(&dir.join("raw/l001_v000.exr")).unwrap(), raw_frame(b));
    let rec = ds.step_record(a).unwrap();
    assert_eq!(rec.attempts, 2);
    let bytes = std::fs::read(dir.join(&rec.files[0].path)).unwrap();
    assert_eq!(rec.files[0].hash, btfrig_store::content_hash(&bytes));
    assert_eq!(rec.files[0].size, bytes.len() as u64);

    // A resumed run can neither rewrite nor recommit a journaled step.
    assert!(matches!(ds.write_texture(a, &texels(a), W, H), Err(StoreError::StepAlreadyJournaled { .. })));
    assert!(matches!(ds.commit_step(a, vec![], 1, timing()), Err(StoreError::StepAlreadyJournaled { .. })));
    // Nor touch steps outside the plan or skipped by it.
    for s in [step(2, 0), step(1, 2)] {
        assert!(matches!(ds.write_texture(s, &texels(s), W, H), Err(StoreError::UnknownStep { .. })), "{s}");
    }
    assert!(matches!(ds.write_texture(c, &texels(c), W + 1, H), Err(StoreError::BadInput { .. })));
    // A run-time skip is journaled and survives a reopen.
    ds.skip_step(step(1, 1), "marker occluded").unwrap();
    drop(ds);
    let (_, resume) = Dataset::open_for_resume(&dir, &plan_hash(PLAN)).unwrap();
    assert_eq!(resume.skipped.get(&step(1, 1)).map(String::as_str), Some("marker occluded"));
    assert_eq!(resume.remaining, BTreeSet::from([step(0, 0), step(0, 2)]));

    // Another plan cannot resume it.
    match Dataset::open_for_resume(&dir, &plan_hash("other")) {
        Err(StoreError::PlanMismatch { found, .. }) => assert_eq!(found, plan_hash(PLAN)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn an_hdr_bracket_keeps_every_raw_exposure_and_its_record() {
    let tmp = TempDir::new("bracket");
    let dir = tmp.path().join("ds");
    let ds = Dataset::create(&dir, manifest(PLAN, TextureFormat::ExrFloat, true)).unwrap();
    let s = step(0, 1);
    let mut short = raw_frame(s);
    short.meta.exposure_s /= 8.0;
    short.data.iter_mut().for_each(|v| *v /= 8);
    let files = vec![
        ds.write_texture(s, &texels(s), W, H).unwrap(),
        ds.write_raw_exposure(s, 0, &raw_frame(s)).unwrap(),
        ds.write_raw_exposure(s, 1, &short).unwrap(),
    ];
    assert_eq!(files[1].path, format!("raw/{}.exr", s.stem()));
    assert_eq!(files[2].path, format!("raw/{}_e1.exr", s.stem()));
    let hdr = StepHdr {
        exposures_s: vec![raw_frame(s).meta.exposure_s, short.meta.exposure_s],
        bracket_s: 5.8,
        saturated_photosites: 0,
        always_s: vec![0.01, 0.00125, 0.00015625],
    };
    ds.commit_step_with(s, files, 1, timing(), StepExtra { registration: None, hdr: Some(hdr.clone()) }).unwrap();
    drop(ds);
    let (ds, _) = Dataset::open_for_resume(&dir, &plan_hash(PLAN)).unwrap();
    assert_eq!(ds.step_record(s).unwrap().hdr, Some(hdr));
    assert_eq!(btfrig_imageio::read_raw_exr(&dir.join(format!("raw/{}_e1.exr", s.stem()))).unwrap(), short);
    // Every exposure is checked by verify like any journaled file.
    std::fs::write(dir.join(format!("raw/{}_e1.exr", s.stem())), b"damaged").unwrap();
    let problems = verify(&dir).problems;
    assert!(problems.iter().any(|p| format!("{p:?}").contains("_e1.exr")), "{problems:?}");
}

#[test]
fn half_textures_round_to_half_precision() {
    let tmp = TempDir::new("half");
    let ds = Dataset::create(tmp.path(), manifest(PLAN, TextureFormat::ExrHalf, false)).unwrap();
    let s = step(0, 2);
    let t = ds.write_texture(s, &texels(s), W, H).unwrap();
    assert!(matches!(ds.write_raw(s, &raw_frame(s)), Err(StoreError::BadInput { .. })));
    let (_, _, back) = btfrig_imageio::read_rgb_exr(&tmp.path().join(&t.path)).unwrap();
    for (a, b) in texels(s).iter().zip(&back) {
        for c in 0..3 {
            // Half: 11 significant bits, round to nearest.
            assert!((a[c] - b[c]).abs() <= a[c].abs() * 2f32.powi(-11), "{} vs {}", a[c], b[c]);
        }
    }
}

#[test]
fn verify_passes_on_a_complete_dataset_and_info_reports_it() {
    let tmp = TempDir::new("verify-ok");
    complete(tmp.path());
    let v = verify(tmp.path());
    assert!(v.is_ok(), "{v}");
    assert_eq!((v.done, v.expected, v.files_checked), (5, 5, 10));
    assert_eq!(v.skipped.len(), 1);
    let i = info(tmp.path()).unwrap();
    assert_eq!((i.done, i.expected, i.files), (5, 5, 13));
    // attempts are 1 + view: steps (0,0) (0,1) (0,2) (1,0) (1,1) -> retries 0+1+2+0+1.
    assert_eq!(i.retries, 4);
    assert!(i.finished);
    let text = i.to_string();
    for want in ["test-rig", &plan_hash(PLAN), "2 light x 3 view", "5/5 done", "4x3 OpenEXR float", "finished"] {
        assert!(text.contains(want), "{want:?} not in\n{text}");
    }
    let m = i.manifest.timing.unwrap();
    assert_eq!((m.steps_done, m.steps_skipped, m.retries, m.hardware_s), (5, 1, 4, Some(10.0)));
}

fn problems_after(tag: &str, damage: impl FnOnce(&std::path::Path)) -> Vec<Problem> {
    let tmp = TempDir::new(tag);
    complete(tmp.path());
    damage(tmp.path());
    let v = verify(tmp.path());
    assert!(!v.is_ok());
    v.problems
}

#[test]
fn verify_names_each_kind_of_damage() {
    let tex = "textures/l000_v001.exr";
    let p = problems_after("missing", |d| std::fs::remove_file(d.join(tex)).unwrap());
    assert_eq!(p, vec![Problem::MissingFile { step: step(0, 1), path: tex.into() }]);

    let p = problems_after("altered", |d| {
        let mut b = std::fs::read(d.join(tex)).unwrap();
        let n = b.len();
        b[n - 5] ^= 0x40;
        std::fs::write(d.join(tex), b).unwrap();
    });
    assert!(matches!(&p[..], [Problem::WrongHash { path, .. }] if path == tex), "{p:?}");

    let p = problems_after("shortened", |d| {
        let b = std::fs::read(d.join(tex)).unwrap();
        std::fs::write(d.join(tex), &b[..b.len() - 1]).unwrap();
    });
    assert!(matches!(&p[..], [Problem::WrongSize { path, .. }] if path == tex), "{p:?}");

    let p = problems_after("torn", |d| {
        let b = std::fs::read(d.join(JOURNAL_FILE)).unwrap();
        std::fs::write(d.join(JOURNAL_FILE), &b[..b.len() - 7]).unwrap();
    });
    // The last step's record is torn: its step is missing and its files are orphans.
    assert!(matches!(p[0], Problem::TornJournalTail(_)), "{p:?}");
    assert!(p.contains(&Problem::Incomplete { missing: 1 }), "{p:?}");
    assert_eq!(p.iter().filter(|x| matches!(x, Problem::Orphan { .. })).count(), 2, "{p:?}");

    let p = problems_after("middle", |d| {
        let mut b = std::fs::read(d.join(JOURNAL_FILE)).unwrap();
        let second_line = b.iter().position(|&c| c == b'\n').unwrap() + 1;
        b[second_line + 40] ^= 0x01;
        std::fs::write(d.join(JOURNAL_FILE), b).unwrap();
    });
    assert!(p.iter().any(|x| matches!(x, Problem::Journal { reason } if reason.contains("damaged at byte"))), "{p:?}");

    let p = problems_after("orphan", |d| std::fs::write(d.join("textures/stray.exr"), b"x").unwrap());
    assert_eq!(p, vec![Problem::Orphan { path: "textures/stray.exr".into() }]);

    let p = problems_after("manifest", |d| {
        let t = std::fs::read_to_string(d.join("manifest.json")).unwrap();
        std::fs::write(d.join("manifest.json"), t.replace("\"schema_version\": 1", "\"schema_version\": 99")).unwrap();
    });
    assert!(matches!(&p[..], [Problem::Manifest { reason }] if reason.contains("schema_version 99")), "{p:?}");

    let tmp = TempDir::new("foreign");
    std::fs::write(tmp.path().join("holiday.jpg"), b"jpeg").unwrap();
    let v = verify(tmp.path());
    assert_eq!(v.problems, vec![Problem::NotADataset { found: vec!["holiday.jpg".into()] }]);
}

#[test]
fn create_refuses_other_datasets_and_unrelated_directories_without_touching_them() {
    let tmp = TempDir::new("refuse");
    let dir = tmp.path().join("ds");
    complete(&dir);
    let before = std::fs::read(dir.join("manifest.json")).unwrap();
    let journal_before = std::fs::read(dir.join(JOURNAL_FILE)).unwrap();

    let err = Dataset::create(&dir, manifest("another plan", TextureFormat::ExrFloat, true)).unwrap_err();
    assert!(matches!(err, StoreError::OtherDataset { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains(&plan_hash(PLAN)) && msg.contains("test-rig") && msg.contains("never overwritten"), "{msg}");

    let err = Dataset::create(&dir, manifest(PLAN, TextureFormat::ExrFloat, true)).unwrap_err();
    assert!(matches!(err, StoreError::AlreadyExists { .. }), "{err:?}");
    assert!(err.to_string().contains("resume"), "{err}");
    assert_eq!(std::fs::read(dir.join("manifest.json")).unwrap(), before);
    assert_eq!(std::fs::read(dir.join(JOURNAL_FILE)).unwrap(), journal_before);
    assert!(verify(&dir).is_ok());

    let other = tmp.path().join("photos");
    std::fs::create_dir_all(other.join("2024")).unwrap();
    std::fs::write(other.join("notes.txt"), b"keep me").unwrap();
    let err = Dataset::create(&other, manifest(PLAN, TextureFormat::ExrFloat, true)).unwrap_err();
    match &err {
        StoreError::NotEmpty { found, .. } => assert_eq!(found, &vec!["2024/".to_string(), "notes.txt".to_string()]),
        other => panic!("{other:?}"),
    }
    assert!(err.to_string().contains("notes.txt"));
    assert_eq!(std::fs::read_dir(&other).unwrap().count(), 2);

    // An empty existing directory is fine.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    Dataset::create(&empty, manifest(PLAN, TextureFormat::ExrFloat, false)).unwrap();
}

#[test]
fn resume_cuts_a_torn_journal_tail_and_reports_it() {
    let tmp = TempDir::new("resume-torn");
    let dir = tmp.path();
    let ds = Dataset::create(dir, manifest(PLAN, TextureFormat::ExrFloat, false)).unwrap();
    for s in [step(0, 0), step(0, 1)] {
        let t = ds.write_texture(s, &texels(s), W, H).unwrap();
        ds.commit_step(s, vec![t], 1, timing()).unwrap();
    }
    drop(ds);
    let full = std::fs::read(dir.join(JOURNAL_FILE)).unwrap();
    let cut = full.len() - 20;
    std::fs::write(dir.join(JOURNAL_FILE), &full[..cut]).unwrap();
    let (ds, resume) = Dataset::open_for_resume(dir, &plan_hash(PLAN)).unwrap();
    let torn = resume.torn_tail.clone().unwrap();
    assert_eq!(torn.offset + torn.bytes, cut as u64);
    assert_eq!(resume.completed, BTreeSet::from([step(0, 0)]));
    assert_eq!(resume.removed_orphans, vec!["textures/l000_v001.exr".to_string()]);
    assert_eq!(std::fs::metadata(dir.join(JOURNAL_FILE)).unwrap().len(), torn.offset);
    assert!(resume.to_string().contains("torn journal tail"), "{resume}");
    // The step is redone exactly once.
    let s = step(0, 1);
    let t = ds.write_texture(s, &texels(s), W, H).unwrap();
    ds.commit_step(s, vec![t], 1, timing()).unwrap();
    assert_eq!(ds.completed(), BTreeSet::from([step(0, 0), step(0, 1)]));
}

/// r24: resume trusted the journal without looking at the files. A done step whose texture
/// or raw frame is missing, shorter, or altered is now journaled as retaken (named with what
/// was found), its files deleted, and it is to be captured again; the rest stays done.
#[test]
fn r24_resume_retakes_the_steps_of_damaged_files_and_names_them() {
    let tmp = TempDir::new("retake");
    let dir = tmp.path().join("ds");
    complete(&dir);
    let (missing, short, altered, intact) = (step(0, 0), step(0, 1), step(1, 0), step(0, 2));
    std::fs::remove_file(dir.join(format!("textures/{}.exr", missing.stem()))).unwrap();
    let raw = dir.join(format!("raw/{}.exr", short.stem()));
    let len = std::fs::metadata(&raw).unwrap().len();
    std::fs::OpenOptions::new().write(true).open(&raw).unwrap().set_len(len - 1).unwrap();
    let tex = dir.join(format!("textures/{}.exr", altered.stem()));
    let mut bytes = std::fs::read(&tex).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x01;
    std::fs::write(&tex, &bytes).unwrap();

    let (ds, resume) = Dataset::open_for_resume(&dir, &plan_hash(PLAN)).unwrap();
    let named: Vec<(StepId, &str)> = resume.retaken.iter().map(|(s, w)| (*s, w.as_str())).collect();
    assert_eq!(named.len(), 3, "{named:?}");
    assert_eq!(named[0], (missing, "textures/l000_v000.exr: missing"));
    assert_eq!(named[1].0, short);
    assert_eq!(named[1].1, format!("raw/l000_v001.exr: {} bytes, journaled with {len}", len - 1));
    assert_eq!(named[2].0, altered);
    assert!(named[2].1.starts_with("textures/l001_v000.exr: content hash sha256:"), "{}", named[2].1);
    assert_eq!(resume.remaining, BTreeSet::from([missing, short, altered]));
    assert!(resume.completed.contains(&intact) && !resume.completed.contains(&missing));
    assert!(resume.removed_orphans.is_empty(), "{:?}", resume.removed_orphans);
    // Every file of a retaken step is gone (the intact texture of `short` too): captured again.
    assert!(!dir.join(format!("textures/{}.exr", short.stem())).exists());
    assert!(!tex.exists() && !raw.exists());
    assert!(resume.to_string().contains("textures/l000_v000.exr: missing: step (light 0, view 0) is captured again"));

    // The retaken steps are written and committed again; the dataset verifies.
    for s in [missing, short, altered] {
        let t = ds.write_texture(s, &texels(s), W, H).unwrap();
        let r = ds.write_raw(s, &raw_frame(s)).unwrap();
        ds.commit_step(s, vec![t, r], 1, timing()).unwrap();
    }
    drop(ds);
    let report = verify(&dir);
    assert!(report.is_ok(), "{report}");
    let (_, resume) = Dataset::open_for_resume(&dir, &plan_hash(PLAN)).unwrap();
    assert!(resume.retaken.is_empty() && resume.remaining.is_empty());
    assert_eq!(resume.files_checked, 10);
}

/// r24: the manifest was not protected. The journal's header holds its hash; an edited seed
/// is refused by resume and reported by verify, naming manifest.json; `finish` rewrites only
/// `timing` and keeps the hash valid.
#[test]
fn r24_the_manifest_is_protected_by_the_journal_header() {
    let tmp = TempDir::new("manifest-hash");
    let dir = tmp.path().join("ds");
    complete(&dir);
    // finish wrote the timing summary; the manifest still checks.
    let text = std::fs::read_to_string(dir.join("manifest.json")).unwrap();
    assert!(text.contains("\"steps_done\": 5"), "{text}");
    assert!(verify(&dir).is_ok());
    let (mut ds, _) = Dataset::open_for_resume(&dir, &plan_hash(PLAN)).unwrap();
    ds.finish(&RunReport::default()).unwrap();
    drop(ds);
    assert!(verify(&dir).is_ok(), "{}", verify(&dir));

    let seed = text.find("\"seed\": ").unwrap() + "\"seed\": ".len();
    let edited = format!("{}9{}", &text[..seed], &text[seed..]);
    std::fs::write(dir.join("manifest.json"), &edited).unwrap();
    match Dataset::open_for_resume(&dir, &plan_hash(PLAN)) {
        Err(e @ StoreError::ManifestChanged { .. }) => {
            assert!(e.to_string().contains("manifest.json: changed since the dataset was created"), "{e}")
        }
        other => panic!("{other:?}"),
    }
    let report = verify(&dir);
    assert!(matches!(report.problems.as_slice(), [Problem::ManifestChanged { .. }]), "{report}");
    assert!(report.to_string().contains("manifest.json: changed since the dataset was created"), "{report}");
}

/// A dome-style dataset: raw frames per view group (`raw_groups`), no per-step raw frame.
fn group_manifest() -> btfrig_store::Manifest {
    let mut m = manifest(PLAN, TextureFormat::ExrFloat, false);
    m.raw_groups = Some(serde_json::json!({"mode": "test", "patterns": 3}));
    m
}

/// Writes and journals view `view`'s 3 group frames, then its textures.
fn commit_view(ds: &Dataset, view: u32) {
    let files: Vec<_> =
        (0..3).map(|p| ds.write_group_frame(view, p, &raw_frame(step(p as u32, view))).unwrap()).collect();
    ds.commit_frames(view, files).unwrap();
    for s in ds.expected_steps().clone().into_iter().filter(|s| s.view == view) {
        let t = ds.write_texture(s, &texels(s), W, H).unwrap();
        ds.commit_step(s, vec![t], 1, timing()).unwrap();
    }
}

#[test]
fn r25_view_group_raw_frames_are_journaled_verified_and_retaken_when_damaged() {
    let tmp = TempDir::new("groups");
    let dir = tmp.path().join("ds");
    let mut ds = Dataset::create(&dir, group_manifest()).unwrap();
    for view in 0..3 {
        commit_view(&ds, view);
    }
    // Refusals: a journaled group again, a view outside the dataset, a group out of order.
    let again = ds.write_group_frame(0, 0, &raw_frame(step(0, 0)));
    assert!(
        matches!(&again, Err(StoreError::BadInput { reason, .. }) if reason.contains("already journaled")),
        "{again:?}"
    );
    let outside = ds.write_group_frame(3, 0, &raw_frame(step(0, 0)));
    assert!(
        matches!(&outside, Err(StoreError::BadInput { reason, .. }) if reason.contains("views 0..3")),
        "{outside:?}"
    );
    ds.finish(&RunReport::default()).unwrap();
    drop(ds);
    let r = verify(&dir);
    assert!(r.is_ok(), "{r}");
    assert_eq!(r.files_checked, 5 + 9, "5 textures and 9 group frames hashed");
    // The frames read back as written.
    assert_eq!(btfrig_imageio::read_raw_exr(&dir.join("raw/v001_p002.exr")).unwrap(), raw_frame(step(2, 1)));

    // Damage one frame of view 1: verify names it, and a resume retakes the group with every
    // texture of its view (a texture is never kept without its frames).
    std::fs::write(dir.join("raw/v001_p002.exr"), b"torn").unwrap();
    let r = verify(&dir);
    assert!(
        r.problems.iter().any(|p| matches!(p, Problem::GroupFrame { view: 1, path, what }
            if path == "raw/v001_p002.exr" && what.contains("journaled with"))),
        "{r}"
    );
    // An uncommitted frame (a crash before the group's record) is an orphan.
    std::fs::write(dir.join("raw/v002_p003.exr"), b"partial").unwrap();
    let (ds, resume) = Dataset::open_for_resume(&dir, &plan_hash(PLAN)).unwrap();
    assert_eq!(resume.remaining, BTreeSet::from([step(0, 1), step(1, 1)]), "{resume}");
    assert!(resume.retaken.iter().any(|(_, what)| what.starts_with("raw/v001_p002.exr")), "{resume}");
    assert_eq!(resume.removed_orphans, vec!["raw/v002_p003.exr".to_string()]);
    assert!(ds.frames_record(1).is_none() && ds.frames_record(0).is_some());
    assert!(!dir.join("raw/v001_p000.exr").exists(), "the retaken group's frames are deleted");
    commit_view(&ds, 1);
    drop(ds);
    let r = verify(&dir);
    assert!(r.is_ok(), "{r}");

    // Textures of a view without its raw frames: refused by verify.
    let dir2 = tmp.path().join("ds2");
    let ds = Dataset::create(&dir2, group_manifest()).unwrap();
    let s = step(0, 0);
    let t = ds.write_texture(s, &texels(s), W, H).unwrap();
    ds.commit_step(s, vec![t], 1, timing()).unwrap();
    drop(ds);
    let r = verify(&dir2);
    assert!(r.problems.iter().any(|p| matches!(p, Problem::NoGroupFrames { view: 0 })), "{r}");
    // A dataset without raw_groups refuses group frames.
    let dir3 = tmp.path().join("ds3");
    let ds = Dataset::create(&dir3, manifest(PLAN, TextureFormat::ExrFloat, false)).unwrap();
    let e = ds.write_group_frame(0, 0, &raw_frame(s));
    assert!(matches!(&e, Err(StoreError::BadInput { reason, .. }) if reason.contains("raw_groups")), "{e:?}");
}

#[test]
fn r25_a_crash_between_a_groups_frames_and_its_textures_takes_the_group_again() {
    let tmp = TempDir::new("groups-crash");
    let dir = tmp.path().join("ds");
    let ds = Dataset::create(&dir, group_manifest()).unwrap();
    commit_view(&ds, 0);
    // View 1: frames journaled, then the crash after the first of its textures.
    let files: Vec<_> = (0..3).map(|p| ds.write_group_frame(1, p, &raw_frame(step(p as u32, 1))).unwrap()).collect();
    ds.commit_frames(1, files).unwrap();
    let s = step(0, 1);
    let t = ds.write_texture(s, &texels(s), W, H).unwrap();
    ds.commit_step(s, vec![t], 1, timing()).unwrap();
    // View 2: a texture journaled without its group's frames (not what a run writes; resume
    // treats it the same).
    let s = step(0, 2);
    let t = ds.write_texture(s, &texels(s), W, H).unwrap();
    ds.commit_step(s, vec![t], 1, timing()).unwrap();
    drop(ds);
    let (ds, resume) = Dataset::open_for_resume(&dir, &plan_hash(PLAN)).unwrap();
    assert_eq!(resume.remaining, BTreeSet::from([step(0, 1), step(1, 1), step(0, 2)]), "{resume}");
    let said: Vec<&str> = resume.retaken.iter().map(|(_, w)| w.as_str()).collect();
    assert_eq!(
        said,
        [
            "view 1's group: its textures are incomplete (1 of 2 journaled)",
            "view 2's group: its raw frames are not journaled"
        ],
        "{resume}"
    );
    assert!(resume.removed_orphans.is_empty(), "the retaken files are not orphans: {resume}");
    assert!(ds.frames_record(1).is_none() && ds.frames_record(0).is_some());
    assert!(!dir.join("raw/v001_p000.exr").exists() && !dir.join("textures/l000_v001.exr").exists());
    // View 0 was whole: kept. The retaken groups are captured again, and the dataset is sound.
    assert!(dir.join("raw/v000_p002.exr").exists());
    commit_view(&ds, 1);
    commit_view(&ds, 2);
    drop(ds);
    let r = verify(&dir);
    assert!(r.is_ok(), "{r}");
}
