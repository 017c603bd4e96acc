//! `btfrig hw probe --recorded DIR`: what a recording holds and the problems found in it.

use std::collections::BTreeMap;
use std::path::Path;

use crate::Recording;

/// Lines describing the recording in `dir`: frame count, size, formats, bit depth and
/// layout, exposure and gain ranges, what the sidecar says; or every problem found. The
/// flag is whether the recording is usable.
pub fn describe(dir: &Path) -> (bool, Vec<String>) {
    let rec = match Recording::open(dir) {
        Ok(r) => r,
        Err(e) => {
            let mut lines = vec![format!("recording {}: NOT USABLE", dir.display())];
            lines.extend(e.to_string().lines().map(|l| format!("  {}", l.trim_start())));
            return (false, lines);
        }
    };
    let c = &rec.sidecar.camera;
    let mut formats: BTreeMap<&str, usize> = BTreeMap::new();
    for f in &rec.frames {
        *formats.entry(f.format.name()).or_default() += 1;
    }
    let range = |v: &mut dyn Iterator<Item = f64>| {
        v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)))
    };
    let (emin, emax) = range(&mut rec.frames.iter().map(|f| f.entry.exposure_s));
    let (gmin, gmax) = range(&mut rec.frames.iter().map(|f| f.entry.gain));
    let by_joints = rec.frames.iter().filter(|f| f.joints.is_some()).count();
    let formats: Vec<String> = formats.iter().map(|(k, n)| format!("{k} x{n}")).collect();
    let lines = vec![
        format!("recording {}: usable", dir.display()),
        format!("  frames    {} ({})", rec.frames.len(), formats.join(", ")),
        format!(
            "  size      {}x{}, {}-bit, black {} white {} DN, layout {}",
            c.width, c.height, c.bit_depth, c.black_level, c.white_level, c.bayer
        ),
        format!("  exposure  {emin} .. {emax} s recorded (camera allowed {} .. {} s)", c.exposure_range_s[0], c.exposure_range_s[1]),
        format!("  gain      {gmin} .. {gmax} recorded (camera allowed {} .. {})", c.gain_range[0], c.gain_range[1]),
        format!(
            "  poses     {by_joints} by joints, {} by light and view directions only (resolved by the rig's inverse kinematics)",
            rec.frames.len() - by_joints
        ),
        format!(
            "  camera    {}; sidecar: {}",
            c.model.as_deref().unwrap_or("not named"),
            rec.sidecar.recording.description.as_deref().unwrap_or("no description")
        ),
    ];
    (true, lines)
}
