//! The per-frame stages: demosaic (or HDR merge), register, rectify, radiometry, truth figures.

use std::collections::BTreeMap;
use std::time::Instant;

use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_core::pose::ScenePose;
use btfrig_hw::truth::{ExposureTruth, SampleRegion};
use btfrig_imaging::{rectify, rectify_vignetted, to_radiance_factor, vignetting_map, Mosaic, RectifyError};
use btfrig_registration::{texel_position_error_with_cameras, FrameError, GreyFrame, PlateRegistrar, SearchRecord};
use btfrig_store::{PoseSource, StepId, StepRegistration, StepSearch};

use crate::{dark_flat, light, OnRegistrationFailure, PipelineError, Processor};

/// Texel position errors of one frame's poses against its true pose (simulated rig only).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseErrors {
    /// Mean and maximum over the texture's texels, texels, of the pose used.
    pub used: (f64, f64),
    /// The same for the nominal pose.
    pub nominal: (f64, f64),
}

/// One processed frame.
#[derive(Debug, Clone)]
pub struct Processed {
    /// Radiance-factor texture, row-major linear sRGB.
    pub texels: Vec<[f32; 3]>,
    /// Seconds per stage (demosaic, register, rectify, radiometry).
    pub stage_s: BTreeMap<String, f64>,
    /// Sum of squared differences to the ground truth, and of the squared truth (both over
    /// texels and channels); `None` without a truth.
    pub error: Option<(f64, f64)>,
    /// How the pose was found (`None` only for a frame that was not processed).
    pub registration: Option<StepRegistration>,
    /// Texel position errors against the truth; `None` without a truth.
    pub pose_errors: Option<PoseErrors>,
    /// As `error`, had the nominal pose been used; only with
    /// [`Processor::with_nominal_comparison`] and a truth.
    pub error_nominal: Option<(f64, f64)>,
    /// The lamp factor measured on the plate (only with
    /// [`ProcessingModel::with_light`](crate::ProcessingModel::with_light) and drift correction,
    /// and when the plate was measurable).
    pub lamp_factor: Option<light::LampFactor>,
    /// `sum(texture) / sum(truth at the nominal lamp) - 1`; `None` without a truth.
    pub brightness_err: Option<f64>,
    /// For a merged bracket: photosites saturated in every exposure; `None` for one frame.
    pub saturated_photosites: Option<u64>,
}

impl Processed {
    pub(crate) fn nothing() -> Processed {
        Processed {
            texels: Vec::new(),
            stage_s: BTreeMap::new(),
            error: None,
            registration: None,
            pose_errors: None,
            error_nominal: None,
            lamp_factor: None,
            brightness_err: None,
            saturated_photosites: None,
        }
    }
}

impl Processor {
    /// Demosaic, register (or take the nominal pose of `commanded`, per the plan's policy),
    /// rectify with that pose, convert to radiance factor; compare with the truth of `truth`
    /// (true joints, lamp intensity) when given.
    pub fn process(
        &self,
        step: StepId,
        frame: &RawFrame,
        commanded: &JointState,
        truth: Option<ExposureTruth>,
    ) -> Result<Processed, PipelineError> {
        self.process_bracket(step, &[frame], commanded, truth)
    }

    /// [`Processor::process`] of an HDR bracket (`frames`: the exposures of one pose, the base
    /// exposure first): with more than one frame they are merged per photosite into signal
    /// rate (`btfrig_imaging::hdr::merge_bracket`, with the measured dark model and flat if the
    /// processor has them), expressed in the base exposure's normalised DN and demosaiced; the
    /// rest is the single-frame path with the base frame's radiometry. One frame takes the
    /// single-frame path unchanged (no merge).
    pub fn process_bracket(
        &self,
        step: StepId,
        frames: &[&RawFrame],
        commanded: &JointState,
        truth: Option<ExposureTruth>,
    ) -> Result<Processed, PipelineError> {
        let err = |source| PipelineError::Rectify { step, source };
        let Some(&frame) = frames.first() else {
            return Err(PipelineError::Hdr { step, source: btfrig_imaging::hdr::HdrError::Empty });
        };
        let mut stage_s = BTreeMap::new();
        let t = Instant::now();
        let mut saturated_photosites = None;
        // A bracket is merged and a calibrated frame corrected per photosite first; a plain
        // frame is read in place. Either way nothing is demosaiced whole: the marker search
        // reads green in its windows, the rectification RGB under the sample
        // (`btfrig_imaging::mosaic`, the bilinear demosaic's values exactly).
        let values = match (&self.model.dark_flat, frames.len()) {
            (_, 2..) => {
                let (values, saturated) = self.merged_values(step, frames)?;
                saturated_photosites = Some(saturated);
                Some(values)
            }
            (Some(cal), _) => Some(
                dark_flat::corrected_values(frame, cal).map_err(|source| PipelineError::DarkFlat { step, source })?,
            ),
            (None, _) => None,
        };
        let (w, h, bayer) = (frame.width, frame.height, frame.meta.bayer);
        let image = match &values {
            Some(v) => Mosaic::of_values(w, h, bayer, v),
            None => Mosaic::of_raw(frame),
        }
        .map_err(|e| err(RectifyError::ImageSize { width: e.width, height: e.height, len: e.len }))?;
        stage_s.insert(if frames.len() > 1 { "hdr_merge" } else { "demosaic" }.to_string(), t.elapsed().as_secs_f64());

        let nominal = self.model.gonio.scene_pose(commanded);
        let cam = &self.model.camera;
        let s = &self.settings;
        let (pose, registration) = match &self.registrar {
            None => (nominal, record(PoseSource::NominalByPlan)),
            Some(registrar) => {
                let t = Instant::now();
                let found = self.register(registrar, &image, &nominal);
                stage_s.insert("register".to_string(), t.elapsed().as_secs_f64());
                match found {
                    Ok(r) => r,
                    Err((reason, search)) => match s.registration.on_failure {
                        OnRegistrationFailure::Fail => return Err(PipelineError::Registration { step, reason }),
                        OnRegistrationFailure::Nominal => (
                            nominal,
                            StepRegistration { reason: Some(reason), search, ..record(PoseSource::NominalFallback) },
                        ),
                    },
                }
            }
        };

        let t = Instant::now();
        // The vignetting map from the rectifier's own projections.
        let (tex, vig) = rectify_vignetted(&image, cam, &pose, s.region, s.size, s.filter).map_err(err)?;
        stage_s.insert("rectify".to_string(), t.elapsed().as_secs_f64());

        let t = Instant::now();
        let mut radiometry = self.radiometry(frame);
        if saturated_photosites.is_some() {
            // The merge subtracted the dark signal.
            radiometry.dark_e_per_s = 0.0;
        }
        let mut lamp_factor = None;
        if let Some(l) = &self.model.light {
            let (d, points) = (self.model.gonio.geometry().lamp_distance_m, &self.light_points);
            // A frame whose plate cannot be measured keeps factor 1 (counted in the totals).
            lamp_factor = l
                .correct_drift
                .then(|| light::measure_lamp_factor(l, &image, cam, &pose, d, &radiometry, points).ok())
                .flatten();
            let factor = lamp_factor.map_or([1.0; 3], |f| f.factor);
            radiometry = l.apply(&radiometry, factor);
            if let Some(c) = &self.model.color {
                // The colour model was fitted to camera RGB balanced with the chart's white:
                // keep that balance, corrected by this frame's lamp factor only.
                radiometry.white_balance = std::array::from_fn(|k| c.white_balance[k] / factor[k]);
            }
        }
        let vig = if self.model.dark_flat.is_some() { dark_flat::unit_vignetting(vig) } else { vig };
        let mut tex = to_radiance_factor(&tex, &vig, &radiometry).map_err(err)?;
        if let Some(c) = &self.model.color {
            c.apply(&mut tex.data);
        }
        stage_s.insert("radiometry".to_string(), t.elapsed().as_secs_f64());

        let (mut error, mut pose_errors, mut error_nominal, mut brightness_err) = (None, None, None, None);
        // Truth figures need a probe, and textures in absolute units to compare.
        let probe = self.truth.as_deref().filter(|_| self.model.is_absolute());
        if let (Some(ExposureTruth { joints, lamp_intensity: lamp }), Some(probe)) = (truth, probe) {
            // Drift-corrected textures estimate the radiance factor under the calibrated
            // (nominal) lamp, the others under the lamp of the exposure.
            let gt_lamp = if self.light().is_some_and(|l| l.correct_drift) { 1.0 } else { lamp };
            let region = SampleRegion {
                x_min: s.region.x_min,
                x_max: s.region.x_max,
                y_min: s.region.y_min,
                y_max: s.region.y_max,
            };
            let gt = probe.texture(&joints, gt_lamp, region, s.size);
            let true_cam = probe.camera();
            error = Some(squared_error(&tex.data, &gt));
            brightness_err = (gt_lamp > 0.0)
                .then(|| (1.0 + light::brightness_error(&tex.data, &gt)) * gt_lamp - 1.0)
                .filter(|e| e.is_finite());
            let true_pose = probe.pose(&joints);
            let used = texel_position_error_with_cameras(&true_pose, true_cam, &pose, cam, s.region, s.size);
            let nominal_err = if registration.pose == PoseSource::Markers {
                texel_position_error_with_cameras(&true_pose, true_cam, &nominal, cam, s.region, s.size)
            } else {
                used
            };
            pose_errors = Some(PoseErrors { used, nominal: nominal_err });
            if self.compare_nominal {
                error_nominal = if registration.pose == PoseSource::Markers {
                    let tex = rectify(&image, cam, &nominal, s.region, s.size, s.filter).map_err(err)?;
                    let mut vig = vignetting_map(cam, &nominal, s.region, s.size).map_err(err)?;
                    if self.model.dark_flat.is_some() {
                        vig = dark_flat::unit_vignetting(vig);
                    }
                    let mut tex = to_radiance_factor(&tex, &vig, &radiometry).map_err(err)?;
                    if let Some(c) = &self.model.color {
                        c.apply(&mut tex.data);
                    }
                    Some(squared_error(&tex.data, &gt))
                } else {
                    error
                };
            }
        }
        Ok(Processed {
            texels: tex.data,
            stage_s,
            error,
            registration: Some(registration),
            pose_errors,
            error_nominal,
            lamp_factor,
            brightness_err,
            saturated_photosites,
        })
    }

    /// Merges a bracket (base exposure first) into photosite values in the base exposure's
    /// normalised DN (`(DN - dark) / (white - black)` of a frame at the base's exposure and
    /// gain, above 1 where the base saturated); also returns the photosites saturated in
    /// every exposure.
    fn merged_values(&self, step: StepId, frames: &[&RawFrame]) -> Result<(Vec<f32>, u64), PipelineError> {
        use btfrig_imaging::hdr::{merge_bracket_into, MergeOptions, NoiseModel, NominalCalibration};
        let base = frames[0];
        let sensor = &self.model.sensor;
        let noise = NoiseModel { electrons_per_dn: sensor.electrons_per_dn, read_noise_e: sensor.read_noise_e };
        let opts = MergeOptions::default();
        let hdr_err = |source| PipelineError::Hdr { step, source };
        // Planes from the pool (they go back whatever happens below).
        let mut merged = self.merge_planes.lock().expect("merge planes").pop().unwrap_or_default();
        let done = match &self.model.dark_flat {
            Some(cal) => cal
                .merge_calibration(base.meta.f_number)
                .map_err(|source| PipelineError::DarkFlat { step, source })
                .and_then(|mc| {
                    merge_bracket_into(frames, &mc, &noise, &opts, &mut merged).map_err(hdr_err)?;
                    mc.replace_defects(&mut merged.rate, base.meta.bayer.is_some());
                    Ok(())
                }),
            None => {
                let nominal = NominalCalibration {
                    dark_current_e_per_s: sensor.dark_current_e_per_s,
                    electrons_per_dn: sensor.electrons_per_dn,
                };
                merge_bracket_into(frames, &nominal, &noise, &opts, &mut merged).map_err(hdr_err)
            }
        };
        let out = done.map(|()| {
            let range = (f64::from(base.meta.white_level) - f64::from(base.meta.black_level)).max(1.0);
            let scale = base.meta.exposure_s * sensor.dn_per_electron(base.meta.gain.max(1.0)) / range;
            let values: Vec<f32> = merged.rate.iter().map(|&r| (f64::from(r) * scale) as f32).collect();
            (values, merged.saturated_everywhere() as u64)
        });
        self.merge_planes.lock().expect("merge planes").push(merged);
        out
    }

    /// Registers `image` (its demosaiced green channel, computed only where the markers are
    /// searched; half of a Bayer sensor's photosites are green) against the plate; the pose and its record, or the reason it failed with the search's record
    /// when the markers were searched.
    fn register(
        &self,
        registrar: &PlateRegistrar,
        image: &Mosaic,
        nominal: &ScenePose,
    ) -> Result<(ScenePose, StepRegistration), RegistrationFailure> {
        let found = registrar.register_grey(GreyFrame::Mosaic(*image), nominal).map_err(|e| {
            let search = match &e {
                FrameError::Register { search, .. } => Some(step_search(search)),
                _ => None,
            };
            (e.to_string(), search)
        })?;
        let r = &found.registration;
        let s = &self.settings;
        let sigma = r.texel_sigma(registrar.camera(), s.region, s.size);
        let rec = StepRegistration {
            markers: r.inlier_markers.clone(),
            rms_px: Some(r.rms_px),
            texel_sigma: sigma.is_finite().then_some(sigma),
            search: Some(step_search(&found.search)),
            ..record(PoseSource::Markers)
        };
        Ok((found.registration.pose, rec))
    }
}

/// Why a frame did not register, and its marker search's record when the markers were searched.
type RegistrationFailure = (String, Option<Box<StepSearch>>);

/// A registration record with only its pose source set.
fn record(pose: PoseSource) -> StepRegistration {
    StepRegistration { pose, markers: Vec::new(), rms_px: None, texel_sigma: None, reason: None, search: None }
}

/// The journal's record of a frame's marker search.
fn step_search(s: &SearchRecord) -> Box<StepSearch> {
    Box::new(StepSearch {
        windows: s.windows as u32,
        searched_fraction: s.pixels as f64 / s.frame_pixels.max(1) as f64,
        whole_frame: s.whole_frame,
        fallback: s.cause.map(|c| c.as_str().to_string()),
        fallback_detail: s.fallback.clone(),
        detect_s: s.detect_s,
        whole_frame_s: s.whole_frame_s,
        reference_s: s.reference_s,
    })
}

/// Sum of squared differences and of the squared truth over texels and channels.
fn squared_error(tex: &[[f32; 3]], gt: &[[f32; 3]]) -> (f64, f64) {
    let mut se = 0.0;
    let mut st = 0.0;
    for (a, b) in tex.iter().zip(gt) {
        for c in 0..3 {
            let (a, b) = (f64::from(a[c]), f64::from(b[c]));
            se += (a - b) * (a - b);
            st += b * b;
        }
    }
    (se, st)
}
