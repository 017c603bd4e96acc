//! The recorded camera end to end: a small seeded run on the small-camera simulated rig keeps
//! its raw frames; they are exported as a recording (PNG, TIFF, OpenEXR), and the same plan
//! run on the recorded rig gives the same texture files, byte for byte. Broken recordings are
//! refused before anything is written, each naming the file and the field.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use btfrig_measurement::{run, RunControl, RunOutcome, RunRequest};
use btfrig_recorded::export::{export_recording, RIG_FILE};
use btfrig_recorded::format::ExportFormat;

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("recorded-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

/// Six captures up to theta 15 deg, 16-texel textures, raw frames kept, on the rig `rig`.
fn plan(rig: &Path) -> String {
    format!(
        r#"
name = "replay"
[rig]
config = "{}"
material = "lacquered-wood"
seed = 7
[sampling]
light = {{ preset = "bonn81", theta_max_deg = 15 }}
view = {{ preset = "bonn81", theta_max_deg = 15 }}
[texture]
size = 16
[exposure]
mode = "auto"
[skip]
max_captures = 6
[outputs]
raw_frames = true
[run]
fault_scenario = "none"
"#,
        rig.display()
    )
}

/// The source dataset, measured once for every test of this file.
fn source() -> &'static Path {
    static SOURCE: OnceLock<PathBuf> = OnceLock::new();
    SOURCE.get_or_init(|| {
        btfrig_sim_backend::install();
        let dir = scratch("source");
        let out = dir.join("dataset");
        let req =
            RunRequest::from_text(plan(&repo("rig-configs/bonn-gonio-sim-small.toml")), &dir.join("plan.toml"), &out);
        let s = run(&req, &RunControl::new(), &mut |_| {}).unwrap();
        assert_eq!(s.outcome, RunOutcome::Finished, "{s:?}");
        assert_eq!(s.captures, 6);
        out
    })
}

/// `textures/*.exr` by name, with their content hashes.
fn textures(dataset: &Path) -> BTreeMap<String, String> {
    std::fs::read_dir(dataset.join("textures"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "exr"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                btfrig_store::content_hash(&std::fs::read(&p).unwrap()),
            )
        })
        .collect()
}

/// Exports the source as a recording in `format` under `dir/rec`.
fn export(dir: &Path, format: ExportFormat) -> PathBuf {
    let rec = dir.join("rec");
    let s = export_recording(source(), &rec, format).unwrap();
    assert_eq!((s.captures, s.frames), (6, 6), "{s:?}");
    rec
}

/// The plan run on the recorded rig of `rec` into `dir/replay`.
fn replay(dir: &Path, rec: &Path) -> Result<PathBuf, btfrig_measurement::RunError> {
    btfrig_sim_backend::install();
    let out = dir.join("replay");
    let req = RunRequest::from_text(plan(&rec.join(RIG_FILE)), &dir.join("plan.toml"), &out);
    let s = run(&req, &RunControl::new(), &mut |_| {})?;
    assert_eq!(s.outcome, RunOutcome::Finished, "{s:?}");
    Ok(out)
}

fn round_trip(format: ExportFormat) {
    let dir = scratch(&format!("round-trip-{}", format.extension()));
    let original = textures(source());
    assert_eq!(original.len(), 6);
    let rec = export(&dir, format);
    let out = replay(&dir, &rec).unwrap();
    assert_eq!(textures(&out), original, "the replayed textures differ from the original run's ({format:?} frames)");
}

#[test]
fn png_recording_replays_to_the_same_textures() {
    round_trip(ExportFormat::Png);
}

#[test]
fn tiff_recording_replays_to_the_same_textures() {
    round_trip(ExportFormat::Tiff);
}

#[test]
fn exr_recording_replays_to_the_same_textures() {
    round_trip(ExportFormat::Exr);
}

/// A broken copy of a PNG recording: `brk` edits it; the replay must fail before creating
/// its output, with a message holding every string of `expect`.
fn refused(name: &str, brk: impl FnOnce(&Path), expect: &[&str]) {
    let dir = scratch(&format!("broken-{name}"));
    let rec = export(&dir, ExportFormat::Png);
    brk(&rec);
    let e = replay(&dir, &rec).expect_err("a broken recording must be refused").to_string();
    eprintln!("{name}: {e}");
    for s in expect {
        assert!(e.contains(s), "{name}: the message lacks {s:?}:\n{e}");
    }
    assert!(!dir.join("replay").exists(), "{name}: the output directory was created");
}

fn sidecar(rec: &Path) -> toml::Table {
    toml::from_str(&std::fs::read_to_string(rec.join("recording.toml")).unwrap()).unwrap()
}

fn write_sidecar(rec: &Path, t: &toml::Table) {
    std::fs::write(rec.join("recording.toml"), toml::to_string(t).unwrap()).unwrap();
}

fn frame_file(rec: &Path, i: usize) -> String {
    sidecar(rec)["frame"].as_array().unwrap()[i]["file"].as_str().unwrap().to_string()
}

#[test]
fn a_missing_frame_file_is_named() {
    let mut name = String::new();
    refused(
        "missing",
        |rec| {
            name = frame_file(rec, 2);
            std::fs::remove_file(rec.join(&name)).unwrap();
        },
        &["frame[2].file", "missing"],
    );
    assert!(!name.is_empty());
}

#[test]
fn a_frame_of_the_wrong_size_is_named() {
    refused(
        "size",
        |rec| {
            let name = frame_file(rec, 1);
            let small = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(8, 6);
            small.save_with_format(rec.join(&name), image::ImageFormat::Png).unwrap();
        },
        &["wrong frame size", "8x6", "160x120"],
    );
}

#[test]
fn an_unknown_frame_format_is_named() {
    refused(
        "format",
        |rec| {
            let mut t = sidecar(rec);
            let f = &mut t["frame"].as_array_mut().unwrap()[3];
            let old = f["file"].as_str().unwrap().to_string();
            let new = old.replace(".png", ".bmp");
            std::fs::rename(rec.join(&old), rec.join(&new)).unwrap();
            f.as_table_mut().unwrap().insert("file".into(), toml::Value::String(new));
            write_sidecar(rec, &t);
        },
        &["unknown frame format", "frame[3].file", ".bmp", ".png"],
    );
}

#[test]
fn a_frame_without_its_sidecar_entry_is_named() {
    refused(
        "stray",
        |rec| {
            let mut t = sidecar(rec);
            t["frame"].as_array_mut().unwrap().remove(4);
            write_sidecar(rec, &t);
        },
        &["without its sidecar entry", "recording.toml", ".png"],
    );
}

#[test]
fn a_malformed_sidecar_is_named_with_its_field() {
    refused(
        "malformed",
        |rec| {
            let mut t = sidecar(rec);
            t["frame"].as_array_mut().unwrap()[0].as_table_mut().unwrap().remove("exposure_s");
            write_sidecar(rec, &t);
        },
        &["recording.toml", "exposure_s"],
    );
}

#[test]
fn a_capture_the_recording_lacks_is_named() {
    refused(
        "lacking",
        |rec| {
            let mut t = sidecar(rec);
            let gone = t["frame"].as_array_mut().unwrap().remove(5);
            std::fs::remove_file(rec.join(gone["file"].as_str().unwrap())).unwrap();
            write_sidecar(rec, &t);
        },
        &["the plan asks for 1 capture(s) the recording lacks", "step light", "nothing was written"],
    );
}

/// A DNG file per the DNG 1.4 specification, written here byte by byte (not by the decoder
/// under test): one uncompressed strip of 16-bit CFA samples (`PhotometricInterpretation`
/// 32803), a 2x2 RGGB `CFAPattern`, black and white level, an identity `ColorMatrix1`.
#[cfg(feature = "raw")]
fn write_dng(path: &Path, width: u32, height: u32, samples: &[u16], black: u32, white: u32) {
    // (tag, TIFF type, count, value bytes); types: 1 BYTE, 2 ASCII, 3 SHORT, 4 LONG, 10 SRATIONAL.
    let ascii = |s: &str| [s.as_bytes(), &[0]].concat();
    let short = |v: &[u16]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let long = |v: u32| v.to_le_bytes().to_vec();
    let identity: Vec<u8> =
        (0..9).flat_map(|i| [if i % 4 == 0 { 1i32 } else { 0 }, 1].into_iter().flat_map(i32::to_le_bytes)).collect();
    let strip_bytes = 2 * width * height;
    let mut entries: Vec<(u16, u16, u32, Vec<u8>)> = vec![
        (254, 4, 1, long(0)),
        (256, 4, 1, long(width)),
        (257, 4, 1, long(height)),
        (258, 3, 1, short(&[16])),
        (259, 3, 1, short(&[1])),
        (262, 3, 1, short(&[32803])),
        (271, 2, 7, ascii("btfrig")),
        (272, 2, 14, ascii("recorded test")),
        (273, 4, 1, long(0)), // the strip's offset, set below
        (277, 3, 1, short(&[1])),
        (278, 4, 1, long(height)),
        (279, 4, 1, long(strip_bytes)),
        (284, 3, 1, short(&[1])),
        (33421, 3, 2, short(&[2, 2])),
        (33422, 1, 4, vec![0, 1, 1, 2]),
        (50706, 1, 4, vec![1, 4, 0, 0]),
        (50708, 2, 21, ascii("btfrig recorded test")),
        (50714, 4, 1, long(black)),
        (50717, 4, 1, long(white)),
        (50721, 10, 9, identity),
        (50778, 3, 1, short(&[21])),
    ];
    let ifd_len = 2 + 12 * entries.len() as u32 + 4;
    let mut extra_at = 8 + ifd_len;
    let mut extra = Vec::new();
    let strip_at = {
        let outside: u32 =
            entries.iter().filter(|e| e.3.len() > 4).map(|e| (e.3.len() as u32).next_multiple_of(2)).sum();
        8 + ifd_len + outside
    };
    entries.iter_mut().find(|e| e.0 == 273).unwrap().3 = long(strip_at);
    let mut out = b"II\x2a\x00\x08\x00\x00\x00".to_vec();
    out.extend((entries.len() as u16).to_le_bytes());
    for (tag, kind, count, bytes) in &entries {
        out.extend(tag.to_le_bytes());
        out.extend(kind.to_le_bytes());
        out.extend(count.to_le_bytes());
        if bytes.len() <= 4 {
            let mut v = bytes.clone();
            v.resize(4, 0);
            out.extend(v);
        } else {
            out.extend(extra_at.to_le_bytes());
            let mut v = bytes.clone();
            v.resize(bytes.len().next_multiple_of(2), 0);
            extra_at += v.len() as u32;
            extra.extend(v);
        }
    }
    out.extend(0u32.to_le_bytes());
    out.extend(extra);
    assert_eq!(out.len() as u32, strip_at);
    out.extend(samples.iter().flat_map(|s| s.to_le_bytes()));
    std::fs::write(path, out).unwrap();
}

/// DNG frames (the camera raw path, through rawler; feature `raw`): the TIFF recording's
/// frames rewritten as DNG files replay to the original run's textures.
#[cfg(feature = "raw")]
#[test]
fn dng_recording_replays_to_the_same_textures() {
    let dir = scratch("round-trip-dng");
    let original = textures(source());
    let rec = export(&dir, ExportFormat::Tiff);
    let mut t = sidecar(&rec);
    let mut written = 0;
    for f in t["frame"].as_array_mut().unwrap() {
        let f = f.as_table_mut().unwrap();
        let tif = f["file"].as_str().unwrap().to_string();
        let img = image::open(rec.join(&tif)).unwrap().into_luma16();
        let dng = tif.replace(".tif", ".dng");
        write_dng(&rec.join(&dng), img.width(), img.height(), img.as_raw(), 256, 16383);
        std::fs::remove_file(rec.join(&tif)).unwrap();
        f.insert("file".into(), toml::Value::String(dng));
        written += 1;
    }
    assert_eq!(written, 6);
    write_sidecar(&rec, &t);
    let out = replay(&dir, &rec).unwrap();
    assert_eq!(textures(&out), original, "the replayed textures differ from the original run's (DNG frames)");
}
