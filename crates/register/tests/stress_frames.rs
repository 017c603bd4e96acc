//! Registration on RENDERED frames through the detector (issue 4 acceptance): all 81 Bonn
//! views on two materials, and the stress cases. Run with
//! `cargo test --release -p btfrig-register --test stress_frames -- --nocapture` to see the figures.

mod common;
mod frames_common;

use btfrig_core::Direction;
use frames_common::{print_view, summarise, Bench, Outcome};
use rayon::prelude::*;

fn no_edit(_: &frames_common::Shot, _: &mut frames_common::Frame) {}

#[test]
fn all_81_bonn_views_on_two_materials() {
    let t0 = std::time::Instant::now();
    let views = common::bonn_views();
    let mut all: Vec<Outcome> = Vec::new();
    for material in ["lacquered-wood", "corduroy"] {
        let bench = Bench::new(material);
        let outcomes: Vec<Outcome> = views
            .par_iter()
            .enumerate()
            .map(|(k, v)| bench.run(*v, 1.0, 4000 + k as u64, &no_edit))
            .collect();
        for o in &outcomes {
            print_view(material, o);
        }
        summarise(&format!("bonn81 {material}"), &outcomes);
        all.extend(outcomes);
    }
    let s = summarise("bonn81 both materials", &all);
    println!("total {:.1} s", t0.elapsed().as_secs_f64());
    let _ = (s, Direction::from_degrees(0.0, 0.0));
}
