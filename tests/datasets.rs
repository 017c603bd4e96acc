//! Data safety of datasets (issue 24, items 4, 5 and 7): what `btfrig run` does with a
//! finished dataset whose files were damaged, a `--compress` run killed while writing its
//! model, an edited or broken manifest, and `dataset verify` on a closed pipe. Each test
//! first reproduces the fault as it was found, then checks the fixed behaviour. Real
//! processes on real files, each test in its own directory under `target/`.

mod support;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use support::{btfrig, ok, read_journal, read_json, repo, text};

fn scratch(name: &str) -> PathBuf {
    support::scratch(&format!("datasets-{name}"))
}

fn run(cmd: &mut Command) -> Output {
    cmd.output().expect("btfrig runs")
}

/// `btfrig run --plan PLAN --out OUT` with extra arguments.
fn run_plan(plan: &Path, out: &Path, extra: &[&str]) -> Output {
    run(btfrig().args(["run", "--plan"]).arg(plan).arg("--out").arg(out).args(extra))
}

/// The small plan of the CLI tests: 12 captures of 32-texel textures.
fn tiny_plan(dir: &Path) -> PathBuf {
    let path = dir.join("tiny.toml");
    let text = include_str!("data/tiny-plan.toml").replace("SEED", "7").replace("FAULTS", "none");
    std::fs::write(&path, text).unwrap();
    path
}

/// The texture files of the journal's step records, in journal order, with their hashes.
fn journaled_textures(out: &Path) -> Vec<(String, String)> {
    let j = read_journal(out);
    j.committed().values().flat_map(|files| files.iter().filter(|(p, _)| p.starts_with("textures/")).cloned()).collect()
}

/// r24 item 4: after a texture of a finished dataset was deleted, truncated or bit-flipped,
/// `btfrig run` said "nothing to do" and exited 0 with the texture still missing. Now the
/// rerun names each damaged file and why, captures its step again (the simulator is
/// deterministic: the same bytes), and the dataset verifies.
#[test]
fn r24_damaged_textures_are_named_and_captured_again_on_resume() {
    let dir = scratch("damaged");
    let plan = repo("rig-configs/plans/demo.toml");
    let out = dir.join("demo");
    let first = run_plan(&plan, &out, &[]);
    assert!(first.status.success(), "{}", text(&first));
    let textures = journaled_textures(&out);
    assert_eq!(textures.len(), 60);
    let (missing, short, flipped) = (&textures[3], &textures[20], &textures[41]);
    std::fs::remove_file(out.join(&missing.0)).unwrap();
    let len = std::fs::metadata(out.join(&short.0)).unwrap().len();
    std::fs::OpenOptions::new().write(true).open(out.join(&short.0)).unwrap().set_len(len - 100).unwrap();
    let mut bytes = std::fs::read(out.join(&flipped.0)).unwrap();
    let at = bytes.len() / 2;
    bytes[at] ^= 0x10;
    std::fs::write(out.join(&flipped.0), &bytes).unwrap();
    // Only verify noticed before.
    assert!(!run(btfrig().args(["dataset", "verify"]).arg(&out)).status.success());

    let again = run_plan(&plan, &out, &[]);
    let all = text(&again);
    assert!(again.status.success(), "{all}");
    assert!(!all.contains("nothing to do"), "{all}");
    assert!(all.contains(&format!("{}: missing", missing.0)), "{all}");
    assert!(all.contains(&format!("{}: {} bytes, journaled with {len}", short.0, len - 100)), "{all}");
    assert!(all.contains(&format!("{}: content hash", flipped.0)), "{all}");
    assert!(all.contains("60 captures (3 this run)"), "{all}");
    ok(btfrig().args(["dataset", "verify"]).arg(&out));
    let report = read_json(&out.join("report.json"));
    assert_eq!((report["status"].as_str(), report["captures"].as_u64()), (Some("finished"), Some(60)), "{report}");
    let j = read_journal(&out);
    assert_eq!(j.retakes.len(), 3, "{:?}", j.retakes);
    // Captured again, byte for byte: the same content hash as first journaled.
    let now = journaled_textures(&out);
    for (path, hash) in [missing, short, flipped] {
        assert!(now.contains(&(path.clone(), hash.clone())), "{path} not recaptured as it was");
    }
    // And a third run has nothing to do.
    let third = run_plan(&plan, &out, &[]);
    assert!(String::from_utf8_lossy(&third.stdout).contains("nothing to do"), "{}", text(&third));
}

/// r24 item 5: `--compress` finalised report and manifest before writing the model; a kill at
/// the model's write left a complete `.btfm.tmp`, and the rerun said "nothing to do" without
/// building the model. The state such a kill leaves is a finished dataset whose journal
/// names no model, and the temporary file next to it: the rerun must build and journal the
/// model and remove the temporary file; a further rerun builds nothing.
#[test]
fn r24_a_compress_run_killed_at_the_model_write_builds_the_model_on_rerun() {
    let dir = scratch("compress");
    // The demo plan: its 60 captures allow the streaming FMF's 16 terms.
    let plan = repo("rig-configs/plans/demo.toml");
    let out = dir.join("run");
    let first = run_plan(&plan, &out, &[]);
    assert!(first.status.success(), "{}", text(&first));
    let (model, tmp) = (dir.join("run.fmf.btfm"), dir.join("run.fmf.btfm.tmp"));
    std::fs::write(&tmp, vec![0x42u8; 4096]).unwrap();
    assert!(read_journal(&out).models.is_empty());

    let again = run_plan(&plan, &out, &["--compress", "fmf"]);
    let all = text(&again);
    assert!(again.status.success(), "{all}");
    assert!(all.contains("nothing to do") && all.contains(&format!("removed {}", tmp.display())), "{all}");
    assert!(!tmp.exists(), "{} left behind", tmp.display());
    let written = std::fs::read(&model).unwrap_or_else(|e| panic!("{}: {e}\n{all}", model.display()));
    let models = read_journal(&out).models;
    assert_eq!(models.len(), 1, "{models:?}");
    assert_eq!(models[0]["file"], "run.fmf.btfm");
    assert_eq!(models[0]["size"].as_u64(), Some(written.len() as u64));
    assert_eq!(models[0]["hash"].as_str(), Some(btfrig_store::content_hash(&written).as_str()));
    // A model file that reads back.
    let info = ok(btfrig().args(["dataset", "info"]).arg(&model));
    assert!(info.contains("fmf") && info.contains("texels"), "{info}");

    let third = run_plan(&plan, &out, &["--compress", "fmf"]);
    let all = text(&third);
    assert!(third.status.success() && all.contains("built and journaled earlier"), "{all}");
    assert!(!dir.join("run.fmf-2.btfm").exists(), "a second model was built:\n{all}");
    assert_eq!(read_journal(&out).models.len(), 1);
    ok(btfrig().args(["dataset", "verify"]).arg(&out));
}

/// r24 item 7: editing a sampling angle or the seed in `manifest.json` passed `verify` and
/// resume. Both now refuse, naming the manifest; the original passes again.
#[test]
fn r24_an_edited_manifest_is_refused_by_verify_and_resume() {
    let dir = scratch("manifest-edit");
    let plan = tiny_plan(&dir);
    let out = dir.join("run");
    assert!(run_plan(&plan, &out, &[]).status.success());
    let path = out.join("manifest.json");
    let original = std::fs::read_to_string(&path).unwrap();
    let angle = original.find("\"theta_deg\": ").expect("a sampling angle") + "\"theta_deg\": ".len();
    let seed = original.find("\"seed\": 7").expect("the seed");
    let edits = [
        ("a sampling angle", format!("{}9{}", &original[..angle], &original[angle + 1..])),
        ("the seed", format!("{}\"seed\": 8{}", &original[..seed], &original[seed + "\"seed\": 7".len()..])),
    ];
    for (what, edited) in edits {
        assert_ne!(edited, original);
        std::fs::write(&path, &edited).unwrap();
        let v = run(btfrig().args(["dataset", "verify"]).arg(&out));
        let all = text(&v);
        assert!(
            !v.status.success() && all.contains("manifest.json: changed since the dataset was created"),
            "{what}: {all}"
        );
        let r = run_plan(&plan, &out, &[]);
        let all = text(&r);
        assert_eq!(r.status.code(), Some(1), "{what}: {all}");
        assert!(all.contains("manifest.json: changed since the dataset was created"), "{what}: {all}");
        assert!(!all.contains("nothing to do"), "{what}: {all}");
    }
    std::fs::write(&path, &original).unwrap();
    ok(btfrig().args(["dataset", "verify"]).arg(&out));
    assert!(String::from_utf8_lossy(&run_plan(&plan, &out, &[]).stdout).contains("nothing to do"));
}

/// r24 item 7: a broken manifest gave "holds another dataset (plan ?, ...)". Now the message
/// names manifest.json and the line where it breaks.
#[test]
fn r24_a_broken_manifest_is_named_with_its_line() {
    let dir = scratch("manifest-broken");
    let plan = tiny_plan(&dir);
    let out = dir.join("run");
    assert!(run_plan(&plan, &out, &[]).status.success());
    let path = out.join("manifest.json");
    let original = std::fs::read_to_string(&path).unwrap();
    // Line 2 loses its comma: the parser stops at line 3.
    let mut lines: Vec<&str> = original.lines().collect();
    assert!(lines[1].ends_with(','), "{}", lines[1]);
    lines[1] = lines[1].trim_end_matches(',');
    std::fs::write(&path, lines.join("\n")).unwrap();
    let r = run_plan(&plan, &out, &[]);
    let all = text(&r);
    assert_eq!(r.status.code(), Some(1), "{all}");
    assert!(all.contains(&format!("{}: bad manifest: does not parse as JSON", path.display())), "{all}");
    assert!(all.contains("at line 3 column"), "{all}");
    assert!(!all.contains("another dataset"), "{all}");
}

/// `btfrig dataset verify DIR`, its stdout a pipe whose reader is gone before it writes: the
/// write end of `true`'s stdin, taken after `true` exited (its read end then closed).
fn verify_into_closed_pipe(dir: &Path) -> Output {
    let mut reader = Command::new("true").stdin(std::process::Stdio::piped()).spawn().expect("true runs");
    let writer = reader.stdin.take().unwrap();
    reader.wait().unwrap();
    btfrig().args(["dataset", "verify"]).arg(dir).stdout(writer).output().expect("btfrig runs")
}

/// r24 item 7: `btfrig dataset verify DIR | head -1` exited 101 with a panic message. Now a
/// closed pipe ends it quietly, the exit code still the verdict (0 sound, 1 problems).
#[test]
fn r24_verify_on_a_closed_pipe_exits_quietly() {
    let dir = scratch("pipe");
    let plan = tiny_plan(&dir);
    let out = dir.join("run");
    assert!(run_plan(&plan, &out, &[]).status.success());
    let o = verify_into_closed_pipe(&out);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(o.stderr.is_empty(), "{}", text(&o));
    let first = journaled_textures(&out).remove(0).0;
    std::fs::remove_file(out.join(first)).unwrap();
    let o = verify_into_closed_pipe(&out);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(o.stderr.is_empty(), "{}", text(&o));
}

/// r24 item 4 on a dome: a deleted texture of a finished dome dataset is named on resume and
/// its view group is captured again (only the missing texture is written); the dataset
/// verifies and the report counts every texture.
#[test]
fn r24_a_damaged_dome_texture_is_named_and_its_view_group_captured_again() {
    let dir = scratch("dome");
    let plan = dir.join("dome.toml");
    std::fs::write(
        &plan,
        "name = \"r24-dome\"\ntexture_size = 8\n[rig]\nconfig = \"builtin:bonn-dome-sim\"\nmaterial = \"leather\"\n\
         [dome]\ncameras = [4]\nrotations = [1]\n",
    )
    .unwrap();
    let out = dir.join("run");
    let first = run_plan(&plan, &out, &[]);
    assert!(first.status.success(), "{}", text(&first));
    let textures = journaled_textures(&out);
    assert_eq!(textures.len(), 198);
    let gone = &textures[100].0;
    std::fs::remove_file(out.join(gone)).unwrap();

    let again = run_plan(&plan, &out, &[]);
    let all = text(&again);
    assert!(again.status.success(), "{all}");
    assert!(all.contains(&format!("{gone}: missing: step")) && all.contains("is captured again"), "{all}");
    assert!(all.contains("textures          1 "), "{all}");
    ok(btfrig().args(["dataset", "verify"]).arg(&out));
    let report = read_json(&out.join("report.json"));
    assert_eq!((report["status"].as_str(), report["captures"].as_u64()), (Some("finished"), Some(198)), "{report}");
    assert_eq!(read_journal(&out).retakes.len(), 1);
}
