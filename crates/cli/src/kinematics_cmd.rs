//! `btfrig kinematics check`.

use btfrig_core::kinematics::Gonio;
use btfrig_core::sampling::Sampling;

/// Classifies every Bonn 81 x 81 pair, checks FK(IK(pair)) for the reachable ones, prints
/// counts per reason and the worst round-trip error.
pub fn check(rig: Option<&std::path::Path>, json: bool) -> anyhow::Result<()> {
    let cfg = super::rig::load(rig)?;
    cfg.require_gonio("kinematics check")?;
    let gonio = Gonio::new(cfg.geometry.clone())?;
    let bonn = Sampling::bonn81();
    let started = std::time::Instant::now();
    let report = gonio.report(&bonn, &bonn);
    let mut worst = 0.0_f64;
    for &l in bonn.directions() {
        for &v in bonn.directions() {
            if let Ok(j) = gonio.ik(l, v) {
                let (l2, v2) = gonio.fk(&j);
                worst = worst.max(l.angle_to(l2)).max(v.angle_to(v2));
            }
        }
    }
    let elapsed = started.elapsed().as_secs_f64();
    if json {
        let reasons: serde_json::Map<String, serde_json::Value> =
            report.unreachable.iter().map(|(k, n)| (k.label().to_string(), (*n).into())).collect();
        let out = serde_json::json!({
            "rig": cfg.rig.name,
            "pairs": report.total,
            "reachable": report.reachable,
            "unreachable": reasons,
            "max_roundtrip_error_rad": worst,
            "seconds": elapsed,
        });
        println!("{out}");
    } else {
        println!("rig {}", cfg.rig.name);
        print!("{report}");
        println!("max FK(IK(pair)) error over reachable pairs: {worst:.3e} rad (limit 1e-9)");
        println!("time: {:.3} s for IK + FK of all pairs", elapsed);
    }
    anyhow::ensure!(worst < 1e-9, "FK(IK(pair)) error {worst:e} rad exceeds 1e-9 rad");
    anyhow::ensure!(
        report.reachable + report.unreachable.iter().map(|(_, n)| n).sum::<usize>() == report.total,
        "every pair must be either reachable or unreachable with a reason"
    );
    Ok(())
}
