//! `btfrig dataset info DIR` and `btfrig dataset verify DIR`.

use std::path::Path;

/// Prints what a dataset holds, and the compressed models next to it; or what a model file
/// (`.btfm`) holds.
pub fn info(dir: &Path) -> anyhow::Result<()> {
    if dir.is_file() {
        println!("{}", crate::compress_cmd::describe(dir)?);
        return Ok(());
    }
    print!("{}", btfrig_store::info(dir)?);
    for m in crate::compress_cmd::models_next_to(dir) {
        println!();
        match crate::compress_cmd::describe(&m) {
            Ok(s) => print!("{s}"),
            Err(e) => print!("model     {}: unreadable: {e}", m.display()),
        }
    }
    println!();
    Ok(())
}

/// Checks every journaled file's size and hash, completeness and orphans; fails when
/// anything is wrong.
pub fn verify(dir: &Path) -> anyhow::Result<()> {
    let report = btfrig_store::verify(dir);
    print!("{report}");
    anyhow::ensure!(
        report.is_ok(),
        "{}: dataset verification found {} problem(s)",
        dir.display(),
        report.problems.len()
    );
    Ok(())
}
