//! The processor: one processing model, its settings, builders and accessors.

use std::sync::{Arc, Mutex};

use btfrig_core::camera::CameraModel;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_hw::truth::{SampleRegion, TruthProbe};
use btfrig_imaging::Radiometry;
use btfrig_registration::{PlateRegistrar, RegisterOptions};
use tokio::sync::watch;

use crate::preview::PreviewGate;
use crate::{
    color, light, HdrRecording, Outputs, PipelineError, Preview, ProcessSettings, ProcessingModel, RegistrationMethod,
    TextureSink,
};

/// Turns raw frames into textures with one processing model.
pub struct Processor {
    /// What the rig is known as: camera, sensor, plate, kinematics, calibrations.
    pub(crate) model: ProcessingModel,
    pub(crate) settings: ProcessSettings,
    /// `None` when the plan asks for the nominal pose.
    pub(crate) registrar: Option<PlateRegistrar>,
    pub(crate) compare_nominal: bool,
    pub(crate) outputs: Outputs,
    pub(crate) preview: watch::Sender<Option<Arc<Preview>>>,
    pub(crate) preview_gate: Mutex<PreviewGate>,
    /// The plate points of the light calibration's drift patch.
    pub(crate) light_points: Vec<nalgebra::Point2<f64>>,
    /// With HDR on: what each step's journal record says of its exposures.
    hdr: Option<HdrRecording>,
    /// Receives every committed texture ([`Processor::with_sink`]).
    pub(crate) sink: Option<Arc<dyn TextureSink>>,
    /// The truth behind the frames (simulated rigs only), for the error figures.
    pub(crate) truth: Option<Arc<dyn TruthProbe>>,
    /// HDR merge planes kept between brackets (one per bracket merged at once): fresh
    /// frame-sized planes cost a page fault per 4 KiB on every frame.
    pub(crate) merge_planes: Mutex<Vec<btfrig_imaging::hdr::MergedFrame>>,
}

impl Processor {
    /// A processor with `model` (camera, sensor, plate, kinematics, calibrations), writing
    /// textures only ([`Outputs::default`]). One marker registrar is built here for the whole
    /// run, with the model's camera and the registrar's default settings but the pose
    /// tolerance of the rig config (`[geometry] pose_tolerance_deg`, `pose_tolerance_mm`;
    /// absent: 2 degrees / 10 mm, a real rig's), which also sizes the first frame's windows.
    /// Refused: a light calibration with an unusable figure, a dark/flat calibration of
    /// another sensor size.
    pub fn new(model: ProcessingModel, settings: ProcessSettings) -> Result<Self, PipelineError> {
        let camera = &model.camera;
        let registrar = match settings.registration.method {
            RegistrationMethod::Markers => {
                let (deg, m) = model.gonio.geometry().pose_tolerance();
                let options = RegisterOptions::with_pose_tolerance(deg, m);
                let mut r = PlateRegistrar::new(camera.clone(), &model.plate, options)?;
                r.detect = btfrig_markers::DetectParams { camera: Some(camera.clone()), ..r.detect.clone() };
                Some(r)
            }
            RegistrationMethod::Nominal => None,
        };
        if let Some(cal) = &model.dark_flat {
            let (w, h) = (camera.width, camera.height);
            if (cal.dark.width, cal.dark.height) != (w, h) {
                let source = btfrig_imaging::dark_flat::DarkFlatError::SizeMismatch {
                    got_w: w,
                    got_h: h,
                    cal_w: cal.dark.width,
                    cal_h: cal.dark.height,
                };
                return Err(PipelineError::DarkFlatSetup(source));
            }
        }
        let light_points = match &model.light {
            Some(l) => {
                l.validate()?;
                light::patch_points(l, &model.plate)
            }
            None => Vec::new(),
        };
        Ok(Processor {
            model,
            settings,
            registrar,
            compare_nominal: false,
            outputs: Outputs::default(),
            preview: watch::Sender::new(None),
            preview_gate: Mutex::new(PreviewGate::default()),
            light_points,
            hdr: None,
            sink: None,
            truth: None,
            merge_planes: Mutex::new(Vec::new()),
        })
    }

    /// The same processor handing every committed texture to `sink` (none: `None`).
    pub fn with_sink(mut self, sink: Option<Arc<dyn TextureSink>>) -> Self {
        self.sink = sink;
        self
    }

    /// The same processor measuring its results against `truth` (a simulated rig's probe):
    /// texture, pose and brightness errors. The probe never changes a texture.
    pub fn with_truth(mut self, truth: Option<Arc<dyn TruthProbe>>) -> Self {
        self.truth = truth;
        self
    }

    /// The processing model.
    pub fn model(&self) -> &ProcessingModel {
        &self.model
    }

    /// The colour calibration in use, if any.
    pub fn color_correction(&self) -> Option<&color::ColorCorrection> {
        self.model.color.as_ref()
    }

    /// The camera model frames are registered and rectified with.
    pub fn camera(&self) -> &CameraModel {
        &self.model.camera
    }

    /// With `on`, each frame that has a truth and was registered is also rectified with the
    /// nominal pose and compared ([`Processed::error_nominal`](crate::Processed::error_nominal),
    /// [`Totals::texture_rel_rmse_nominal`](crate::Totals::texture_rel_rmse_nominal)): a second
    /// rectification per frame, so off by default.
    pub fn with_nominal_comparison(mut self, on: bool) -> Self {
        self.compare_nominal = on;
        self
    }

    /// The same processor journaling each step's exposures ([`HdrRecording`]); `None`: HDR off.
    pub fn with_hdr_recording(mut self, hdr: Option<HdrRecording>) -> Self {
        self.hdr = hdr;
        self
    }

    /// What is journaled of each step's exposures, with HDR on.
    pub fn hdr_recording(&self) -> Option<&HdrRecording> {
        self.hdr.as_ref()
    }

    /// Photosites that see the sample (the footprint of its region from the nominal pose of
    /// `commanded`, `btfrig_imaging::exposure::sample_footprint`) and are saturated in every one
    /// of `frames`.
    pub fn saturated_on_sample(&self, frames: &[&RawFrame], commanded: &JointState) -> u64 {
        let Some(first) = frames.first() else { return 0 };
        let fp = btfrig_imaging::exposure::sample_footprint(
            &self.model.camera,
            &self.model.gonio.scene_pose(commanded),
            self.settings.region,
        );
        if (fp.width, fp.height) != (first.width, first.height) {
            return 0;
        }
        let saturated = |i: usize| frames.iter().all(|f| f.data.get(i).is_some_and(|&v| v >= f.meta.white_level));
        fp.mask.iter().enumerate().filter(|&(i, &m)| m && saturated(i)).count() as u64
    }

    /// The light correction, if any.
    pub fn light(&self) -> Option<&light::LightCorrection> {
        self.model.light.as_ref()
    }

    /// The same processor writing `outputs`.
    pub fn with_outputs(mut self, outputs: Outputs) -> Self {
        self.outputs = outputs;
        self
    }

    /// The settings.
    pub fn settings(&self) -> &ProcessSettings {
        &self.settings
    }

    /// What is written per frame.
    pub fn outputs(&self) -> &Outputs {
        &self.outputs
    }

    /// The latest preview, updated after each committed step that made one (`None` until the
    /// first): e.g. for an HTTP handler serving "the latest preview frame".
    pub fn subscribe_preview(&self) -> watch::Receiver<Option<Arc<Preview>>> {
        self.preview.subscribe()
    }

    /// The latest preview (see [`Processor::subscribe_preview`]).
    pub fn latest_preview(&self) -> Option<Arc<Preview>> {
        self.preview.borrow().clone()
    }

    /// The radiometric parameters of `frame` before the light calibration: its exposure and
    /// gain, the model's sensor, the colour calibration's white balance (1 without one), no
    /// matrix (a colour calibration's model does the rest), and as nominal irradiance the
    /// sensor's full scale per second (relative units, until the light calibration replaces it).
    pub fn radiometry(&self, frame: &RawFrame) -> Radiometry {
        let sensor = &self.model.sensor;
        let gain = frame.meta.gain.max(1.0);
        Radiometry {
            dn_range: (f64::from(frame.meta.white_level) - f64::from(frame.meta.black_level)).max(1.0),
            exposure_s: frame.meta.exposure_s,
            dn_per_electron: sensor.dn_per_electron(gain),
            dark_e_per_s: if self.model.dark_flat.is_some() { 0.0 } else { sensor.dark_current_e_per_s },
            nominal_irradiance: sensor.full_scale_e,
            white_balance: self.model.color.as_ref().map_or([1.0; 3], |c| c.white_balance),
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        }
    }

    /// The truth probe's texture of the region for true `joints` and `lamp_intensity`
    /// (radiance factor relative to the nominal lamp: what [`Processor::process`] estimates);
    /// `None` without a probe.
    pub fn ground_truth(&self, joints: &JointState, lamp_intensity: f64) -> Option<Vec<[f32; 3]>> {
        let r = self.settings.region;
        let region = SampleRegion { x_min: r.x_min, x_max: r.x_max, y_min: r.y_min, y_max: r.y_max };
        Some(self.truth.as_ref()?.texture(joints, lamp_intensity, region, self.settings.size))
    }
}
