//! `btfrig dataset info DIR`, `btfrig dataset verify DIR` and `btfrig dataset export-recording`.
//!
//! They write through [`out`], which returns write errors instead of panicking as `print!`
//! does: `btfrig dataset verify DIR | head -1` then ends quietly (a closed pipe is
//! [`is_broken_pipe`], exit 0, as ripgrep does).

use std::io::Write;
use std::path::Path;

/// Writes `text` to stdout, returning (not panicking on) a write error such as a closed pipe.
fn out(text: &str) -> anyhow::Result<()> {
    let mut o = std::io::stdout().lock();
    o.write_all(text.as_bytes())?;
    o.flush()?;
    Ok(())
}

/// True if `e` is, or is caused by, a write to a closed pipe (the reader left: not an error).
pub fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| c.downcast_ref::<std::io::Error>().is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe))
}

/// Prints what a dataset holds, and the compressed models next to it; or what a model file
/// (`.btfm`) holds.
pub fn info(dir: &Path) -> anyhow::Result<()> {
    if dir.is_file() {
        return out(&format!("{}\n", crate::compress_cmd::describe(dir)?));
    }
    let mut text = btfrig_store::info(dir)?.to_string();
    for m in crate::compress_cmd::models_next_to(dir) {
        text.push('\n');
        match crate::compress_cmd::describe(&m) {
            Ok(s) => text.push_str(&s),
            Err(e) => text.push_str(&format!("model     {}: unreadable: {e}", m.display())),
        }
    }
    text.push('\n');
    out(&text)
}

/// Checks every journaled file's size and hash, completeness and orphans; fails when
/// anything is wrong. A closed stdout (`| head -1`) ends it quietly, with the verdict as the
/// exit code (0 sound, 1 problems found).
pub fn verify(dir: &Path) -> anyhow::Result<std::process::ExitCode> {
    let report = btfrig_store::verify(dir);
    match out(&format!("{report}\n")) {
        Err(e) if is_broken_pipe(&e) => {
            return Ok(if report.is_ok() { std::process::ExitCode::SUCCESS } else { std::process::ExitCode::FAILURE })
        }
        r => r?,
    }
    anyhow::ensure!(
        report.is_ok(),
        "{}: dataset verification found {} problem(s)",
        dir.display(),
        report.problems.len()
    );
    Ok(std::process::ExitCode::SUCCESS)
}

/// `btfrig dataset export-recording DIR --out RECDIR`: the raw frames a gonio dataset kept, as
/// a recording that `btfrig run --rig RECDIR/rig.toml` replays (docs/recorded-camera.md).
pub fn export_recording(dir: &Path, recording: &Path, format: &str) -> anyhow::Result<()> {
    let format = btfrig_recorded::format::ExportFormat::parse(format).map_err(|e| anyhow::anyhow!("--format: {e}"))?;
    let s = btfrig_recorded::export::export_recording(dir, recording, format)?;
    let mut text = format!(
        "recording {}: {} frames of {} captures ({} files), sidecar {}\nreplay it: btfrig run --plan PLAN --rig {} --out DIR\n",
        s.out.display(),
        s.frames,
        s.captures,
        format.extension(),
        s.out.join(btfrig_recorded::SIDECAR_FILE).display(),
        s.rig_file.display()
    );
    for n in &s.notes {
        text.push_str(&format!("note: {n}\n"));
    }
    out(&text)
}
