//! `btfrig dataset info DIR` and `btfrig dataset verify DIR`.

use std::path::Path;

/// Prints what a dataset holds.
pub fn info(dir: &Path) -> anyhow::Result<()> {
    print!("{}", btfrig_store::info(dir)?);
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
