//! The colour calibration on the simulated rig: each chart of the plan rendered in the sample
//! region of the holder plate (true lens, lamp, seeded sensor noise), its patches' reference
//! colours computed from their spectra under the simulated lamp, the lamp's level from its
//! model; the procedure itself is `btfrig_calibrate::color::calibrate_color`.

use btfrig_calibrate::color::{calibrate_color, ChartCamera, ChartFrame, ChartReferences, ColorCalibration, ColorPlan};
use btfrig_calibrate::RigCalibError;
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_render::chart::ColorChart;
use btfrig_render::renderer::RenderOptions;
use btfrig_render::rig_scene::RigScene;

/// The simulated rig with each of a plan's charts mounted: a [`ChartCamera`].
pub struct SimChartCamera {
    /// One scene per chart of the plan.
    scenes: Vec<RigScene>,
    seed: u64,
    opts: RenderOptions,
}

impl SimChartCamera {
    /// The rig `cfg` with the charts of `plan`; noise seeded from `seed` and the frame.
    pub fn new(cfg: &RigConfig, plan: &ColorPlan, seed: u64) -> Result<SimChartCamera, RigCalibError> {
        let rig = |e: String| RigCalibError::Rig(e);
        let mut scenes = Vec::new();
        for c in &plan.charts {
            let chart = ColorChart::by_name(&c.name).map_err(rig)?;
            scenes.push(RigScene::with_chart(cfg, &chart).map_err(|e| rig(e.to_string()))?);
        }
        if scenes.is_empty() {
            return Err(RigCalibError::Plan {
                origin: plan.name.clone(),
                message: "charts: at least one chart".into(),
            });
        }
        Ok(SimChartCamera { scenes, seed, opts: RenderOptions::default() })
    }

    /// The charts' reference colours under the simulated lamp (each patch spectrum's output
    /// colour) and the lamp model's nominal irradiance.
    pub fn references(&self, plan: &ColorPlan) -> Result<ChartReferences, RigCalibError> {
        let mut patches = Vec::new();
        for (c, scene) in plan.charts.iter().zip(&self.scenes) {
            let chart = ColorChart::by_name(&c.name).map_err(RigCalibError::Rig)?;
            patches.push(chart.patches.iter().map(|p| scene.colour().output_rgb(&p.spectrum)).collect());
        }
        let s = &self.scenes[0];
        Ok(ChartReferences {
            patches,
            white_rate_e_per_s: s.white_signal_dn(1.0, 1.0) / s.sensor().dn_per_electron(1.0),
            provenance: plan
                .charts
                .iter()
                .map(|c| format!("{}: the simulator's patch spectra under its lamp", c.name))
                .collect(),
        })
    }
}

impl ChartCamera for SimChartCamera {
    fn metering_exposure_s(&self) -> f64 {
        self.scenes[0].exposure_for_white(0.3, 1e-4, 30.0)
    }

    fn capture(&mut self, frame: ChartFrame, joints: &JointState, exposure_s: f64) -> Result<RawFrame, String> {
        let (scene, s) = match frame {
            ChartFrame::Metering => (&self.scenes[0], self.seed ^ 0x4D_45_54_45_52),
            ChartFrame::Chart(i) => (
                self.scenes.get(i).ok_or_else(|| format!("no chart {i}"))?,
                self.seed ^ (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            ),
        };
        scene.capture(joints, 1.0, exposure_s, 1.0, s, &self.opts).map(|(raw, _)| raw).map_err(|e| e.to_string())
    }
}

/// Runs `plan` on the simulated rig `cfg`: photographs the fitting and test charts (noise
/// seeded from `seed`), registers and rectifies with `camera` (the processing camera,
/// e.g. `btfrig_calibrate::processing_camera`), measures the patches and fits and evaluates
/// every candidate model. `progress` receives one line per stage.
pub fn calibrate_color_simulated(
    cfg: &RigConfig,
    camera: &CameraModel,
    plan: &ColorPlan,
    seed: u64,
    progress: impl FnMut(&str),
) -> Result<ColorCalibration, RigCalibError> {
    run(cfg, camera, plan, seed, 1.0, progress)
}

/// [`calibrate_color_simulated`] with the metered exposure multiplied by `exposure_scale`
/// (stress tests: over-exposure clips bright patches, under-exposure buries dark ones).
pub fn calibrate_color_simulated_with_exposure_scale(
    cfg: &RigConfig,
    camera: &CameraModel,
    plan: &ColorPlan,
    seed: u64,
    exposure_scale: f64,
) -> Result<ColorCalibration, RigCalibError> {
    run(cfg, camera, plan, seed, exposure_scale, |_| {})
}

fn run(
    cfg: &RigConfig,
    camera: &CameraModel,
    plan: &ColorPlan,
    seed: u64,
    exposure_scale: f64,
    progress: impl FnMut(&str),
) -> Result<ColorCalibration, RigCalibError> {
    let problems = plan.problems();
    if !problems.is_empty() {
        return Err(RigCalibError::Plan { origin: plan.name.clone(), message: problems.join("; ") });
    }
    let mut rig = SimChartCamera::new(cfg, plan, seed)?;
    let references = rig.references(plan)?;
    calibrate_color(cfg, camera, plan, &references, exposure_scale, &mut rig, progress)
}

/// The simulated chart `chart` of the default colour plan as a "measured reference file":
/// its patch spectra under the lamp of rig `cfg` as CIE L*a*b* (D50) CSV, as a lab measures
/// its own chart with a spectrophotometer (`btfrig calibrate color --reference CHART=FILE`).
/// `rig_arg` is the rig config as the header names it. The `sim_chart_lab` example prints it;
/// `calibration/bonn-gonio-sim-chart-*-lab-d50.csv` are its output (a test recomputes them).
pub fn chart_lab_csv(cfg: &RigConfig, rig_arg: &str, chart: &str) -> Result<String, RigCalibError> {
    use btfrig_color::space::{bradford, d65_white, linear_srgb_to_xyz, mat3_apply, xyz_to_lab};
    let plan = ColorPlan::default_plan();
    let index = plan.charts.iter().position(|c| c.name == chart).ok_or_else(|| {
        let known: Vec<&str> = plan.charts.iter().map(|c| c.name.as_str()).collect();
        RigCalibError::Rig(format!("chart {chart:?} is not in the default colour plan (it has: {})", known.join(", ")))
    })?;
    let refs = SimChartCamera::new(cfg, &plan, cfg.rig.seed)?.references(&plan)?;
    // ICC D50, as the published data and `ReferenceValues::linear_srgb`.
    let d50 = [0.9642, 1.0, 0.8249];
    let to_d50 = bradford(d65_white(), d50);
    let mut out = format!(
        "# {chart}: the simulated chart's patch spectra under the lamp of {}, CIE L*a*b* (D50)\n\
         # made by: cargo run --release -p btfrig-sim-calibration --example sim_chart_lab -- {rig_arg} {chart}\nL,a,b\n",
        cfg.rig.name
    );
    for rgb in &refs.patches[index] {
        let lab = xyz_to_lab(mat3_apply(&to_d50, linear_srgb_to_xyz(*rgb)), d50);
        out += &format!("{:.6},{:.6},{:.6}\n", lab[0], lab[1], lab[2]);
    }
    Ok(out)
}
