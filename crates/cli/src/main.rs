//! The `btfrig` binary: argument handling and display only; the work is in the library crates.

// The files, one job each (one command, or one family, per `*_cmd.rs`):
// - args: the command line as clap parses it; rig, material: --rig and --material made valid settings
// - demo_cmd, run_cmd, serve_cmd, reprocess_cmd: runs through btfrig-measurement and btfrig-daemon
// - plan_cmd, dataset_cmd, compress_cmd (compress, sparse, dataset export): plans, datasets, models
// - calibrate_cmd (geometry), calibrate_{rig_geometry,color,radiometric,light,leds,sensor}_cmd: the calibrations
// - hw_cmd: btfrig hw probe; kinematics_cmd: btfrig kinematics check
// - sim_cmd, captures_cmd, session: btfrig sim ... on a simulated gonio session
// - model_cmd: btfrig model ... and btfrig bench model (btfrig-model)
// - bench_cmd, bench_{color,compress,demux,pipeline,serve}: btfrig bench ... (harnesses in btfrig-bench)

mod args;
mod backends;
mod bench_cmd;
mod bench_color;
mod bench_compress;
mod bench_demux;
mod bench_pipeline;
mod bench_serve;
mod calibrate_cmd;
mod calibrate_color_cmd;
mod calibrate_leds_cmd;
mod calibrate_light_cmd;
mod calibrate_radiometric_cmd;
mod calibrate_rig_geometry_cmd;
mod calibrate_sensor_cmd;
mod captures_cmd;
mod compress_cmd;
mod dataset_cmd;
mod demo_cmd;
mod hw_cmd;
mod kinematics_cmd;
mod look_cmd;
mod material;
mod model_cmd;
mod plan_cmd;
mod reprocess_cmd;
mod rig;
mod run_cmd;
mod serve_cmd;
mod session;
mod sim_cmd;
mod texel_footprint;

use args::{BenchCommand, CalibrateCommand, Cli, Command, DatasetCommand, KinematicsCommand, PlanCommand, SimCommand};
use clap::Parser;

// Frames of several MB are made and freed on different threads (render, PTP responder,
// pipeline): glibc's per-thread arenas then hold on to freed memory (peak RSS 786 MiB for
// the serial demo against 186 MiB with two arenas). mimalloc returns it.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> std::process::ExitCode {
    // The device backends every run of this binary opens rigs with (`btfrig_measurement::backend`).
    backends::install();
    let cli = Cli::parse();
    let done = |r: anyhow::Result<()>| r.map(|()| std::process::ExitCode::SUCCESS);
    let result = match cli.command {
        Command::Kinematics(KinematicsCommand::Check { rig, json }) => {
            done(kinematics_cmd::check(rig.as_deref(), json))
        }
        Command::Demo(a) => demo_cmd::run(&a),
        Command::Run(a) => run_cmd::run(&a),
        Command::Sim(SimCommand::Render(a)) => done(sim_cmd::render(&a)),
        Command::Sim(SimCommand::Materials) => done(sim_cmd::materials()),
        Command::Sim(SimCommand::Captures(a)) => done(captures_cmd::run(&a)),
        Command::Plan(PlanCommand::Check { file }) => done(plan_cmd::check(&file)),
        Command::Plan(PlanCommand::Show { file }) => done(plan_cmd::show(&file)),
        Command::Dataset(DatasetCommand::Info { dir }) => done(dataset_cmd::info(&dir)),
        Command::Dataset(DatasetCommand::Verify { dir }) => dataset_cmd::verify(&dir),
        Command::Dataset(DatasetCommand::ExportRecording { dir, out, format }) => {
            done(dataset_cmd::export_recording(&dir, &out, &format))
        }
        Command::Dataset(DatasetCommand::Export(a)) => done(compress_cmd::export(&a)),
        Command::Dataset(DatasetCommand::Render(a)) => done(look_cmd::render(&a)),
        Command::Dataset(DatasetCommand::Report(a)) => done(look_cmd::report(&a)),
        Command::Compress(a) => done(compress_cmd::compress(&a)),
        Command::Model(model_cmd::ModelCommand::Ps(a)) => done(model_cmd::ps(&a)),
        Command::Model(model_cmd::ModelCommand::Lafortune(a)) => done(model_cmd::lafortune(&a)),
        Command::Model(model_cmd::ModelCommand::ScaledLafortune(a)) => done(model_cmd::scaled_lafortune(&a)),
        Command::Model(model_cmd::ModelCommand::Ptm(a)) => done(model_cmd::ptm(&a)),
        Command::Model(model_cmd::ModelCommand::Car(a)) => done(model_cmd::car::model_car(&a)),
        Command::Reprocess(a) => done(reprocess_cmd::run(&a)),
        Command::Sparse(args::SparseCommand::Select(a)) => done(compress_cmd::select(&a)),
        Command::Sparse(args::SparseCommand::Reconstruct(a)) => done(compress_cmd::reconstruct(&a)),
        Command::Serve(a) => done(serve_cmd::serve(&a)),
        Command::Hw(args::HwCommand::Probe { rig, recorded, genicam, discover }) => {
            hw_cmd::probe(rig.as_deref(), &recorded, &genicam, discover)
        }
        Command::Calibrate(CalibrateCommand::Geometry(a)) => done(calibrate_cmd::geometry(&a)),
        Command::Calibrate(CalibrateCommand::Color(a)) => done(calibrate_color_cmd::color(&a)),
        Command::Calibrate(CalibrateCommand::RigGeometry(a)) => done(calibrate_rig_geometry_cmd::rig_geometry(&a)),
        Command::Calibrate(CalibrateCommand::Radiometric(a)) => done(calibrate_radiometric_cmd::run(&a)),
        Command::Calibrate(CalibrateCommand::Light(a)) => done(calibrate_light_cmd::light(&a)),
        Command::Calibrate(CalibrateCommand::Leds(a)) => done(calibrate_leds_cmd::leds(&a)),
        Command::Calibrate(CalibrateCommand::Sensor(a)) => done(calibrate_sensor_cmd::sensor(&a)),
        Command::Bench(BenchCommand::Render { rig, material, texels, repeat }) => {
            done(bench_cmd::render(rig.as_deref(), &material, texels, repeat))
        }
        Command::Bench(BenchCommand::Registration(a)) => done(bench_cmd::registration(&a)),
        Command::Bench(BenchCommand::Pipeline(a)) => done(bench_pipeline::bench(&a)),
        Command::Bench(BenchCommand::Color(a)) => done(bench_color::bench(&a)),
        Command::Bench(BenchCommand::Demux(a)) => done(bench_demux::bench(&a)),
        Command::Bench(BenchCommand::Compress(a)) => done(bench_compress::bench(&a)),
        Command::Bench(BenchCommand::Model(a)) => done(model_cmd::bench(&a)),
        Command::Bench(BenchCommand::Serve(a)) => done(bench_serve::bench(&a)),
        Command::Bench(BenchCommand::ServeLoad(a)) => done(bench_serve::load(&a)),
    };
    match result {
        Ok(code) => code,
        // The reader of our output left (`btfrig dataset verify DIR | head -1`): not an error.
        Err(e) if dataset_cmd::is_broken_pipe(&e) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("btfrig: {}", message(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes, each once: many errors already quote their source in their own
/// message, and `{:#}` would print it a second time.
fn message(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !text.contains(&c) {
            text.push_str(": ");
            text.push_str(&c);
        }
    }
    text
}
