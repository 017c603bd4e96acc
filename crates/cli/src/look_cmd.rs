//! `btfrig dataset render` (btfrig's own evaluation of a dataset's compressed model at a
//! (light, view) pair, as PNG or EXR) and `btfrig dataset report` (the coverage plot and the
//! dataset's figures as one self-contained HTML file). The work is `btfrig_daemon::look`'s,
//! which the daemon's API and viewer use too.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;

/// `btfrig dataset render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// The dataset directory (its models are `<DIR>.<method>.btfm` beside it).
    pub dir: PathBuf,
    /// The model: a `<method>` beside the dataset (`fmf`) or a `.btfm` file (default: the one
    /// model beside the dataset).
    #[arg(long)]
    pub model: Option<String>,
    /// Light direction `THETA,PHI` in degrees (theta 0 to 90).
    #[arg(long, value_parser = parse_pair)]
    pub light: [f64; 2],
    /// View direction `THETA,PHI` in degrees (theta 0 to 90).
    #[arg(long, value_parser = parse_pair)]
    pub view: [f64; 2],
    /// Output file: `.png` (8-bit sRGB at --scale) or `.exr` (linear float RGB).
    #[arg(long)]
    pub out: PathBuf,
    /// PNG: linear values times this before the sRGB curve (default: the model's display
    /// scale, as the viewer starts with).
    #[arg(long)]
    pub scale: Option<f32>,
    /// Replace an existing file.
    #[arg(long)]
    pub overwrite: bool,
}

fn parse_pair(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<&str> = s.split(',').collect();
    let bad = || format!("{s:?}: give THETA,PHI in degrees, e.g. 30,90");
    match v.as_slice() {
        [t, p] => Ok([t.trim().parse().map_err(|_| bad())?, p.trim().parse().map_err(|_| bad())?]),
        _ => Err(bad()),
    }
}

/// The model file `--model` names for dataset `dir`.
fn model_path(dir: &Path, model: Option<&str>) -> anyhow::Result<PathBuf> {
    match model {
        Some(m) if m.ends_with(&format!(".{}", btfrig_compress::file::EXTENSION)) => Ok(PathBuf::from(m)),
        Some(m) => {
            btfrig_daemon::look::check_model_name(m).map_err(anyhow::Error::msg)?;
            let name = dir.file_name().context("the dataset directory has no name")?.to_string_lossy();
            let parent = dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
            let f = btfrig_daemon::look::model_file(parent, &name, m);
            anyhow::ensure!(
                f.is_file(),
                "--model {m}: no {} (models beside the dataset: {:?})",
                f.display(),
                btfrig_daemon::look::models_of(parent, &name)
            );
            Ok(f)
        }
        None => match crate::compress_cmd::models_next_to(dir).as_slice() {
            [one] => Ok(one.clone()),
            [] => anyhow::bail!(
                "no model beside {}: build one with `btfrig compress {}`, or give --model FILE.btfm",
                dir.display(),
                dir.display()
            ),
            many => anyhow::bail!(
                "several models beside {}: {}; choose one with --model",
                dir.display(),
                many.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
            ),
        },
    }
}

/// Renders the model at the pair into `--out`.
pub fn render(a: &RenderArgs) -> anyhow::Result<()> {
    let exr = match a.out.extension().and_then(|e| e.to_str()) {
        Some("png") => false,
        Some("exr") => true,
        _ => anyhow::bail!("--out {}: allowed a .png or .exr file", a.out.display()),
    };
    if a.out.exists() && !a.overwrite {
        anyhow::bail!("{} already exists: refusing to overwrite it (--overwrite to replace)", a.out.display());
    }
    if let Some(s) = a.scale {
        anyhow::ensure!(s.is_finite() && s > 0.0, "--scale {s}: allowed a finite number above 0");
    }
    let (light, view) = btfrig_daemon::look::pair_from_degrees(a.light, a.view).map_err(anyhow::Error::msg)?;
    let file = model_path(&a.dir, a.model.as_deref())?;
    let model = btfrig_compress::file::read(&file)?;
    let bytes = btfrig_daemon::look::render_file(&model, light, view, a.scale, exr).map_err(anyhow::Error::msg)?;
    std::fs::write(&a.out, bytes).with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "rendered {} ({} x {}) at light {:?}, view {:?} deg -> {}",
        file.display(),
        model.layout.width,
        model.layout.height,
        a.light,
        a.view,
        a.out.display()
    );
    Ok(())
}

/// `btfrig dataset report`.
#[derive(Debug, Args)]
pub struct ReportArgs {
    /// The dataset directory.
    pub dir: PathBuf,
    /// The HTML file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an existing file.
    #[arg(long)]
    pub overwrite: bool,
}

/// Writes the dataset's report page.
pub fn report(a: &ReportArgs) -> anyhow::Result<()> {
    if a.out.exists() && !a.overwrite {
        anyhow::bail!("{} already exists: refusing to overwrite it (--overwrite to replace)", a.out.display());
    }
    let html = btfrig_daemon::look::report_html(&a.dir).map_err(anyhow::Error::msg)?;
    std::fs::write(&a.out, html).with_context(|| format!("writing {}", a.out.display()))?;
    println!("report of {} -> {}", a.dir.display(), a.out.display());
    Ok(())
}
