//! Registration of one camera frame: detect the holder plate's markers in the image, pair
//! their corners with the plate layout, estimate the sample pose ([`crate::register`]).
//!
//! This is the glue the pipeline and the benchmark share, so both measure the same thing.

use std::time::Instant;

use btfrig_core::camera::CameraModel;
use btfrig_core::config::plate::{MarkerPlacement, PlateConfig};
use btfrig_core::pose::ScenePose;
use btfrig_markers::{detect, DetectError, DetectParams, Detection, Dictionary, GrayImage};

use crate::{register, Correspondence, RegisterError, RegisterOptions, Registration};

/// Why a frame could not be registered.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// The plate names a dictionary the detector does not know.
    #[error("plate.marker_dictionary = {name:?} is not known to the marker detector (known: DICT_4X4_50)")]
    UnknownDictionary {
        /// The name in the rig config.
        name: String,
    },
    /// The detector refused the image or its settings.
    #[error("marker detection: {0}")]
    Detect(#[from] DetectError),
    /// The detected markers gave no trustworthy pose.
    #[error("{source} (plate markers detected: {detected:?})")]
    Register {
        /// Ids of the plate's markers that were detected, ascending.
        detected: Vec<u32>,
        /// Why registration refused.
        source: RegisterError,
    },
}

/// A registered frame.
#[derive(Debug, Clone)]
pub struct FrameRegistration {
    /// The pose estimate and its diagnostics.
    pub registration: Registration,
    /// Ids of the plate's markers that were detected, ascending.
    pub detected: Vec<u32>,
    /// Ids decoded in the image that are not on this plate (ignored).
    pub foreign: Vec<u32>,
    /// Seconds spent detecting markers.
    pub detect_s: f64,
    /// Seconds spent estimating the pose.
    pub register_s: f64,
}

/// Registers frames of one rig: camera model, plate layout, detector and estimator settings.
#[derive(Debug, Clone)]
pub struct PlateRegistrar {
    camera: CameraModel,
    markers: Vec<MarkerPlacement>,
    dictionary: Dictionary,
    /// Detector settings (the camera model is set, so edges are undistorted before fitting).
    pub detect: DetectParams,
    /// Estimator settings.
    pub options: RegisterOptions,
}

impl PlateRegistrar {
    /// A registrar for frames of `camera` showing the plate `plate` (a validated section).
    pub fn new(camera: CameraModel, plate: &PlateConfig, options: RegisterOptions) -> Result<Self, FrameError> {
        let dictionary = Dictionary::by_name(&plate.marker_dictionary)
            .ok_or_else(|| FrameError::UnknownDictionary { name: plate.marker_dictionary.clone() })?;
        let detect = DetectParams { camera: Some(camera.clone()), ..DetectParams::default() };
        Ok(PlateRegistrar { camera, markers: plate.marker_placements(), dictionary, detect, options })
    }

    /// The camera model frames are registered with.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// The plate's markers.
    pub fn markers(&self) -> &[MarkerPlacement] {
        &self.markers
    }

    /// Pairs detected corners with the plate layout: four correspondences per detection of a
    /// plate marker (sigma: the detector's per-corner standard deviation). Returns them with
    /// the detected plate ids and the ids not on this plate.
    pub fn correspondences(&self, detections: &[Detection]) -> (Vec<Correspondence>, Vec<u32>, Vec<u32>) {
        let mut out = Vec::with_capacity(4 * detections.len());
        let (mut detected, mut foreign) = (Vec::new(), Vec::new());
        for d in detections {
            match self.markers.iter().find(|m| m.id == d.id) {
                Some(m) => {
                    detected.push(d.id);
                    for k in 0..4 {
                        out.push(Correspondence {
                            plane: m.corners_sample_m[k],
                            pixel: d.corners[k],
                            sigma_px: d.corner_sigma_px[k],
                            marker: d.id,
                        });
                    }
                }
                None => foreign.push(d.id),
            }
        }
        detected.sort_unstable();
        foreign.sort_unstable();
        (out, detected, foreign)
    }

    /// Detects the markers in `image` (a grey image of the frame: the green channel of a
    /// Bayer camera carries half its photosites) and estimates the sample pose, with
    /// `nominal` (the kinematic pose) as prior and gate.
    pub fn register_image(&self, image: &GrayImage, nominal: &ScenePose) -> Result<FrameRegistration, FrameError> {
        let t = Instant::now();
        let detections = detect(image, &self.dictionary, &self.detect)?;
        let detect_s = t.elapsed().as_secs_f64();
        let (corr, detected, foreign) = self.correspondences(&detections);
        let t = Instant::now();
        let registration = register(&corr, &self.camera, nominal, &self.options)
            .map_err(|source| FrameError::Register { detected: detected.clone(), source })?;
        Ok(FrameRegistration { registration, detected, foreign, detect_s, register_s: t.elapsed().as_secs_f64() })
    }
}
