//! Low-level arguments as clap parses them. `main.rs` turns them into validated settings
//! (a loaded rig, a material, directions) before any work starts.

use clap::{Args, Parser, Subcommand};

pub use crate::compress_cmd::SparseCommand;

/// btfrig: runs the rigs that measure bidirectional texture functions.
#[derive(Debug, Parser)]
#[command(name = "btfrig", version, about, propagate_version = true)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the default measurement plan (embedded) on the simulated gonioreflectometer end
    /// to end into a new dataset directory, and print a summary.
    Demo(DemoArgs),
    /// Run a measurement plan on the simulated rig into a dataset directory; resumes a
    /// dataset of the same plan, refuses any other.
    Run(RunArgs),
    /// The simulated rig on its own.
    #[command(subcommand)]
    Sim(SimCommand),
    /// Kinematics of a rig.
    #[command(subcommand)]
    Kinematics(KinematicsCommand),
    /// Measurement plans: validate, and dry-run with time and disk estimates.
    #[command(subcommand)]
    Plan(PlanCommand),
    /// Datasets on disk.
    #[command(subcommand)]
    Dataset(DatasetCommand),
    /// Benchmarks that print time and error side by side.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Calibrations of the rig.
    #[command(subcommand)]
    Calibrate(CalibrateCommand),
    /// From measurement to material: photometric stereo, height, reflectance models
    /// (docs/material-models.md).
    #[command(subcommand)]
    Model(crate::model_cmd::ModelCommand),
    /// Compress a dataset into a linear BTF model file: FMF, PVMF or PCMF (docs/compression.md).
    Compress(crate::compress_cmd::CompressArgs),
    /// Process a gonio dataset's raw frames again, e.g. after a better calibration, into a new
    /// dataset, without the rig (docs/pipeline.md, "Reprocessing").
    Reprocess(crate::reprocess_cmd::ReprocessArgs),
    /// Sparse acquisition with a linear basis: choose the captures, reconstruct the full BTF.
    #[command(subcommand)]
    Sparse(crate::compress_cmd::SparseCommand),
    /// Hardware: list serial ports and USB devices, and query a rig's devices.
    #[command(subcommand)]
    Hw(HwCommand),
    /// The control daemon: HTTP API, live events, preview and the operator page
    /// (docs/http-api.md). SIGTERM pauses the run under way resumably and exits.
    Serve(ServeArgs),
}

/// `btfrig hw ...`.
#[derive(Debug, Subcommand)]
pub enum HwCommand {
    /// List serial ports and USB devices (PTP cameras marked); with `--rig`, connect each
    /// device of that rig through its backend and print its identity, health and homing
    /// state without moving it (emulated devices: behind their firmware on pseudo-terminals,
    /// real serial controllers on their ports; docs/serial.md). GenICam cameras (a build with
    /// the `genicam` feature): the rig's, those named by `--genicam`, and with `--discover`
    /// every camera Aravis finds (docs/genicam.md). Exit status 1 when any device fails,
    /// naming it.
    Probe {
        /// Rig config file, or an embedded rig by name (`gonio-serial`).
        #[arg(long)]
        rig: Option<std::path::PathBuf>,
        /// A recorded-camera directory (docs/recorded-camera.md): its frame count, size,
        /// format, exposure range, what its sidecar says and any problem found; repeatable.
        #[arg(long, value_name = "DIR")]
        recorded: Vec<std::path::PathBuf>,
        /// A GenICam camera to open by IP address (repeatable); no broadcast.
        #[arg(long, value_name = "ADDR")]
        genicam: Vec<std::net::Ipv4Addr>,
        /// Also list every GenICam camera by discovery, which BROADCASTS on every network
        /// interface of this machine.
        #[arg(long)]
        discover: bool,
    },
}

/// `btfrig serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Rig config; default the embedded simulated gonioreflectometer.
    #[arg(long)]
    pub rig: Option<std::path::PathBuf>,
    /// Address to listen on (port 0: any free port; the first stdout line names it).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub listen: std::net::SocketAddr,
    /// Data directory: datasets and calibrations go here, and nothing outside it is served.
    #[arg(long, default_value = "btfrig-data")]
    pub data: std::path::PathBuf,
    /// Auth file with [[token]] name, token, role (viewer | operator | admin); without it one
    /// random admin token is generated and written to DATA/daemon-token.
    #[arg(long)]
    pub auth: Option<std::path::PathBuf>,
    /// Directory of plan files offered by name; default the embedded plans (demo, ...).
    #[arg(long)]
    pub plans: Option<std::path::PathBuf>,
}

/// `btfrig calibrate ...`.
#[derive(Debug, Subcommand)]
pub enum CalibrateCommand {
    /// Geometric camera calibration: the robot presents the calibration board at the plan's
    /// views, the camera captures (any rig, through its devices), the board's markers give
    /// intrinsics and distortion; writes the calibration file (docs/camera-calibration.md).
    Geometry(CalibrateGeometryArgs),
    /// Rig geometry: the joints' zero offsets from the marker plate registered at a few dozen
    /// poses (any rig, through its devices); prints the pose error before and after, writes
    /// the file `[geometry] calibration` names (docs/kinematics.md).
    RigGeometry(crate::calibrate_rig_geometry_cmd::CalibrateRigGeometryArgs),
    /// Light calibration: photograph a white reference tile on the holder at the plan's
    /// captures (through the rig's devices), measure the lamp's power and colour and the plate's
    /// albedo relative to the tile, write the light calibration file (docs/light.md).
    Light(crate::calibrate_light_cmd::CalibrateLightArgs),
    /// Dark and flat-field calibration: dark frames at several exposures and gains, master
    /// flats per f-number on a uniform field (through the rig's devices); writes float EXR maps and a TOML header
    /// (docs/dark-flat.md).
    Radiometric(crate::calibrate_radiometric_cmd::CalibrateRadiometricArgs),
    /// Colour calibration: photograph colour charts in the sample region (any rig, through
    /// its devices), fit colour models against published or measured reference values, choose by cross-validated CIEDE2000, report held-out CIEDE2000 and
    /// write the calibration file (docs/color.md).
    Color(CalibrateColorArgs),
    /// LED calibration of a dome (flash calibration of a camera array): photograph a white
    /// reference tile under one light at a time or multiplexed patterns (through the rig's devices), measure each light's power
    /// and colour, write the file a rig's `[dome] led_calibration` names (docs/rig-config.md).
    Leds(crate::calibrate_leds_cmd::CalibrateLedsArgs),
    /// Characterise the camera's sensor after EMVA 1288 (gain, read noise, dark current,
    /// DSNU, PRNU, saturation, linearity), captured through the devices.
    Sensor(crate::calibrate_sensor_cmd::CalibrateSensorArgs),
}

/// `btfrig calibrate color`.
#[derive(Debug, Args)]
pub struct CalibrateColorArgs {
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<std::path::PathBuf>,
    /// Colour calibration plan file (default: the embedded rig-configs/plans/calibration-color.toml).
    #[arg(long)]
    pub plan: Option<std::path::PathBuf>,
    /// Calibration file to write (default: `<rig name>-color.toml` in the current directory).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Seed of the sensor noise (default: the rig's `[rig] seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Print one JSON object (per model figures, per patch errors) instead of tables.
    #[arg(long)]
    pub json: bool,
    /// Measured reference values of a chart instead of its published ones: `CHART=FILE`, a
    /// CSV with columns L, a, b (CIE L*a*b*, D50), one row per patch in chart order; repeat
    /// per chart. Charts not named use the published values.
    #[arg(long, value_name = "CHART=FILE")]
    pub reference: Vec<String>,
}

/// `btfrig calibrate geometry`.
#[derive(Debug, Args)]
pub struct CalibrateGeometryArgs {
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<std::path::PathBuf>,
    /// Calibration plan file (default: the embedded rig-configs/plans/calibration-geometry.toml).
    #[arg(long)]
    pub plan: Option<std::path::PathBuf>,
    /// Calibration file to write (default: `<rig name>-geometry.toml` in the current directory).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Seed of the sensor noise (default: the rig's `[rig] seed`).
    #[arg(long)]
    pub seed: Option<u64>,
}

/// `btfrig demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Run the whole Bonn 81 x 81 plan (embedded rig-configs/plans/bonn-full.toml) instead
    /// of the quick demo plan (rig-configs/plans/demo.toml).
    #[arg(long)]
    pub full: bool,
    /// Rig config file instead of the plan's embedded simulated gonioreflectometer, or an
    /// embedded rig by name: `gonio-serial` (the same rig through the serial and PTP
    /// backends and emulated firmware on pseudo-terminals, docs/serial.md), `dome` (the LED
    /// dome demo) or `camera-array` (the camera array demo, its flashes as the lights;
    /// docs/multiplexing.md).
    #[arg(long)]
    pub rig: Option<std::path::PathBuf>,
    /// Material name (see `btfrig sim materials`) or a material TOML file, instead of the plan's.
    #[arg(long)]
    pub material: Option<String>,
    /// Dataset directory, new or empty (default: a new `btfrig-demo-*` directory under the
    /// system's temporary directory).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Print the summary as one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// `btfrig sim captures`.
#[derive(Debug, Args)]
pub struct CapturesArgs {
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<std::path::PathBuf>,
    /// Material name (see `btfrig sim materials`) or a material TOML file.
    #[arg(long)]
    pub material: Option<String>,
    /// Directory to write the captured frames into (default: a new `btfrig-captures-*`
    /// directory under the system's temporary directory).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Print the summary as one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// `btfrig run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// The plan (TOML, see docs/plan-format.md).
    #[arg(long)]
    pub plan: std::path::PathBuf,
    /// The dataset directory (created; or a dataset of the same plan, resumed).
    #[arg(long)]
    pub out: std::path::PathBuf,
    /// Rig config instead of the plan's `[rig] config`: a file, or an embedded rig by name;
    /// e.g. a recorded rig, whose camera replays recorded frames (docs/recorded-camera.md).
    #[arg(long, value_name = "FILE")]
    pub rig: Option<std::path::PathBuf>,
    /// Fault scenario of the simulated rig instead of the plan's `run.fault_scenario`: an
    /// embedded name (none, flaky, lamp-drift, stuck-led, robot-fault) or a file. Does not
    /// change the plan hash, so a run paused on a fatal fault resumes with `--faults none`.
    #[arg(long, value_name = "NAME|FILE")]
    pub faults: Option<String>,
    /// Light calibration file (`btfrig calibrate light`): the lamp's power and colour from it,
    /// and its drift measured on the plate per frame and corrected (docs/light.md).
    #[arg(long, value_name = "FILE")]
    pub light: Option<std::path::PathBuf>,
    /// Dark/flat calibration directory (`btfrig calibrate radiometric --out DIR`): every frame
    /// is corrected with its dark model and master flat before demosaicing (docs/dark-flat.md).
    #[arg(long, value_name = "DIR")]
    pub dark_flat: Option<std::path::PathBuf>,
    /// Build a linear model of the BTF while the run captures (fmf, pvmf, pcmf or pcmf-shared
    /// with the `btfrig compress` defaults; fmf: YUV 16/8/8 terms; pcmf-shared: PCMF 32 x 8
    /// in a shared basis of 32 terms) and write it next to the dataset
    /// (docs/compression.md). Overrides the plan's `outputs.compressed_model`; for gonio and dome plans.
    #[arg(long, value_name = "METHOD")]
    pub compress: Option<String>,
    /// Run the devices on the wall clock even on a simulated rig (whose devices then wait in
    /// real time); a rig with real devices always does. The plan's `[run] clock = "wall"`
    /// does the same (docs/timing.md).
    #[arg(long)]
    pub wall_clock: bool,
}

/// `btfrig sim ...`.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Render one capture: the raw frame, a preview and the ground-truth texture.
    Render(RenderArgs),
    /// List the embedded materials.
    Materials,
    /// A handful of captures through the device traits, each written as raw frame, preview
    /// and ground-truth texture (no plan, no dataset).
    Captures(CapturesArgs),
}

/// `btfrig sim render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Rig config file (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Option<std::path::PathBuf>,
    /// Material name (see `btfrig sim materials`) or a material TOML file.
    #[arg(long)]
    pub material: Option<String>,
    /// View direction in sample coordinates: THETA,PHI in degrees.
    #[arg(long, value_name = "THETA,PHI")]
    pub view: String,
    /// Light direction in sample coordinates: THETA,PHI in degrees.
    #[arg(long, value_name = "THETA,PHI")]
    pub light: String,
    /// Raw frame output: `.exr` (linear float DN) or `.png` (16-bit DN).
    #[arg(long)]
    pub out: std::path::PathBuf,
    /// 8-bit sRGB demosaiced preview (`.png`).
    #[arg(long)]
    pub preview: Option<std::path::PathBuf>,
    /// Ground-truth texture on the sample plane (`.exr`, linear sRGB).
    #[arg(long)]
    pub ground_truth: Option<std::path::PathBuf>,
    /// Ground-truth texture size in texels (square).
    #[arg(long, default_value_t = 256)]
    pub texture_size: usize,
    /// Exposure time in seconds (default: chosen so the white plate sits near 60% of full scale).
    #[arg(long)]
    pub exposure: Option<f64>,
    /// Seed of every random process of the simulated rig: sensor noise and the robot's and
    /// rail's positioning error (default: the rig config's `[rig] seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Draw the nominal pose, without the robot's and rail's positioning error.
    #[arg(long)]
    pub nominal: bool,
}

/// `btfrig kinematics ...`.
#[derive(Debug, Subcommand)]
pub enum KinematicsCommand {
    /// Classify every (light, view) pair of the Bonn 81 x 81 sampling: reachable, or
    /// unreachable with a reason; check FK(IK(pair)) for each reachable one.
    Check {
        /// Rig config file (default: the embedded simulated gonioreflectometer).
        #[arg(long)]
        rig: Option<std::path::PathBuf>,
        /// Print the result as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// `btfrig plan ...`.
#[derive(Debug, Subcommand)]
pub enum PlanCommand {
    /// Validate a plan file: every problem at once, naming field, value and what is allowed.
    Check {
        /// The plan (TOML, see docs/plan-format.md).
        file: std::path::PathBuf,
    },
    /// Dry run: captures, skips by reason, estimated hardware time (motion-optimised order,
    /// naive order, lower bound) and disk space.
    Show {
        /// The plan (TOML, see docs/plan-format.md).
        file: std::path::PathBuf,
    },
}

/// `btfrig dataset ...`.
#[derive(Debug, Subcommand)]
pub enum DatasetCommand {
    /// What a dataset holds: rig, plan, samplings, progress, size, timing, and the model
    /// files next to it; or, given a `.btfm` model file, what the model holds.
    Info {
        /// The dataset directory (or a model file).
        dir: std::path::PathBuf,
    },
    /// Export the dataset's compressed model to a Bonn `.btf` container (docs/compression.md).
    Export(crate::compress_cmd::ExportArgs),
    /// Write the raw frames a gonio dataset kept (`[outputs] raw_frames = true`) as a
    /// recording: frame files, their sidecar recording.toml and a recorded rig config rig.toml,
    /// which `btfrig run --rig RECDIR/rig.toml` replays (docs/recorded-camera.md).
    ExportRecording {
        /// The dataset directory.
        dir: std::path::PathBuf,
        /// The recording directory (created; must be new or empty).
        #[arg(long)]
        out: std::path::PathBuf,
        /// Frame file format: png (16-bit), tiff (16-bit) or exr.
        #[arg(long, default_value = "png")]
        format: String,
    },
    /// Render the dataset's compressed model at a (light, view) pair, as the viewer does:
    /// btfrig's own evaluation, to PNG (sRGB) or EXR (linear) (docs/looking.md).
    Render(crate::look_cmd::RenderArgs),
    /// The coverage plot and the dataset's figures as one self-contained HTML file that
    /// opens without the daemon (docs/looking.md).
    Report(crate::look_cmd::ReportArgs),
    /// Check every file's size and hash, completeness, and orphans; exit 1 on any problem.
    Verify {
        /// The dataset directory.
        dir: std::path::PathBuf,
    },
}

/// `btfrig bench ...`.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Render time of a full frame with and without the renderer's skips, side by side,
    /// with the difference between the two images.
    Render {
        /// Rig config file (default: the embedded simulated gonioreflectometer).
        #[arg(long)]
        rig: Option<std::path::PathBuf>,
        /// Material names to benchmark (default: all embedded materials).
        #[arg(long)]
        material: Vec<String>,
        /// Texels per side of the sample's material grid.
        #[arg(long, default_value_t = 256)]
        texels: usize,
        /// Timed repetitions per setting (the median is reported).
        #[arg(long, default_value_t = 5)]
        repeat: usize,
    },
    /// Marker registration and rectification: per pose setting and filter, time per frame
    /// and texel / texture error against the simulator's truth (docs/benchmarks.md).
    Registration(BenchRegistrationArgs),
    /// One frame from raw photosites to texture, stage by stage, against the OpenCV pipeline
    /// and a memory pass; the HDR merge before and after (docs/benchmarks.md).
    Pipeline(crate::bench_pipeline::BenchPipelineArgs),
    /// Colour-correction models: fit and apply time against held-out CIEDE2000 (docs/color.md).
    Color(crate::bench_color::BenchColorArgs),
    /// Demultiplexing S-matrix captures: fast transform vs dense inverse vs least squares,
    /// time and error, against a plain memory pass (docs/multiplexing.md).
    Demux(crate::bench_demux::BenchDemuxArgs),
    /// BTF compression on a simulated 81 x 81 BTF: per model and setting, ratio, build time,
    /// decode throughput and relative RMSE against the measured data and the ground truth;
    /// sparse acquisition (docs/compression.md).
    Compress(crate::bench_compress::BenchCompressArgs),
    /// Material models of simulated datasets: photometric stereo (least squares and robust)
    /// against the true surface (docs/material-models.md).
    Model(crate::model_cmd::BenchModelArgs),
    /// The daemon under load: a simulated run through `btfrig serve` with and without a
    /// second process sending status requests; p99 latency and the run's slowdown.
    Serve(crate::bench_serve::BenchServeArgs),
    /// The load generator of `bench serve` (a second process); not for direct use.
    #[command(hide = true)]
    ServeLoad(crate::bench_serve::ServeLoadArgs),
}

/// `btfrig bench registration` (implemented in `bench_cmd.rs`).
#[derive(Debug, clap::Args)]
pub struct BenchRegistrationArgs {
    /// Rig config files, side by side (default: the embedded simulated gonioreflectometer).
    #[arg(long)]
    pub rig: Vec<std::path::PathBuf>,
    /// Views as THETA,PHI in degrees (light at 45,0); default: 0,0 45,90 45,270 75,90 75,270 80,90.
    #[arg(long, num_args = 1.., value_parser = |s: &str| parse_direction("views", s))]
    pub views: Vec<btfrig_core::Direction>,
    /// Texels per side of the texture over the sample.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    /// Timed repetitions of each step (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Seed of positioning error and sensor noise (frame k uses seed + k).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Material of the sample.
    #[arg(long, default_value = "lacquered-wood")]
    pub material: String,
    /// Also run OpenCV (ArUco, undistortPoints, findHomography, warpPerspective) on the same
    /// frames via tests/markers/bench_opencv.py (installs opencv-python-headless if needed).
    #[arg(long)]
    pub opencv: bool,
    /// Print one table row per view as well as the totals.
    #[arg(long)]
    pub per_view: bool,
}

/// Parses `THETA,PHI` in degrees.
pub fn parse_direction(field: &str, text: &str) -> Result<btfrig_core::Direction, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let bad = || format!("--{field} {text:?}: expected THETA,PHI in degrees, theta in [0, 90), phi any (e.g. 45,120)");
    if parts.len() != 2 {
        return Err(bad());
    }
    let theta: f64 = parts[0].parse().map_err(|_| bad())?;
    let phi: f64 = parts[1].parse().map_err(|_| bad())?;
    if !theta.is_finite() || !phi.is_finite() || !(0.0..90.0).contains(&theta) {
        return Err(bad());
    }
    Ok(btfrig_core::Direction::from_degrees(theta, phi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_parse_and_reject() {
        let d = parse_direction("view", "45, 120").unwrap();
        assert!((d.theta.to_degrees() - 45.0).abs() < 1e-12);
        for bad in ["", "45", "45,1,2", "90,0", "-1,0", "x,0", "nan,0"] {
            let e = parse_direction("view", bad).unwrap_err();
            assert!(e.contains("--view") && e.contains("[0, 90)"), "{e}");
        }
    }
}
