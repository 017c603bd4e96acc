//! Registration of one camera frame: detect the holder plate's markers in the image, pair
//! their corners with the plate layout, estimate the sample pose ([`crate::register`]).
//!
//! This is the glue the pipeline and the benchmark share, so both measure the same thing.
//!
//! Where the markers are searched ([`MarkerSearch`]): by default only in a window around each
//! marker's position predicted from the nominal pose, as far as the pose may be off (the
//! estimator's own tolerance, so no pose it would accept puts a marker outside its window);
//! the whole frame when that prediction misses. Inside its window a marker is found exactly
//! as in the whole frame (`btfrig_markers::detect_in_windows`), so the accuracy is the
//! whole-frame detector's.

use std::borrow::Cow;
use std::time::Instant;

use btfrig_core::camera::CameraModel;
use btfrig_core::config::plate::{MarkerPlacement, PlateConfig};
use btfrig_core::pose::ScenePose;
use btfrig_imaging::Mosaic;
use btfrig_markers::{
    detect, detect_in_windows, module_across, DetectError, DetectParams, Detection, Dictionary, GrayImage, GreenSites,
    Window, WindowSearch,
};
use nalgebra::{Isometry3, Point2, Point3, Vector3};

use crate::{register, sample_to_camera, Correspondence, RegisterError, RegisterOptions, Registration};

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
        /// Where the markers were searched.
        search: Box<SearchRecord>,
    },
}

/// A registered frame.
#[derive(Debug, Clone)]
pub struct FrameRegistration {
    /// The pose estimate and its diagnostics.
    pub registration: Registration,
    /// The detections the pose was estimated from (foreign ids included).
    pub detections: Vec<Detection>,
    /// Ids of the plate's markers that were detected, ascending.
    pub detected: Vec<u32>,
    /// Ids decoded in the image that are not on this plate (ignored).
    pub foreign: Vec<u32>,
    /// Seconds spent detecting markers.
    pub detect_s: f64,
    /// Seconds spent estimating the pose.
    pub register_s: f64,
    /// Where the markers were searched.
    pub search: SearchRecord,
}

/// Where [`PlateRegistrar::register_image`] searches for the markers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MarkerSearch {
    /// The whole frame, every time.
    WholeFrame,
    /// A window per plate marker around its projection with the nominal pose, grown by how far
    /// the sample may be from it: a rotation by up to `tolerance.0` degrees about the sample's
    /// origin and a shift by up to `tolerance.1` metres. `None`: learned from the frames this
    /// registrar has registered, [`LEARNED_FACTOR`] times the largest deviation of a measured
    /// pose from its nominal pose (at least [`LEARNED_FLOOR`]), never beyond the estimator's
    /// gate ([`RegisterOptions::max_rotation_deg`], [`RegisterOptions::max_translation_m`]),
    /// which is used until a frame has registered.
    /// The whole frame is searched when the windows give no pose, or when the measured pose
    /// puts a marker that lies inside the image outside its window.
    Predicted {
        /// `(rotation degrees, translation metres)`, or `None` to learn it.
        tolerance: Option<(f64, f64)>,
    },
}

/// Learned windows: this many times the largest deviation from the nominal pose seen so far.
pub const LEARNED_FACTOR: f64 = 3.0;
/// Learned windows: at least this tolerance (degrees, metres).
pub const LEARNED_FLOOR: (f64, f64) = (0.2, 0.001);

/// The largest deviation (rotation radians, translation metres) of a measured pose from its
/// nominal pose over the frames registered so far. Frames may be registered on several
/// threads at once, hence the lock; a clone starts from the same figures.
#[derive(Debug, Default)]
struct Deviation(std::sync::Mutex<Option<(f64, f64)>>);

impl Clone for Deviation {
    fn clone(&self) -> Self {
        Deviation(std::sync::Mutex::new(self.get()))
    }
}

impl Deviation {
    fn get(&self) -> Option<(f64, f64)> {
        *self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn observe(&self, rot: f64, trans: f64) {
        let mut g = self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let (r, t) = g.unwrap_or((0.0, 0.0));
        *g = Some((r.max(rot), t.max(trans)));
    }
}

/// How the markers of one frame were searched.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SearchRecord {
    /// Windows searched before any whole-frame search (0: none, the whole frame at once).
    pub windows: usize,
    /// Pixels searched in all (windows, plus the frame after a fallback).
    pub pixels: usize,
    /// Pixels of the frame.
    pub frame_pixels: usize,
    /// Whether the whole frame was searched.
    pub whole_frame: bool,
    /// Why the windows were not enough, when they were tried and the whole frame followed.
    pub fallback: Option<String>,
    /// The kind of `fallback`.
    pub cause: Option<FallbackCause>,
    /// Seconds the detection took (windows and any whole-frame search; as
    /// [`FrameRegistration::detect_s`], kept here for frames that failed to register).
    pub detect_s: f64,
    /// Seconds one whole-frame detection takes on this frame: measured when this frame's
    /// whole frame was searched, else the registrar's reference search (one per registrar,
    /// [`PlateRegistrar::time_whole_frame`]) scaled by pixels; `None` before any reference.
    pub whole_frame_s: Option<f64>,
    /// Seconds this frame spent on the registrar's reference whole-frame search (timed only,
    /// its result unused; 0 on every other frame).
    pub reference_s: f64,
}

/// Why the predicted windows were not enough.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FallbackCause {
    /// The markers found in the windows gave no pose.
    NoPose,
    /// The measured pose puts a marker inside the image outside every window.
    MarkerOutsideWindows,
}

impl FallbackCause {
    /// The name as journaled and reported.
    pub fn as_str(self) -> &'static str {
        match self {
            FallbackCause::NoPose => "no-pose",
            FallbackCause::MarkerOutsideWindows => "marker-outside-windows",
        }
    }
}

/// Seconds per pixel of a whole-frame detection, once measured, and whether a frame has
/// claimed the measurement (two frames in flight must not both pay for it).
#[derive(Debug, Default)]
struct WholeFrameCost {
    s_per_px: std::sync::Mutex<Option<f64>>,
    claimed: std::sync::atomic::AtomicBool,
}

impl Clone for WholeFrameCost {
    fn clone(&self) -> Self {
        let c = WholeFrameCost::default();
        *c.s_per_px.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = self.get();
        c
    }
}

impl WholeFrameCost {
    fn get(&self) -> Option<f64> {
        *self.s_per_px.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn observe(&self, seconds: f64, pixels: usize) {
        if pixels > 0 {
            let mut g = self.s_per_px.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            g.get_or_insert(seconds / pixels as f64);
        }
    }

    /// True once for the frame that is to measure (none measured or claimed yet).
    fn claim(&self) -> bool {
        self.get().is_none() && !self.claimed.swap(true, std::sync::atomic::Ordering::AcqRel)
    }
}

/// Directions of the tolerance ball sampled to bound a corner's image motion: the 26
/// neighbours of a cube's centre, normalised.
fn ball_directions() -> Vec<Vector3<f64>> {
    let mut out = Vec::with_capacity(26);
    for x in -1i32..=1 {
        for y in -1i32..=1 {
            for z in -1i32..=1 {
                if (x, y, z) != (0, 0, 0) {
                    out.push(Vector3::new(f64::from(x), f64::from(y), f64::from(z)).normalize());
                }
            }
        }
    }
    out
}

/// The grey image a frame's markers are searched in.
#[derive(Debug, Clone, Copy)]
pub enum GreyFrame<'a> {
    /// Given whole.
    Image(GrayImage<'a>),
    /// The green channel of the bilinear demosaic of this mosaic, computed only where the
    /// search reads (its windows, grown by what the threshold and the edge fits read around
    /// them; the whole frame when the search falls back to it): the same values there as
    /// the whole frame's demosaic.
    Mosaic(Mosaic<'a>),
}

/// Frame-sized grey buffers kept between frames, all zero: a mosaic's green is filled into
/// one, and the filled parts are zeroed again when it comes back (fresh zeroed pages would
/// cost a page fault per 4 KiB touched on every frame).
#[derive(Debug, Default)]
struct GreyBuffers(std::sync::Mutex<Vec<Vec<f32>>>);

impl Clone for GreyBuffers {
    fn clone(&self) -> Self {
        GreyBuffers::default()
    }
}

impl GreyBuffers {
    /// Buffers kept at most (a run processes two frames at once).
    const KEPT: usize = 2;

    fn take(&self, len: usize) -> Vec<f32> {
        let mut pool = self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        match pool.iter().position(|b| b.len() == len) {
            Some(i) => pool.swap_remove(i),
            None => vec![0.0; len],
        }
    }

    fn give(&self, buf: Vec<f32>) {
        let mut pool = self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if pool.len() < Self::KEPT {
            pool.push(buf);
        }
    }
}

/// A [`GreyFrame`] being read: a mosaic's green is filled in as the search asks for it, into
/// a frame-sized buffer that is zero elsewhere (and zeroed again when done).
struct Grey<'a> {
    source: GreyFrame<'a>,
    buf: Vec<f32>,
    /// The rectangles filled so far, `(x0, y0, x1, y1)` clipped to the frame.
    filled: Vec<(usize, usize, usize, usize)>,
    whole: bool,
    pool: &'a GreyBuffers,
}

impl<'a> Grey<'a> {
    fn new(source: GreyFrame<'a>, pool: &'a GreyBuffers) -> Self {
        let (buf, whole) = match source {
            GreyFrame::Image(_) => (Vec::new(), true),
            GreyFrame::Mosaic(m) => (pool.take(m.width * m.height), false),
        };
        Grey { source, buf, filled: Vec::new(), whole, pool }
    }

    fn size(&self) -> (usize, usize) {
        match self.source {
            GreyFrame::Image(i) => (i.width, i.height),
            GreyFrame::Mosaic(m) => (m.width, m.height),
        }
    }

    /// Makes the image valid over `windows` grown by `margin` pixels.
    fn prepare(&mut self, windows: &[Window], margin: usize) {
        if let (GreyFrame::Mosaic(m), false) = (&self.source, self.whole) {
            for w in windows {
                let grown = (
                    w.x0.saturating_sub(margin),
                    w.y0.saturating_sub(margin),
                    (w.x1 + margin).min(m.width),
                    (w.y1 + margin).min(m.height),
                );
                m.fill_green(grown, &mut self.buf);
                self.filled.push(grown);
            }
        }
    }

    /// Makes the whole image valid.
    fn prepare_all(&mut self) {
        if let (GreyFrame::Mosaic(m), false) = (&self.source, self.whole) {
            m.fill_green((0, 0, m.width, m.height), &mut self.buf);
            self.filled = vec![(0, 0, m.width, m.height)];
            self.whole = true;
        }
    }

    /// The image (valid where prepared).
    fn image(&self) -> Result<GrayImage<'_>, DetectError> {
        match self.source {
            GreyFrame::Image(i) => Ok(i),
            GreyFrame::Mosaic(m) => GrayImage::new(m.width, m.height, &self.buf),
        }
    }
}

impl Drop for Grey<'_> {
    fn drop(&mut self) {
        let GreyFrame::Mosaic(m) = self.source else { return };
        let mut buf = std::mem::take(&mut self.buf);
        for &(x0, y0, x1, y1) in &self.filled {
            for y in y0..y1 {
                buf[y * m.width + x0..y * m.width + x1].fill(0.0);
            }
        }
        self.pool.give(buf);
    }
}

/// Smallest module, in pixels across a marker edge, for which [`PlateRegistrar`] searches
/// regions on 2 x 2 means. Binning is safe from 6 px (3 binned px, the detector's smallest
/// module) and moves corners by ~1e-5 px; it pays where windows are large. 16 px takes the
/// 12 MP gonio views up to 45° (modules 22-33 px) and no 1600 x 1200 view (at most 13 px),
/// whose results, and the shipped calibrations made from them, stay the same bit for bit.
pub const BIN_MIN_MODULE_PX: f64 = 16.0;

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
    /// Where markers are searched (default: predicted windows, tolerance learned).
    pub search: MarkerSearch,
    /// With [`MarkerSearch::Predicted`]: time one whole-frame detection on the first frame
    /// that registered in its windows (its result is not used), so that every frame's
    /// [`SearchRecord::whole_frame_s`] says what the windows saved (default on; benches
    /// that time the search themselves turn it off).
    pub time_whole_frame: bool,
    /// With [`MarkerSearch::Predicted`]: search the windows for dark regions on 2 x 2 means
    /// when the nominal pose shows every marker large enough ([`Self::region_bin_for`];
    /// default on). The corners are fitted on the full image either way.
    pub bin_large_markers: bool,
    deviation: Deviation,
    whole_frame_cost: WholeFrameCost,
    grey_buffers: GreyBuffers,
}

impl PlateRegistrar {
    /// A registrar for frames of `camera` showing the plate `plate` (a validated section).
    pub fn new(camera: CameraModel, plate: &PlateConfig, options: RegisterOptions) -> Result<Self, FrameError> {
        let dictionary = Dictionary::by_name(&plate.marker_dictionary)
            .ok_or_else(|| FrameError::UnknownDictionary { name: plate.marker_dictionary.clone() })?;
        let detect = DetectParams { camera: Some(camera.clone()), ..DetectParams::default() };
        Ok(PlateRegistrar {
            camera,
            markers: plate.marker_placements(),
            dictionary,
            detect,
            options,
            search: MarkerSearch::Predicted { tolerance: None },
            time_whole_frame: true,
            bin_large_markers: true,
            deviation: Deviation::default(),
            whole_frame_cost: WholeFrameCost::default(),
            grey_buffers: GreyBuffers::default(),
        })
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

    /// The search window of each plate marker whose corners all project with `nominal`: the
    /// bounding box of the corners' images when each corner moves anywhere within
    /// `rotation_rad · |corner| + translation_m` of its nominal place (what a rotation about
    /// the sample's origin and a shift within the tolerance can do; the image motion of the
    /// sampled ball's rim is grown by a quarter for the points between the samples), plus a
    /// pad of 4 px and a twentieth of the marker's side for the border's blur (the threshold
    /// and the corner fits read the image around a window, so no quiet zone is needed inside).
    /// Clipped to the image; markers whose window is empty are left out.
    pub fn search_windows(&self, nominal: &ScenePose, rotation_rad: f64, translation_m: f64) -> Vec<(u32, Window)> {
        let cam = &self.camera;
        let t = sample_to_camera(nominal);
        let dirs = ball_directions();
        let mut out = Vec::with_capacity(self.markers.len());
        'markers: for m in &self.markers {
            let (mut lo, mut hi) =
                (Point2::new(f64::INFINITY, f64::INFINITY), Point2::new(f64::NEG_INFINITY, f64::NEG_INFINITY));
            let mut centre_px = [Point2::origin(); 4];
            for (k, c) in m.corners_sample_m.iter().enumerate() {
                let x = t * Point3::new(c.x, c.y, 0.0);
                let Some(p0) = cam.project(&x) else { continue 'markers };
                centre_px[k] = p0;
                let r = rotation_rad * c.coords.norm() + translation_m;
                for p in std::iter::once(p0)
                    .chain(dirs.iter().filter_map(|d| cam.project(&(x + d * r)).map(|p| p0 + (p - p0) * 1.25)))
                {
                    lo = Point2::new(lo.x.min(p.x), lo.y.min(p.y));
                    hi = Point2::new(hi.x.max(p.x), hi.y.max(p.y));
                }
            }
            let side = (0..4).map(|k| (centre_px[(k + 1) % 4] - centre_px[k]).norm()).fold(0.0, f64::max);
            let pad = 4.0 + 0.05 * side;
            let (x0, y0) = ((lo.x - pad).floor().max(0.0), (lo.y - pad).floor().max(0.0));
            let (x1, y1) = ((hi.x + pad).ceil() + 1.0, (hi.y + pad).ceil() + 1.0);
            if !(x1 > x0 && y1 > y0 && x0.is_finite() && y1.is_finite()) {
                continue;
            }
            let w = Window::new(
                x0 as usize,
                y0 as usize,
                x1.min(cam.width as f64) as usize,
                y1.min(cam.height as f64) as usize,
            );
            if w.area() > 0 {
                out.push((m.id, w));
            }
        }
        out
    }

    /// The windows of [`Self::search_windows`] for `tolerance` (degrees, metres), merged where
    /// that searches fewer pixels, and what the detector found in them.
    pub fn detect_predicted(
        &self,
        image: &GrayImage,
        nominal: &ScenePose,
        tolerance: (f64, f64),
    ) -> Result<(Vec<Window>, WindowSearch), DetectError> {
        self.detect_predicted_in(&mut Grey::new(GreyFrame::Image(*image), &self.grey_buffers), nominal, tolerance)
    }

    fn detect_predicted_in(
        &self,
        grey: &mut Grey,
        nominal: &ScenePose,
        tolerance: (f64, f64),
    ) -> Result<(Vec<Window>, WindowSearch), DetectError> {
        let per_marker = self.search_windows(nominal, tolerance.0.to_radians(), tolerance.1);
        let windows = merge_windows(per_marker.into_iter().map(|(_, w)| w).collect());
        grey.prepare(&windows, self.read_margin_px());
        let params = self.params_for(grey, self.region_bin_for(nominal));
        let found = detect_in_windows(&grey.image()?, &self.dictionary, &params, &windows)?;
        Ok((windows, found))
    }

    /// The detector settings for `grey` with the region search binned `bin` x `bin`. A
    /// mosaic's green photosites are known from its pattern, so [`GreenSites::Auto`] is
    /// replaced by them (as `btfrig_markers::detect_raw` does) instead of being recognised
    /// from the filled-in green (the same parity; recognising it was a sixth of a 12 MP
    /// search's time).
    fn params_for(&self, grey: &Grey, bin: usize) -> Cow<'_, DetectParams> {
        let sites = match (grey.source, self.detect.green_sites) {
            (GreyFrame::Mosaic(m), GreenSites::Auto) => match m.bayer {
                None => GreenSites::All,
                // Green sites have x + y of one parity in every Bayer layout.
                Some(b) if b.channel_at(0, 0) == 1 => GreenSites::Even,
                Some(_) => GreenSites::Odd,
            },
            (_, configured) => configured,
        };
        if sites == self.detect.green_sites && bin == self.detect.region_bin {
            Cow::Borrowed(&self.detect)
        } else {
            Cow::Owned(DetectParams { green_sites: sites, region_bin: bin, ..self.detect.clone() })
        }
    }

    /// The region search's binning for a frame at `nominal` ([`DetectParams::region_bin`]):
    /// 2 when every plate marker projects with modules of at least [`BIN_MIN_MODULE_PX`]
    /// across each of its edges ([`Self::smallest_module_px`]), else the detector's setting.
    /// With [`Self::bin_large_markers`] off, always the detector's setting.
    pub fn region_bin_for(&self, nominal: &ScenePose) -> usize {
        match self.smallest_module_px(nominal) {
            Some(m) if self.bin_large_markers && m >= BIN_MIN_MODULE_PX => 2,
            _ => self.detect.region_bin,
        }
    }

    /// The smallest module, in pixels across a marker edge, of the plate markers seen from
    /// `nominal` (`None` if a marker corner does not project).
    pub fn smallest_module_px(&self, nominal: &ScenePose) -> Option<f64> {
        let t = sample_to_camera(nominal);
        let modules = (self.dictionary.size + 2) as f64;
        let mut smallest = f64::INFINITY;
        for m in &self.markers {
            let mut q = [Point2::origin(); 4];
            for (k, c) in m.corners_sample_m.iter().enumerate() {
                q[k] = self.camera.project(&(t * Point3::new(c.x, c.y, 0.0)))?;
            }
            for i in 0..4 {
                smallest = smallest.min(module_across(&q, i, modules));
            }
        }
        Some(smallest)
    }

    /// How far beyond a search window the detector reads: the threshold's local mean (half
    /// its window), and at least the edge fits' bands and profiles and the module grid fit
    /// around a marker inside the window (at most 4 + 2 px beyond its outline), with 2 px to
    /// spare.
    fn read_margin_px(&self) -> usize {
        (self.detect.threshold_window_px / 2).max(8) + 2
    }

    /// Detects the markers in `image` (a grey image of the frame: the green channel of a
    /// Bayer camera carries half its photosites) and estimates the sample pose, with
    /// `nominal` (the kinematic pose) as prior and gate. Where it searches: [`Self::search`].
    /// A registered frame's deviation from `nominal` is remembered for the learned windows.
    pub fn register_image(&self, image: &GrayImage, nominal: &ScenePose) -> Result<FrameRegistration, FrameError> {
        self.register_grey(GreyFrame::Image(*image), nominal)
    }

    /// [`Self::register_image`] of a grey frame given whole or as a mosaic whose green is
    /// demosaiced only where the search reads ([`GreyFrame`]): the same registration.
    pub fn register_grey(&self, frame: GreyFrame, nominal: &ScenePose) -> Result<FrameRegistration, FrameError> {
        let mut grey = Grey::new(frame, &self.grey_buffers);
        let tolerance = match self.search {
            MarkerSearch::WholeFrame => None,
            MarkerSearch::Predicted { tolerance: Some(t) } => Some(t),
            MarkerSearch::Predicted { tolerance: None } => Some(self.learned_tolerance()),
        };
        let mut r = match self.register_in(&mut grey, nominal, tolerance) {
            Ok(r) => r,
            Err(FrameError::Register { detected, source, mut search }) => {
                self.account_whole_frame(&mut search);
                return Err(FrameError::Register { detected, source, search });
            }
            Err(e) => return Err(e),
        };
        self.remember(&r.registration, nominal);
        let pixels = r.search.frame_pixels;
        match r.search.whole_frame_s {
            Some(s) => self.whole_frame_cost.observe(s, pixels),
            None if self.time_whole_frame && self.whole_frame_cost.claim() => {
                let t = Instant::now();
                grey.prepare_all();
                detect(&grey.image()?, &self.dictionary, &self.params_for(&grey, self.detect.region_bin))?;
                let s = t.elapsed().as_secs_f64();
                self.whole_frame_cost.observe(s, pixels);
                r.search.reference_s = s;
            }
            None => {}
        }
        if r.search.whole_frame_s.is_none() {
            r.search.whole_frame_s = self.whole_frame_cost.get().map(|c| c * pixels as f64);
        }
        Ok(r)
    }

    /// [`Self::register_image`] with windows for `tolerance` (degrees, metres; `None`: the
    /// whole frame), remembering nothing.
    pub fn register_within(
        &self,
        image: &GrayImage,
        nominal: &ScenePose,
        tolerance: Option<(f64, f64)>,
    ) -> Result<FrameRegistration, FrameError> {
        self.register_in(&mut Grey::new(GreyFrame::Image(*image), &self.grey_buffers), nominal, tolerance)
    }

    /// [`Self::register_within`] of a [`GreyFrame`].
    pub fn register_grey_within(
        &self,
        frame: GreyFrame,
        nominal: &ScenePose,
        tolerance: Option<(f64, f64)>,
    ) -> Result<FrameRegistration, FrameError> {
        self.register_in(&mut Grey::new(frame, &self.grey_buffers), nominal, tolerance)
    }

    fn register_in(
        &self,
        grey: &mut Grey,
        nominal: &ScenePose,
        tolerance: Option<(f64, f64)>,
    ) -> Result<FrameRegistration, FrameError> {
        let (width, height) = grey.size();
        let frame_pixels = width * height;
        let Some((rot_deg, trans_m)) = tolerance else {
            let search = SearchRecord {
                windows: 0,
                pixels: frame_pixels,
                frame_pixels,
                whole_frame: true,
                ..SearchRecord::default()
            };
            return self.register_whole(grey, nominal, search, (0.0, 0.0));
        };
        let t = Instant::now();
        let (windows, found) = self.detect_predicted_in(grey, nominal, (rot_deg, trans_m))?;
        let detect_s = t.elapsed().as_secs_f64();
        let (corr, detected, foreign) = self.correspondences(&found.detections);
        let t = Instant::now();
        let attempt = register(&corr, &self.camera, nominal, &self.options);
        let register_s = t.elapsed().as_secs_f64();
        let miss = match &attempt {
            Ok(r) => self
                .missed_window(&r.sample_to_camera, &windows, width, height)
                .map(|m| (FallbackCause::MarkerOutsideWindows, m)),
            Err(e) => Some((FallbackCause::NoPose, format!("no pose from the windows: {e}"))),
        };
        match (attempt, miss) {
            (Ok(registration), None) => Ok(FrameRegistration {
                registration,
                detections: found.detections,
                detected,
                foreign,
                detect_s,
                register_s,
                search: SearchRecord {
                    windows: windows.len(),
                    pixels: found.pixels,
                    frame_pixels,
                    whole_frame: false,
                    detect_s,
                    ..SearchRecord::default()
                },
            }),
            (_, miss) => {
                let search = SearchRecord {
                    windows: windows.len(),
                    pixels: found.pixels + frame_pixels,
                    frame_pixels,
                    whole_frame: true,
                    cause: miss.as_ref().map(|m| m.0),
                    fallback: miss.map(|m| m.1),
                    ..SearchRecord::default()
                };
                self.register_whole(grey, nominal, search, (detect_s, register_s))
            }
        }
    }

    /// A failed frame's whole-frame search feeds the reference figure, or gets it.
    fn account_whole_frame(&self, search: &mut SearchRecord) {
        match search.whole_frame_s {
            Some(s) => self.whole_frame_cost.observe(s, search.frame_pixels),
            None => search.whole_frame_s = self.whole_frame_cost.get().map(|c| c * search.frame_pixels as f64),
        }
    }

    /// The window tolerance of `MarkerSearch::Predicted { tolerance: None }` (degrees, metres).
    pub fn learned_tolerance(&self) -> (f64, f64) {
        let gate = (self.options.max_rotation_deg, self.options.max_translation_m);
        match self.deviation.get() {
            None => gate,
            Some((rot, trans)) => (
                (LEARNED_FACTOR * rot.to_degrees()).max(LEARNED_FLOOR.0).min(gate.0),
                (LEARNED_FACTOR * trans).max(LEARNED_FLOOR.1).min(gate.1),
            ),
        }
    }

    /// Remembers how far `registration` is from `nominal` (for the learned windows).
    pub fn remember(&self, registration: &Registration, nominal: &ScenePose) {
        let d = crate::refine::difference(&registration.sample_to_camera, &sample_to_camera(nominal));
        self.deviation.observe(Vector3::new(d[0], d[1], d[2]).norm(), Vector3::new(d[3], d[4], d[5]).norm());
    }

    /// Whole-frame detection and registration; `spent` (detect, register seconds) is added.
    fn register_whole(
        &self,
        grey: &mut Grey,
        nominal: &ScenePose,
        mut search: SearchRecord,
        spent: (f64, f64),
    ) -> Result<FrameRegistration, FrameError> {
        let t = Instant::now();
        grey.prepare_all();
        let detections = detect(&grey.image()?, &self.dictionary, &self.params_for(grey, self.detect.region_bin))?;
        let whole_s = t.elapsed().as_secs_f64();
        search.whole_frame_s = Some(whole_s);
        let detect_s = spent.0 + whole_s;
        search.detect_s = detect_s;
        let (corr, detected, foreign) = self.correspondences(&detections);
        let t = Instant::now();
        let registration = register(&corr, &self.camera, nominal, &self.options).map_err(|source| {
            FrameError::Register { detected: detected.clone(), source, search: Box::new(search.clone()) }
        })?;
        let register_s = spent.1 + t.elapsed().as_secs_f64();
        Ok(FrameRegistration { registration, detections, detected, foreign, detect_s, register_s, search })
    }

    /// A plate marker that the measured pose `s2c` puts inside the image (clear of the
    /// detector's border margin) but inside no search window: the prediction missed it.
    fn missed_window(&self, s2c: &Isometry3<f64>, windows: &[Window], width: usize, height: usize) -> Option<String> {
        let m = self.detect.border_margin_px as f64;
        let in_image =
            |p: &Point2<f64>| p.x >= m && p.y >= m && p.x <= width as f64 - 1.0 - m && p.y <= height as f64 - 1.0 - m;
        for marker in &self.markers {
            let corners: Option<Vec<Point2<f64>>> = marker
                .corners_sample_m
                .iter()
                .map(|c| self.camera.project(&(s2c * Point3::new(c.x, c.y, 0.0))))
                .collect();
            let Some(corners) = corners else { continue };
            if !corners.iter().all(in_image) {
                continue;
            }
            // Two pixels inside a window's sides: the dark border's blur must not reach them.
            let inside = |w: &Window, p: &Point2<f64>| {
                p.x >= w.x0 as f64 + 2.0
                    && p.y >= w.y0 as f64 + 2.0
                    && p.x <= w.x1 as f64 - 3.0
                    && p.y <= w.y1 as f64 - 3.0
            };
            if !windows.iter().any(|w| corners.iter().all(|p| inside(w, p))) {
                return Some(format!("marker {} measured outside the search windows", marker.id));
            }
        }
        None
    }
}

/// Merges overlapping windows whose union is no larger than the two together, so that no
/// pixel is searched twice where one window does as well.
fn merge_windows(mut windows: Vec<Window>) -> Vec<Window> {
    loop {
        let mut merged = false;
        'outer: for i in 0..windows.len() {
            for j in i + 1..windows.len() {
                let u = windows[i].union(&windows[j]);
                if u.area() <= windows[i].area() + windows[j].area() {
                    windows[i] = u;
                    windows.swap_remove(j);
                    merged = true;
                    break 'outer;
                }
            }
        }
        if !merged {
            return windows;
        }
    }
}
