//! The simulated camera's physics: spectral colour, the raw sensor, demosaicing.
//!
//! Brief overview (camera/sensor/colour part): [`spectral`] holds the embedded published
//! spectra (CIE observer, lamps, camera sensitivities, ColorChecker); [`colour::ColourSystem`]
//! turns a reflectance spectrum into camera RGB and into the ground-truth output colour
//! (linear sRGB, D65, adapted); [`sensor::SensorModel`] turns a [`sensor::RadianceImage`] of
//! photo-electron rates into a noisy [`btfrig_core::frame::RawFrame`]; [`demosaic`] makes
//! previews from raw frames.
#![warn(missing_docs)]

pub mod colour;
pub mod demosaic;
pub mod sensor;
pub mod spectral;
