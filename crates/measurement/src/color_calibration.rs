//! Colour calibration through the devices (`btfrig calibrate color`): each chart of the plan
//! mounted in the sample region in turn (on a real rig the operator swaps them when the
//! procedure reopens the rig), the robot and rail at the plan's view, the lamp lit, the camera
//! capturing; the frames go to `btfrig_calibrate::color::calibrate_color`, which registers,
//! measures and fits them against the charts' reference values (published or measured,
//! [`ReferenceValues`]).

use std::path::Path;

use btfrig_calibrate::color::{
    calibrate_color, ChartCamera, ChartFrame, ChartReferences, ColorCalibration, ColorPlan, ReferenceValues,
};
use btfrig_core::camera::CameraModel;
use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;

use crate::backend::{BackendRegistry, MountedTarget, RigTime};
use crate::calibration_rig::{level_quantile, CalibrationRig, Role};
use crate::RunError;

/// The devices a colour calibration needs.
pub const COLOR_DEVICES: &[Role] = &[Role::Robot, Role::Rail, Role::Lamp, Role::Camera];

/// The charts' reference colours and the lamp's level for `plan` on `rig`: per chart the
/// reference values of `references` (the same index as the plan's charts; a missing entry is
/// `Published`), and the lamp's white rate from the light calibration the rig config names
/// (`[lamp] calibration`), or the sensor's full scale (as uncalibrated processing) without one.
pub fn chart_references(
    rig: &RigConfig,
    rig_path: Option<&Path>,
    plan: &ColorPlan,
    references: &[ReferenceValues],
) -> Result<ChartReferences, RunError> {
    let mut patches = Vec::new();
    let mut provenance = Vec::new();
    for (i, c) in plan.charts.iter().enumerate() {
        let r = references.get(i).unwrap_or(&ReferenceValues::Published);
        patches.push(r.linear_srgb(&c.name).map_err(|e| RunError::Rig(e.to_string()))?);
        provenance.push(r.describe(&c.name));
    }
    let white_rate_e_per_s = match crate::model::config_light(rig, rig_path)? {
        Some((light, _)) => light.reference.white_rate[1],
        None => {
            (crate::model::white_level_dn(&rig.sensor) - f64::from(rig.sensor.black_level_dn))
                * rig.sensor.electrons_per_dn
        }
    };
    Ok(ChartReferences { patches, white_rate_e_per_s, provenance })
}

/// Runs `plan` on `rig` through its devices (`backends`: the installed registry when `None`)
/// on `time`, registering and rectifying with `camera` (the processing camera); `seed`
/// drives a simulated rig's noise. `progress` receives one line per stage.
#[allow(clippy::too_many_arguments)]
pub fn calibrate_color_on_rig(
    rig: &RigConfig,
    backends: Option<&BackendRegistry>,
    camera: &CameraModel,
    plan: &ColorPlan,
    references: &ChartReferences,
    seed: u64,
    time: RigTime,
    progress: impl FnMut(&str),
) -> Result<ColorCalibration, RunError> {
    let rt = match time {
        RigTime::Virtual => crate::virtual_time_runtime()?,
        RigTime::Wall => {
            tokio::runtime::Builder::new_current_thread().enable_all().build().map_err(RunError::Runtime)?
        }
    };
    let mut charts = DeviceCharts {
        rt,
        rig,
        backends,
        charts: plan.charts.iter().map(|c| c.name.clone()).collect(),
        seed,
        time,
        mounted: None,
        error: None,
        metering_s: 0.0,
    };
    charts.metering_s = charts.meter(plan)?;
    let r = calibrate_color(rig, camera, plan, references, 1.0, &mut charts, progress);
    if let Some(e) = charts.error.take() {
        // The device error itself, not the procedure's summary of it.
        return Err(e);
    }
    let r = r.map_err(|e| RunError::Rig(e.to_string()))?;
    if let Some((_, dev)) = charts.mounted.take() {
        charts.rt.block_on(dev.finish());
    }
    Ok(r)
}

/// The rig as a [`ChartCamera`]: opens it with the chart asked for mounted (reopening when
/// another chart is asked for), drives it on its own runtime.
struct DeviceCharts<'a> {
    rt: tokio::runtime::Runtime,
    rig: &'a RigConfig,
    backends: Option<&'a BackendRegistry>,
    charts: Vec<String>,
    seed: u64,
    time: RigTime,
    mounted: Option<(usize, CalibrationRig)>,
    error: Option<RunError>,
    metering_s: f64,
}

impl DeviceCharts<'_> {
    /// The rig with chart `i` mounted.
    fn mount(&mut self, i: usize) -> Result<&mut CalibrationRig, RunError> {
        if self.mounted.as_ref().map(|(k, _)| *k) != Some(i) {
            if let Some((_, dev)) = self.mounted.take() {
                self.rt.block_on(dev.finish());
            }
            let chart = self.charts.get(i).ok_or_else(|| RunError::Rig(format!("no chart {i} in the plan")))?;
            let target = MountedTarget::ColorChart { chart: chart.clone() };
            // Each mounting its own noise.
            let seed = self.seed ^ (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let dev = self.rt.block_on(CalibrationRig::open(
                self.rig,
                self.backends,
                &target,
                COLOR_DEVICES,
                seed,
                self.time,
            ))?;
            self.mounted = Some((i, dev));
        }
        Ok(&mut self.mounted.as_mut().expect("mounted above").1)
    }

    /// A first exposure for the metering shot: the chart's brightest photosites (99.5th
    /// percentile) at about 30% of full scale.
    fn meter(&mut self, plan: &ColorPlan) -> Result<f64, RunError> {
        let gonio =
            btfrig_core::kinematics::Gonio::new(self.rig.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?;
        let view = btfrig_core::Direction::from_degrees(plan.view_theta_deg, plan.view_phi_deg);
        let light = btfrig_core::Direction::from_degrees(plan.light_theta_deg, plan.light_phi_deg);
        let joints = gonio.ik(light, view).map_err(|e| RunError::Rig(format!("chart view unreachable: {e}")))?;
        self.mount(0)?;
        let (rt, dev) = (&self.rt, &mut self.mounted.as_mut().expect("mounted above").1);
        rt.block_on(async {
            dev.move_to(&joints).await?;
            let (lo, hi) = dev.exposure_range_s();
            let mut exposure = (lo * hi).sqrt().min(0.1).max(lo);
            for _ in 0..12 {
                let level = level_quantile(&dev.capture(exposure).await?, 0.995);
                if level >= 0.95 {
                    exposure = (exposure / 8.0).max(lo);
                } else if level <= 1e-3 {
                    exposure = (exposure * 16.0).min(hi);
                } else {
                    return Ok((exposure * 0.3 / level).clamp(lo, hi));
                }
            }
            Err(dev.device_error(Role::Camera, format!("cannot meter the chart in {lo}..{hi} s; is the lamp on?")))
        })
    }

    fn capture_frame(&mut self, frame: ChartFrame, joints: &JointState, exposure_s: f64) -> Result<RawFrame, RunError> {
        let i = match frame {
            ChartFrame::Metering => 0,
            ChartFrame::Chart(i) => i,
        };
        self.mount(i)?;
        let (rt, dev) = (&self.rt, &mut self.mounted.as_mut().expect("mounted").1);
        rt.block_on(async {
            dev.move_to(joints).await?;
            dev.capture(exposure_s).await
        })
    }
}

impl ChartCamera for DeviceCharts<'_> {
    fn metering_exposure_s(&self) -> f64 {
        self.metering_s
    }

    fn capture(&mut self, frame: ChartFrame, joints: &JointState, exposure_s: f64) -> Result<RawFrame, String> {
        self.capture_frame(frame, joints, exposure_s).map_err(|e| {
            let text = e.to_string();
            self.error = Some(e);
            text
        })
    }
}
