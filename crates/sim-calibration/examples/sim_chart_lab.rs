//! Prints the simulated colour chart's patches as CIE L*a*b* (D50) CSV: the "measured
//! reference file" of the simulated rig's chart, as a lab measures its own chart with a
//! spectrophotometer (`btfrig calibrate color --reference CHART=FILE`). The simulator's
//! patch spectra are synthesised from the published values and differ from them; fitting
//! the simulated rig's colour model to the published values instead tripled the demo's
//! texture error (0.058 to 0.177). The CSV is `btfrig_sim_calibration::color::chart_lab_csv`
//! (`tests/color_calibration.rs` recomputes the shipped ones).
//!
//! usage: cargo run --release -p btfrig-sim-calibration --example sim_chart_lab -- RIG CHART

use btfrig_core::config::RigConfig;
use btfrig_sim_calibration::color::chart_lab_csv;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, rig, chart] = &args[..] else {
        eprintln!("usage: sim_chart_lab RIG_CONFIG CHART");
        std::process::exit(2);
    };
    let cfg = RigConfig::from_toml(&std::fs::read_to_string(rig).expect("readable rig config"), rig).expect("valid");
    match chart_lab_csv(&cfg, rig, chart) {
        Ok(csv) => print!("{csv}"),
        Err(e) => {
            eprintln!("sim_chart_lab: {e}");
            std::process::exit(1);
        }
    }
}
