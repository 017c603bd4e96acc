//! The `btfrig` binary: argument handling and display only; the work is in the library crates.

mod args;
mod bench_cmd;
mod demo_cmd;
mod kinematics_cmd;
mod material;
mod rig;
mod session;
mod sim_cmd;

use args::{BenchCommand, Cli, Command, KinematicsCommand, SimCommand};
use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Kinematics(KinematicsCommand::Check { rig, json }) => kinematics_cmd::check(rig.as_deref(), json),
        Command::Demo(a) => demo_cmd::run(&a),
        Command::Sim(SimCommand::Render(a)) => sim_cmd::render(&a),
        Command::Sim(SimCommand::Materials) => sim_cmd::materials(),
        Command::Bench(BenchCommand::Render { rig, material, texels, repeat }) => {
            bench_cmd::render(rig.as_deref(), &material, texels, repeat)
        }
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("btfrig: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
