//! Prints the simulated colour chart's patches as CIE L*a*b* (D50) CSV: the "measured
//! reference file" of the simulated rig's chart, as a lab measures its own chart with a
//! spectrophotometer (`btfrig calibrate color --reference CHART=FILE`). The simulator's
//! patch spectra are synthesised from the published values and differ from them; fitting
//! the simulated rig's colour model to the published values instead tripled the demo's
//! texture error (0.058 to 0.177).
//!
//! usage: cargo run --release -p btfrig-sim-calibration --example sim_chart_lab -- RIG CHART

use btfrig_calibrate::color::ColorPlan;
use btfrig_color::space::{bradford, d65_white, linear_srgb_to_xyz, mat3_apply, xyz_to_lab};
use btfrig_core::config::RigConfig;
use btfrig_sim_calibration::color::SimChartCamera;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, rig, chart] = &args[..] else {
        eprintln!("usage: sim_chart_lab RIG_CONFIG CHART");
        std::process::exit(2);
    };
    let cfg = RigConfig::from_toml(&std::fs::read_to_string(rig).expect("readable rig config"), rig).expect("valid");
    let plan = ColorPlan::default_plan();
    let index = plan.charts.iter().position(|c| &c.name == chart).expect("a chart of the default colour plan");
    let refs = SimChartCamera::new(&cfg, &plan, cfg.rig.seed).expect("the simulated charts").references(&plan).unwrap();
    // ICC D50, as the published data and `ReferenceValues::linear_srgb`.
    let d50 = [0.9642, 1.0, 0.8249];
    let to_d50 = bradford(d65_white(), d50);
    println!("# {chart}: the simulated chart's patch spectra under the lamp of {}, CIE L*a*b* (D50)", cfg.rig.name);
    println!("# made by: cargo run --release -p btfrig-sim-calibration --example sim_chart_lab -- {rig} {chart}");
    println!("L,a,b");
    for rgb in &refs.patches[index] {
        let lab = xyz_to_lab(mat3_apply(&to_d50, linear_srgb_to_xyz(*rgb)), d50);
        println!("{:.6},{:.6},{:.6}", lab[0], lab[1], lab[2]);
    }
}
