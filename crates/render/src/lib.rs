//! The physics of the simulated rig: what the camera sees of the sample holder plate, and
//! the sensor that records it.
//!
//! Brief overview: a [`scene::Scene`] is the holder plate ([`plate::PlateLayout`], with ArUco
//! markers from [`markers`]) plus a material ([`material::Material`]: a
//! [`heightfield::HeightField`] with spatially varying diffuse and glossy reflectance, see
//! [`brdf`]) whose colours are resolved into camera-RGB and output-RGB triples. A
//! [`renderer::Renderer`] traces one ray per pixel of a camera given as
//! [`renderer::PixelRays`] for a [`btfrig_core::pose::ScenePose`] and returns a
//! [`radiance::RadianceImage`] (camera-RGB signal rate per photosite); the sensor model turns
//! that into a raw frame. [`ground_truth`] renders the true texture on the sample plane.
//! The physics and the formulas are in `docs/renderer.md`, the material format in
//! `docs/materials.md`.
//!
//! Camera, sensor and colour: [`spectral`] holds the embedded published spectra (CIE
//! observer, lamps, camera sensitivities, ColorChecker); [`colour::ColourSystem`] turns a
//! reflectance spectrum into camera RGB and into the ground-truth output colour (linear sRGB,
//! D65, adapted); [`sensor::SensorModel`] turns a [`radiance::RadianceImage`] of
//! photo-electron rates into a noisy [`btfrig_core::frame::RawFrame`]; `btfrig_imaging::demosaic` makes
//! previews from raw frames; [`scene::Scene::build_target`] renders the geometric
//! calibration board (its layout, `btfrig_core::config::target::TargetBoard`, is shared with
//! the calibration procedure) that replaces the plate for calibration captures;
//! [`chart::ColorChart`] is the colour chart mounted in the sample region for colour
//! calibration (its spectra; the layout and published references are
//! `btfrig_color::chart::ChartLayout`); [`rig_scene::RigScene`] assembles all of it from a rig
//! config.
//!
//! ```
//! use btfrig_core::{Direction, pose::ScenePose, config::plate::PlateConfig};
//! use btfrig_render::{material::MaterialSpec, renderer::{Pinhole, Renderer, RenderOptions}};
//!
//! let spec = MaterialSpec::builtin("corduroy").unwrap();
//! let flat = |name: &str| -> Result<([f64; 3], [f64; 3]), String> {
//!     // A toy colour system: every spectrum is a grey "flat:x"; anything else is mid grey.
//!     let x = name.strip_prefix("flat:").and_then(|v| v.parse().ok()).unwrap_or(0.5);
//!     Ok(([x; 3], [x; 3]))
//! };
//! let r = Renderer::new(&PlateConfig::default(), &spec.with_texels(32), 1000.0, &flat).unwrap();
//! let pose = ScenePose::looking_at(Direction::from_degrees(30.0, 0.0), Direction::from_degrees(0.0, 0.0), 1.5, 2.0);
//! let cam = Pinhole { width: 64, height: 48, fx: 300.0, fy: 300.0, cx: 31.5, cy: 23.5 };
//! let (img, stats) = r.render_with_stats(&pose, &cam, &RenderOptions::default());
//! assert_eq!(img.data.len(), 64 * 48);
//! assert!(stats.pixels_traced > 0);
//! ```
#![warn(missing_docs)]

// The files, one job each:
// - scene, plate, markers, material, heightfield, brdf: what is in front of the camera
// - renderer, radiance: ray tracing one frame to camera-RGB signal rates
// - ground_truth: the true texture on the sample plane
// - spectral, colour: spectra and the colour system
// - sensor:       the raw sensor model (docs/sensor-model.md)
// - chart, flat_field: the colour chart and the flat-field source of the calibrations
// - rig_scene, dome_scene: a gonio's and a dome's physics assembled from a rig config

pub mod brdf;
pub mod chart;
pub mod colour;
/// Demosaicing lives in `btfrig-imageio` (processing needs it without the simulator).
pub mod dome_scene;
pub mod flat_field;
pub mod ground_truth;
pub mod heightfield;
pub mod markers;
pub mod material;
pub mod plate;
pub mod radiance;
pub mod renderer;
pub mod rig_scene;
pub mod scene;
pub mod sensor;
pub mod spectral;
