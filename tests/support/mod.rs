//! Shared helpers of the tests that run the real `btfrig` binary on whole plans: scratch
//! directories, running commands, and an independent reader of a dataset's journal and
//! manifest (`docs/dataset-format.md`), so the tests check the files, not the store's own view.

#![allow(dead_code)] // each test binary uses a part

pub mod http;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn btfrig() -> Command {
    Command::new(env!("CARGO_BIN_EXE_btfrig"))
}

/// A file of the repository, from the cli crate's manifest directory.
pub fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

/// A fresh, empty directory for one test.
pub fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

pub fn text(o: &Output) -> String {
    // Progress lines are rewritten with '\r': keep only the last state of each.
    let err = String::from_utf8_lossy(&o.stderr);
    let err: Vec<&str> = err.lines().map(|l| l.rsplit('\r').next().unwrap_or(l)).collect();
    format!("status {:?}\n--- stdout\n{}--- stderr\n{}", o.status, String::from_utf8_lossy(&o.stdout), err.join("\n"))
}

/// Runs a command that must succeed, returns its stdout.
pub fn ok(cmd: &mut Command) -> String {
    let o = cmd.output().expect("btfrig runs");
    assert!(o.status.success(), "{}", text(&o));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A step id `(light, view)`.
pub type Step = (u64, u64);

/// What the journal of a dataset says, read line by line as the format describes.
#[derive(Debug, Default)]
pub struct Journal {
    /// Step records in journal order: the step and its files `(path, hash)`.
    pub steps: Vec<(Step, Vec<(String, String)>)>,
    /// Skip records: the step and its reason.
    pub skips: Vec<(Step, String)>,
    /// Retake records (a done step found damaged on resume, to be captured again): the step
    /// and what was found.
    pub retakes: Vec<(Step, String)>,
    /// Model records (a compressed model the run built), as JSON.
    pub models: Vec<serde_json::Value>,
    /// A last record cut short (a killed writer); `None` if the journal ends cleanly.
    pub torn_tail: Option<String>,
}

impl Journal {
    /// Each committed step once with its files (the last record of a step retaken); panics
    /// naming a step committed twice without a retake between.
    pub fn committed(&self) -> BTreeMap<Step, Vec<(String, String)>> {
        let mut out = BTreeMap::new();
        let mut times: BTreeMap<Step, usize> = BTreeMap::new();
        for (step, files) in &self.steps {
            *times.entry(*step).or_default() += 1;
            out.insert(*step, files.clone());
        }
        for (step, n) in times {
            let retaken = self.retakes.iter().filter(|r| r.0 == step).count();
            assert!(n <= 1 + retaken, "step {step:?} journaled {n} times, retaken {retaken} times");
        }
        out
    }
}

fn step_of(v: &serde_json::Value) -> Step {
    (v["light"].as_u64().expect("step.light"), v["view"].as_u64().expect("step.view"))
}

/// Reads `DIR/journal.btfj`: `LLLLLLLL CCCCCCCCCCCCCCCC {json}\n` per record, the length
/// checked. Only the last record may be incomplete (a kill during the append).
pub fn read_journal(dir: &Path) -> Journal {
    let bytes = std::fs::read(dir.join("journal.btfj")).expect("journal.btfj");
    let mut j = Journal::default();
    let mut rest = &bytes[..];
    let mut first = true;
    while !rest.is_empty() {
        let parsed = (|| {
            let len = usize::from_str_radix(std::str::from_utf8(rest.get(..8)?).ok()?, 16).ok()?;
            let body = rest.get(26..26 + len)?;
            (rest.get(8) == Some(&b' ') && rest.get(25) == Some(&b' ') && rest.get(26 + len) == Some(&b'\n'))
                .then_some(())?;
            let v: serde_json::Value = serde_json::from_slice(body).ok()?;
            Some((v, 27 + len))
        })();
        let Some((v, used)) = parsed else {
            j.torn_tail = Some(String::from_utf8_lossy(rest).into_owned());
            break;
        };
        rest = &rest[used..];
        // The header is the first record, and only there.
        assert_eq!(v["type"] == "header", first, "header out of place: {v}");
        first = false;
        match v["type"].as_str() {
            Some("header") => {}
            Some("step") => {
                let files = v["files"]
                    .as_array()
                    .expect("files")
                    .iter()
                    .map(|f| (f["path"].as_str().unwrap().to_string(), f["hash"].as_str().unwrap().to_string()))
                    .collect();
                j.steps.push((step_of(&v["step"]), files));
            }
            Some("skip") => j.skips.push((step_of(&v["step"]), v["reason"].as_str().unwrap_or("").to_string())),
            Some("retake") => j.retakes.push((step_of(&v["step"]), v["reason"].as_str().unwrap_or("").to_string())),
            Some("model") => j.models.push(v),
            other => panic!("unknown journal record type {other:?}"),
        }
    }
    j
}

/// Number of complete step records (0 if there is no journal yet).
pub fn journaled_steps(dir: &Path) -> usize {
    if dir.join("journal.btfj").is_file() {
        read_journal(dir).steps.len()
    } else {
        0
    }
}

pub fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The manifest's skipped pairs with their reasons.
pub fn manifest_skipped(dir: &Path) -> BTreeMap<Step, String> {
    let m = read_json(&dir.join("manifest.json"));
    m["samplings"]["skipped"]
        .as_array()
        .expect("samplings.skipped")
        .iter()
        .map(|s| (step_of(&s["step"]), s["reason"].as_str().unwrap().to_string()))
        .collect()
}

/// `btfrig dataset verify DIR` must pass.
pub fn verify(dir: &Path) {
    ok(btfrig().args(["dataset", "verify"]).arg(dir));
}
