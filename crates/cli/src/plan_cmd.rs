//! `btfrig plan check FILE` and `btfrig plan show FILE`.

use std::path::Path;

use btfrig_measurement::dome_dry_run::{self, is_dome_plan};
use btfrig_measurement::plan::load;

fn read(file: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(file).map_err(|e| anyhow::anyhow!("cannot read {}: {e}", file.display()))
}

/// `btfrig plan check`: every problem at once, or a one-paragraph summary. A dome plan (one
/// with a `[dome]` table, docs/plan-format.md) is checked against its dome rig.
pub fn check(file: &Path) -> anyhow::Result<()> {
    let text = read(file)?;
    if is_dome_plan(&text) {
        dome_dry_run::check_lines(&text, file)?.iter().for_each(|l| println!("{l}"));
        return Ok(());
    }
    let (_, v) = load(file)?;
    let list = v.capture_list();
    println!("{}: valid plan {:?} (hash {:016x})", file.display(), v.name, v.plan_hash);
    println!(
        "rig {} ({}), {} light x {} view directions, {} requested pairs, {} captures, {} skipped",
        v.rig.rig.name,
        v.rig_source,
        v.light.len(),
        v.view.len(),
        v.pairs.len(),
        list.captures.len(),
        list.skipped.len()
    );
    let f = crate::texel_footprint::TexelFootprint::of(&v.rig, &v.texture);
    println!(
        "texture {} x {} texels of {:.3} mm; the camera sees {:.3} mm of the sample per photosite at the normal view ({:.2} photosites per texel){}",
        v.texture.size,
        v.texture.size,
        f.texel_m * 1e3,
        f.photosite_m * 1e3,
        f.photosites_per_texel(),
        if f.resolved() { "" } else { ": finer than the camera resolves, the texels are interpolation (fewer texels, a larger region or a finer camera)" }
    );
    Ok(())
}

/// `btfrig plan show`: the dry run — captures, skips by reason, estimated hardware time in
/// the motion-optimised order against the naive order and the lower bound, disk space.
/// A dome plan's dry run is the noise model's choice with every candidate, frames, estimated
/// rig time, disk and memory ([`dome_dry_run`]).
pub fn show(file: &Path) -> anyhow::Result<()> {
    let text = read(file)?;
    if is_dome_plan(&text) {
        dome_dry_run::dry_run(&text, file)?.lines(file).iter().for_each(|l| println!("{l}"));
        return Ok(());
    }
    let d = btfrig_measurement::dry_run::dry_run(&text, file)?;
    println!("plan {:?} from {} (hash {:016x})", d.name, file.display(), d.plan_hash);
    println!(
        "rig {}, exposure {:.4} s per capture, {} bytes transferred per frame",
        d.rig, d.exposure_s, d.frame_bytes
    );
    for (reason, n) in &d.plan_skips {
        println!("skipped by the plan: {n} ({reason})");
    }
    println!("{}", d.schedule);
    if let Some(line) = &d.hdr {
        println!("{line}");
    }
    println!("planning took {:.2} s", d.planning_s);
    Ok(())
}
