//! Expansion: requested (light, view) pairs -> captures with joint states, or skips with
//! reasons.

use std::fmt;

use btfrig_core::kinematics::{Gonio, JointState, Unreachable, UnreachableKind};
use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;

use crate::PlanError;

/// Which (light, view) pairs a plan asks for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PairSelection {
    /// Every light with every view.
    All,
    /// These `(light_index, view_index)` pairs, each at most once.
    List(Vec<(usize, usize)>),
}

/// One capture the rig will make: the pair, the joints that realise it, and what the camera
/// does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanCapture {
    /// Index into the light sampling.
    pub light_index: usize,
    /// Index into the view sampling.
    pub view_index: usize,
    /// The light direction (sample frame).
    pub light: Direction,
    /// The view direction (sample frame).
    pub view: Direction,
    /// Joint values from inverse kinematics.
    pub joints: JointState,
    /// Exposure time, seconds.
    pub exposure_s: f64,
    /// Bytes the camera sends to the host for this frame.
    pub frame_bytes: u64,
}

/// Why a requested pair is not captured.
#[derive(Debug, Clone, PartialEq)]
pub enum SkipReason {
    /// The rig cannot realise the pair.
    Unreachable(Unreachable),
    /// The pair is not needed (e.g. redundant by reciprocity); filled in by later stages.
    NotNeeded {
        /// Why, in words.
        why: String,
    },
}

impl fmt::Display for SkipReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SkipReason::Unreachable(u) => write!(f, "unreachable: {u}"),
            SkipReason::NotNeeded { why } => write!(f, "not needed: {why}"),
        }
    }
}

/// The class of a [`SkipReason`], for counting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SkipKind {
    /// See [`SkipReason::Unreachable`].
    Unreachable(UnreachableKind),
    /// See [`SkipReason::NotNeeded`].
    NotNeeded,
}

impl SkipKind {
    /// Every kind in report order: the unreachable kinds in check order, then not needed.
    pub fn all() -> Vec<SkipKind> {
        UnreachableKind::ALL.iter().map(|&k| SkipKind::Unreachable(k)).chain([SkipKind::NotNeeded]).collect()
    }

    /// A short label for tables and JSON keys (e.g. "camera blocks lamp", "not needed").
    pub fn label(self) -> &'static str {
        match self {
            SkipKind::Unreachable(k) => k.label(),
            SkipKind::NotNeeded => "not needed",
        }
    }
}

impl SkipReason {
    /// The class of this reason.
    pub fn kind(&self) -> SkipKind {
        match self {
            SkipReason::Unreachable(u) => SkipKind::Unreachable(u.kind()),
            SkipReason::NotNeeded { .. } => SkipKind::NotNeeded,
        }
    }
}

/// A requested pair that will not be captured.
#[derive(Debug, Clone, PartialEq)]
pub struct Skip {
    /// Index into the light sampling.
    pub light_index: usize,
    /// Index into the view sampling.
    pub view_index: usize,
    /// Why.
    pub reason: SkipReason,
}

/// The result of expanding a selection of pairs.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Expansion {
    /// Reachable pairs, in request order (for `All`: view-major, i.e. for each view every
    /// light, the naive nested loop).
    pub captures: Vec<PlanCapture>,
    /// Pairs that will not be captured, in request order.
    pub skipped: Vec<Skip>,
}

impl Expansion {
    /// Number of skips per kind, non-zero kinds only, in [`SkipKind::all`] order.
    pub fn skip_counts(&self) -> Vec<(SkipKind, usize)> {
        skip_counts(&self.skipped)
    }

    /// Moves the captures for which `not_needed` returns a reason to the skip list, keeping
    /// the order of both lists. The hook for reciprocity or coverage rules.
    pub fn mark_not_needed(&mut self, mut not_needed: impl FnMut(&PlanCapture) -> Option<String>) {
        let mut kept = Vec::with_capacity(self.captures.len());
        for c in self.captures.drain(..) {
            match not_needed(&c) {
                Some(why) => self.skipped.push(Skip {
                    light_index: c.light_index,
                    view_index: c.view_index,
                    reason: SkipReason::NotNeeded { why },
                }),
                None => kept.push(c),
            }
        }
        self.captures = kept;
    }
}

/// Counts skips per kind, non-zero kinds only, in [`SkipKind::all`] order.
pub fn skip_counts(skipped: &[Skip]) -> Vec<(SkipKind, usize)> {
    SkipKind::all()
        .into_iter()
        .map(|k| (k, skipped.iter().filter(|s| s.reason.kind() == k).count()))
        .filter(|&(_, n)| n > 0)
        .collect()
}

/// Runs inverse kinematics for every selected pair. Every capture gets the same
/// `exposure_s` and `frame_bytes` (callers may change `PlanCapture::exposure_s` per capture
/// afterwards). Fails on an index outside a sampling, a repeated pair, a non-positive or
/// non-finite exposure, or zero frame bytes.
pub fn expand(
    gonio: &Gonio,
    lights: &Sampling,
    views: &Sampling,
    pairs: &PairSelection,
    exposure_s: f64,
    frame_bytes: u64,
) -> Result<Expansion, PlanError> {
    if !(exposure_s > 0.0 && exposure_s.is_finite()) {
        return Err(PlanError::BadExposure { exposure_s });
    }
    if frame_bytes == 0 {
        return Err(PlanError::ZeroFrameBytes);
    }
    let list: Vec<(usize, usize)> = match pairs {
        PairSelection::All => (0..views.len()).flat_map(|v| (0..lights.len()).map(move |l| (l, v))).collect(),
        PairSelection::List(l) => l.clone(),
    };
    let mut seen = vec![false; lights.len() * views.len()];
    let mut out = Expansion::default();
    for (light_index, view_index) in list {
        if light_index >= lights.len() || view_index >= views.len() {
            return Err(PlanError::PairOutOfRange {
                light_index,
                view_index,
                lights: lights.len(),
                views: views.len(),
            });
        }
        let slot = &mut seen[light_index * views.len() + view_index];
        if *slot {
            return Err(PlanError::DuplicatePair { light_index, view_index });
        }
        *slot = true;
        let light = lights.get(light_index);
        let view = views.get(view_index);
        match gonio.ik(light, view) {
            Ok(joints) => {
                out.captures.push(PlanCapture { light_index, view_index, light, view, joints, exposure_s, frame_bytes })
            }
            Err(u) => out.skipped.push(Skip { light_index, view_index, reason: SkipReason::Unreachable(u) }),
        }
    }
    Ok(out)
}
