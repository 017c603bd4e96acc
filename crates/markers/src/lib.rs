//! Detection of ArUco-style square markers (the holder plate's `DICT_4X4_50`) in a grey
//! image, with sub-pixel corners and a per-corner uncertainty. No I/O.
//!
//! Pipeline (details and measured accuracy in `docs/markers.md`):
//!
//! 1. adaptive threshold against the local mean (integral image);
//! 2. connected dark regions; a region touching the image border is dropped (a marker cut by
//!    the border cannot be located reliably);
//! 3. quad from the region's extreme pixels, checked (size, convexity, every region pixel
//!    inside the quad);
//! 4. sub-pixel edges: along many scanlines across each of the four edges, the edge offset
//!    from the profile's area (the position of the step with the same integral between the
//!    dark and light levels); a straight line fitted to each edge (optionally in undistorted
//!    coordinates of a [`CameraModel`]); corners are intersections of adjacent lines;
//! 5. edge model: each edge refined by fitting an area-sampled, blurred straight step to the
//!    pixel values around it, on the genuine green photosites when the image is recognised
//!    as a bilinear demosaic's green channel (or via [`detect_raw`]);
//! 6. unwarp of the 6x6 module grid with the homography of the refined corners, bit
//!    sampling, border check, match against the dictionary in all four rotations.
//!
//! Conventions (those of `btfrig_core::camera` and OpenCV): integer pixel coordinates are
//! pixel centres; corners are returned in the dictionary's canonical order (top-left,
//! top-right, bottom-right, bottom-left of the marker image as OpenCV draws it).
#![warn(missing_docs)]

// The files, one job each:
// - dictionary: the marker dictionaries' bits
// - detect/:    the detector, one file per step (its mod.rs lists them)

pub mod detect;
pub mod dictionary;

pub use detect::{
    detect, detect_in_windows, detect_raw, module_across, DetectError, DetectParams, Detection, GrayImage, GreenSites,
    Quality, Window, WindowSearch,
};
pub use dictionary::{Dictionary, DictionaryError};
