//! `btfrig reprocess DATASET --out NEW [--calibration DIR]`: argument handling and display;
//! the work is `btfrig_measurement::reprocess` (a dome dataset's: `btfrig_measurement::dome_reprocess`).

use std::path::PathBuf;

use clap::Args;

/// `btfrig reprocess`.
#[derive(Debug, Args)]
pub struct ReprocessArgs {
    /// A dataset whose plan kept its raw frames (`[outputs] raw_frames = true`): a
    /// gonioreflectometer's per-step frames, or a dome's or camera array's pattern frames per
    /// view group, demultiplexed again; read only.
    pub dataset: PathBuf,
    /// The new dataset directory (created; refused if it exists and is not empty).
    #[arg(long)]
    pub out: PathBuf,
    /// Calibration files that replace the ones the dataset's rig config names, by file name:
    /// `builtin:NAME` or `some/dir/NAME.toml` is looked up as `DIR/NAME.toml` for `[camera]
    /// calibration`, `[camera] color_calibration`, `[lamp] calibration` and `[dome]
    /// led_calibration`; a dark/flat
    /// calibration as `DIR/dark-flat/`. Names the directory lacks keep the dataset's own.
    /// Without it: the dataset's own calibrations.
    #[arg(long, value_name = "DIR")]
    pub calibration: Option<PathBuf>,
}

/// Runs `btfrig reprocess`.
pub fn run(a: &ReprocessArgs) -> anyhow::Result<()> {
    let req = btfrig_measurement::reprocess::ReprocessRequest {
        dataset: a.dataset.clone(),
        out: a.out.clone(),
        calibration: a.calibration.clone(),
    };
    let s = btfrig_measurement::reprocess::reprocess(&req)?;
    let stages: Vec<String> = s.stage_s.iter().map(|(k, v)| format!("{k} {v:.2} s")).collect();
    println!(
        "{}: {} steps reprocessed from {} ({} registered, {} nominal fallbacks, {} nominal by plan); wall {:.1} s; stages: {}",
        s.out.display(),
        s.steps,
        a.dataset.display(),
        s.registered,
        s.fallbacks,
        s.nominal_by_plan,
        s.wall_s,
        stages.join(", ")
    );
    for (part, source) in &s.processing.sources {
        println!("  {part}: {source}");
    }
    for note in &s.processing.notes {
        println!("  note: {note}");
    }
    Ok(())
}
