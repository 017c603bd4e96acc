//! Ordering the captures to minimise hardware time. Heuristic and reasoning in
//! `docs/planner.md`.
//!
//! Under the timing model the total time of an order `o` is exactly
//! `first_gap(o[0]) + sum_k gap(o[k-1], o[k]) + transfer(o[n-1]) + sum of triggers`, where
//! `gap(a, b) = max(move(a, b), transfer(a) + command(a -> b))` is the time from the end of
//! `a`'s trigger to the start of `b`'s. So ordering is a shortest Hamiltonian path with
//! edge cost `gap`; an edge is *hidden* when its move fits under the transfer it overlaps.
//! Construction: nearest neighbour by (gap, move time); improvement: 2-opt (when the costs
//! are symmetric) and Or-opt, each aimed at the edges that are not hidden. No randomness.
//!
//! Bounded for large plans: up to [`EXACT_MAX_CAPTURES`] captures the construction is the
//! exact nearest neighbour and the improvement moves may reach anywhere; beyond, the
//! construction looks at [`LARGE_WINDOW`] candidates on each side in rail angle and the
//! moves reach [`LARGE_WINDOW`] positions, so the work grows as n log n, not n squared.
//! Every loop checks a [`Cancel`] flag.

use crate::expand::PlanCapture;
use crate::timing::{Start, TimingModel};
use crate::{Cancel, PlanError};

/// Largest number of captures ordered without bounds (the full Bonn plan has 6561 pairs).
pub const EXACT_MAX_CAPTURES: usize = 10_000;
/// Candidates per side (construction) and positions (improvement) considered beyond
/// [`EXACT_MAX_CAPTURES`].
pub const LARGE_WINDOW: usize = 64;
/// Improvement passes beyond [`EXACT_MAX_CAPTURES`] (each is O(n x window)).
pub const LARGE_MAX_PASSES: usize = 3;

/// Limits of the improvement phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OrderOptions {
    /// Maximum number of improvement passes over the order (each pass visits every edge
    /// that is not hidden). 0: nearest neighbour only.
    pub max_passes: usize,
    /// Longest segment Or-opt moves elsewhere (1..=3 is usual; 0 disables Or-opt).
    pub or_opt_max_len: usize,
}

impl Default for OrderOptions {
    fn default() -> Self {
        OrderOptions { max_passes: 20, or_opt_max_len: 3 }
    }
}

/// The naive nested loop: for each view, for each light, in sampling order.
pub fn naive_order(captures: &[PlanCapture]) -> Vec<usize> {
    let mut o: Vec<usize> = (0..captures.len()).collect();
    o.sort_by_key(|&i| (captures[i].view_index, captures[i].light_index, i));
    o
}

/// Tolerance below which a change in seconds counts as no change.
const EPS: f64 = 1e-9;

struct Ctx<'a> {
    model: &'a TimingModel,
    caps: &'a [PlanCapture],
    start: &'a Start,
}

impl Ctx<'_> {
    /// Cost of the edge between two consecutive positions; `None` is the start (as `a`)
    /// or the end (as `b`).
    fn edge(&self, a: Option<usize>, b: Option<usize>) -> f64 {
        match (a, b) {
            (Some(a), Some(b)) => self.model.gap_s(&self.caps[a], &self.caps[b]),
            (None, Some(b)) => self.model.first_gap_s(self.start, &self.caps[b]),
            (Some(a), None) => self.model.transfer_s(self.caps[a].frame_bytes),
            (None, None) => 0.0,
        }
    }

    /// The least an edge leaving `a` can cost: its transfer.
    fn floor(&self, a: Option<usize>) -> f64 {
        a.map_or(0.0, |a| self.model.transfer_s(self.caps[a].frame_bytes))
    }
}

fn at(o: &[usize], k: isize) -> Option<usize> {
    if k < 0 {
        None
    } else {
        o.get(k as usize).copied()
    }
}

/// An order of `captures` (a permutation of `0..captures.len()`) with low
/// [`TimingModel::schedule_time`]. Deterministic.
pub fn optimise_order(model: &TimingModel, captures: &[PlanCapture], start: &Start, opts: &OrderOptions) -> Vec<usize> {
    optimise_order_cancellable(model, captures, start, opts, &Cancel::new()).expect("never cancelled")
}

/// [`optimise_order`], stopping with [`PlanError::Cancelled`] soon after `cancel` is set.
pub fn optimise_order_cancellable(
    model: &TimingModel,
    captures: &[PlanCapture],
    start: &Start,
    opts: &OrderOptions,
    cancel: &Cancel,
) -> Result<Vec<usize>, PlanError> {
    let ctx = Ctx { model, caps: captures, start };
    let large = captures.len() > EXACT_MAX_CAPTURES;
    let window = large.then_some(LARGE_WINDOW);
    let mut o = nearest_neighbour(&ctx, window, cancel)?;
    let symmetric =
        captures.windows(2).all(|w| w[0].frame_bytes == w[1].frame_bytes && w[0].exposure_s == w[1].exposure_s);
    let passes = if large { opts.max_passes.min(LARGE_MAX_PASSES) } else { opts.max_passes };
    let reach = window.unwrap_or(usize::MAX);
    for _ in 0..passes {
        if !improve_pass(&ctx, &mut o, symmetric, opts.or_opt_max_len, reach, cancel)? {
            break;
        }
    }
    Ok(o)
}

/// Greedy construction: from the start, always the unvisited capture with the smallest
/// (gap, move time, index). Candidates are scanned outwards in rail angle and the scan on a
/// side stops once the rail move alone rules every further candidate out, or (with
/// `window`) after that many candidates. Without a window the result is the exact nearest
/// neighbour order (a test compares it with the O(n^2) search). The unvisited captures are a
/// doubly linked list in rail order, so taking one out is O(1).
fn nearest_neighbour(ctx: &Ctx, window: Option<usize>, cancel: &Cancel) -> Result<Vec<usize>, PlanError> {
    let n = ctx.caps.len();
    if n == 0 {
        return Ok(Vec::new());
    }
    let rail: Vec<f64> = ctx.caps.iter().map(|c| c.joints.rail).collect();
    let key = |i: usize| (rail[i], i);
    let mut sorted: Vec<usize> = (0..n).collect();
    sorted.sort_by(|&a, &b| key(a).partial_cmp(&key(b)).expect("finite rail angles"));
    // Position of each capture in `sorted`, and the unvisited neighbours of each position.
    let mut pos = vec![0usize; n];
    for (k, &i) in sorted.iter().enumerate() {
        pos[i] = k;
    }
    const NONE: usize = usize::MAX;
    let mut prev: Vec<usize> = (0..n).map(|k| k.checked_sub(1).unwrap_or(NONE)).collect();
    let mut next: Vec<usize> = (0..n).map(|k| if k + 1 < n { k + 1 } else { NONE }).collect();
    let first = (0..n)
        .map(|i| {
            let m = ctx.model.move_s(ctx.start.joints.as_ref(), &ctx.caps[i].joints);
            (ctx.edge(None, Some(i)), m, i)
        })
        .min_by(|a, b| a.partial_cmp(b).expect("finite times"))
        .expect("non-empty")
        .2;
    let t = &ctx.model.timing().rail;
    let rail_time = |d_rad: f64| {
        let m = btfrig_core::profile::move_time_s(d_rad.to_degrees(), t.max_speed_deg_per_s, t.accel_deg_per_s2);
        if m > 0.0 {
            m + t.settle_s
        } else {
            0.0
        }
    };
    let limit = window.unwrap_or(usize::MAX);
    let mut order = Vec::with_capacity(n);
    let mut cur = first;
    loop {
        cancel.check()?;
        let k = pos[cur];
        let (l0, r0) = (prev[k], next[k]);
        if l0 != NONE {
            next[l0] = r0;
        }
        if r0 != NONE {
            prev[r0] = l0;
        }
        order.push(cur);
        if order.len() == n {
            break;
        }
        let floor = ctx.floor(Some(cur));
        let mut best = (f64::INFINITY, f64::INFINITY, usize::MAX);
        let consider = |j: usize, best: &mut (f64, f64, usize)| -> bool {
            let rt = rail_time(rail[j] - rail[cur]);
            let lb_gap = rt.max(floor);
            if lb_gap > best.0 || (lb_gap >= best.0 && rt > best.1) {
                return false;
            }
            let m = ctx.model.move_time(&ctx.caps[cur].joints, &ctx.caps[j].joints).total_s();
            let cand = (ctx.edge(Some(cur), Some(j)), m, j);
            if cand < *best {
                *best = cand;
            }
            true
        };
        // Scan both sides alternately so that a good candidate is found early.
        let (mut l, mut r) = (l0, r0);
        let (mut seen_l, mut seen_r) = (0usize, 0usize);
        while l != NONE || r != NONE {
            if r != NONE {
                r = if seen_r < limit && consider(sorted[r], &mut best) { next[r] } else { NONE };
                seen_r += 1;
            }
            if l != NONE {
                l = if seen_l < limit && consider(sorted[l], &mut best) { prev[l] } else { NONE };
                seen_l += 1;
            }
        }
        // The first candidate on either side is always evaluated, so `best` names one.
        cur = best.2;
    }
    Ok(order)
}

/// One pass over the edges that are not hidden; returns whether anything improved.
/// Moves reach at most `reach` positions from the edge.
fn improve_pass(
    ctx: &Ctx,
    o: &mut Vec<usize>,
    symmetric: bool,
    max_len: usize,
    reach: usize,
    cancel: &Cancel,
) -> Result<bool, PlanError> {
    let mut improved = false;
    let mut k = 1;
    while k < o.len() {
        cancel.check()?;
        let (a, b) = (o[k - 1], o[k]);
        if ctx.edge(Some(a), Some(b)) > ctx.floor(Some(a)) + EPS
            && ((symmetric && two_opt(ctx, o, k, reach)) || or_opt(ctx, o, k, max_len, reach))
        {
            improved = true;
        }
        k += 1;
    }
    Ok(improved)
}

/// Best reversal of `o[k..m]` for the edge entering position `k`; applies it if it helps.
/// Only valid for symmetric edge costs between captures (checked by the caller).
fn two_opt(ctx: &Ctx, o: &mut [usize], k: usize, reach: usize) -> bool {
    let n = o.len();
    let (a, b) = (Some(o[k - 1]), Some(o[k]));
    let old_ab = ctx.edge(a, b);
    let mut best = (-EPS, 0);
    // Reverse o[k..m]: edges (a, b) and (o[m-1], o[m]) become (a, o[m-1]) and (b, o[m]).
    for m in k + 2..=n.min(k.saturating_add(reach)) {
        let (c, d) = (Some(o[m - 1]), at(o, m as isize));
        let delta = ctx.edge(a, c) + ctx.edge(b, d) - old_ab - ctx.edge(c, d);
        if delta < best.0 {
            best = (delta, m);
        }
    }
    // Reverse o[m..k] for m < k - 1: edges (o[m-1], o[m]) and (a, b) become (o[m-1], a) and
    // (o[m], b). The two end edges are computed exactly, so m = 0 (from the start) is fine.
    for m in k.saturating_sub(reach)..k.saturating_sub(1) {
        let (c, d) = (at(o, m as isize - 1), Some(o[m]));
        let delta = ctx.edge(c, a) + ctx.edge(d, b) - old_ab - ctx.edge(c, d);
        if delta < best.0 {
            best = (delta, m);
        }
    }
    if best.0 >= -EPS {
        return false;
    }
    let m = best.1;
    if m > k {
        o[k..m].reverse();
    } else {
        o[m..k].reverse();
    }
    true
}

/// Moves a segment of up to `max_len` captures next to the edge entering position `k` (the
/// segment ending at `k - 1` or starting at `k`) to its best place elsewhere, possibly
/// reversed; applies the best move if it helps.
fn or_opt(ctx: &Ctx, o: &mut Vec<usize>, k: usize, max_len: usize, reach: usize) -> bool {
    let n = o.len();
    // (delta, segment start, length, reversed, insertion position in the reduced order)
    let mut best: Option<(f64, usize, usize, bool, usize)> = None;
    for len in 1..=max_len.min(n.saturating_sub(1)) {
        let starts = [k.checked_sub(len), Some(k)];
        for s in starts.into_iter().flatten() {
            if s + len > n {
                continue;
            }
            let seg = &o[s..s + len];
            let (p, q) = (at(o, s as isize - 1), at(o, (s + len) as isize));
            let internal = |rev: bool| -> f64 {
                (1..len)
                    .map(|i| {
                        if rev {
                            ctx.edge(Some(seg[len - i]), Some(seg[len - i - 1]))
                        } else {
                            ctx.edge(Some(seg[i - 1]), Some(seg[i]))
                        }
                    })
                    .sum()
            };
            let removal =
                ctx.edge(p, q) - ctx.edge(p, Some(seg[0])) - ctx.edge(Some(seg[len - 1]), q) - internal(false);
            for rev in [false, true] {
                if rev && len == 1 {
                    continue;
                }
                let (first, last) = if rev { (seg[len - 1], seg[0]) } else { (seg[0], seg[len - 1]) };
                let inner = internal(rev);
                // Insert between r[j-1] and r[j] of the order without the segment.
                let reduced = |j: isize| -> Option<usize> {
                    if j < 0 {
                        None
                    } else if (j as usize) < s {
                        Some(o[j as usize])
                    } else {
                        at(o, j + len as isize)
                    }
                };
                for j in s.saturating_sub(reach)..=(n - len).min(s.saturating_add(reach)) {
                    if j == s && !rev {
                        continue; // the segment's own place
                    }
                    let (u, v) = (reduced(j as isize - 1), reduced(j as isize));
                    let delta = removal + ctx.edge(u, Some(first)) + inner + ctx.edge(Some(last), v) - ctx.edge(u, v);
                    if delta < best.map_or(-EPS, |b| b.0) {
                        best = Some((delta, s, len, rev, j));
                    }
                }
            }
        }
    }
    let Some((_, s, len, rev, j)) = best else {
        return false;
    };
    let mut seg: Vec<usize> = o.drain(s..s + len).collect();
    if rev {
        seg.reverse();
    }
    o.splice(j..j, seg);
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{expand, PairSelection};
    use btfrig_core::config::{geometry::GonioGeometry, timing::TimingConfig};
    use btfrig_core::kinematics::Gonio;
    use btfrig_core::sampling::Sampling;
    use rand::seq::SliceRandom;
    use rand::SeedableRng;

    /// The definition: from the start, always the unvisited capture with the smallest
    /// (gap, move time, index), searched over all of them.
    fn brute_force_nearest_neighbour(ctx: &Ctx) -> Vec<usize> {
        let n = ctx.caps.len();
        let mut left: Vec<usize> = (0..n).collect();
        let mut order = Vec::with_capacity(n);
        let mut cur: Option<usize> = None;
        while !left.is_empty() {
            let cost = |j: usize| -> (f64, f64, usize) {
                match cur {
                    None => {
                        (ctx.edge(None, Some(j)), ctx.model.move_s(ctx.start.joints.as_ref(), &ctx.caps[j].joints), j)
                    }
                    Some(c) => (
                        ctx.edge(Some(c), Some(j)),
                        ctx.model.move_time(&ctx.caps[c].joints, &ctx.caps[j].joints).total_s(),
                        j,
                    ),
                }
            };
            let k = (0..left.len()).min_by(|&a, &b| cost(left[a]).partial_cmp(&cost(left[b])).unwrap()).unwrap();
            cur = Some(left.swap_remove(k));
            order.push(cur.unwrap());
        }
        order
    }

    fn timings() -> Vec<TimingConfig> {
        // Motion five times slower: moves are no longer hidden under transfers.
        let mut slow = TimingConfig::bonn();
        slow.robot.max_speed_deg_per_s = slow.robot.max_speed_deg_per_s.map(|v| v / 5.0);
        slow.robot.accel_deg_per_s2 = slow.robot.accel_deg_per_s2.map(|v| v / 5.0);
        slow.rail.max_speed_deg_per_s /= 5.0;
        slow.rail.accel_deg_per_s2 /= 5.0;
        vec![TimingConfig::bonn(), slow]
    }

    #[test]
    fn nearest_neighbour_equals_the_brute_force_search_on_random_plans() {
        let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
        let s = Sampling::bonn81();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(24);
        let all: Vec<(usize, usize)> = (0..81).flat_map(|l| (0..81).map(move |v| (l, v))).collect();
        for timing in timings() {
            let model = TimingModel::new(&timing);
            for n in [1, 2, 17, 300, 900] {
                let pairs: Vec<(usize, usize)> = all.choose_multiple(&mut rng, n).copied().collect();
                let ex = expand(&gonio, &s, &s, &PairSelection::List(pairs), 0.01, 12_000_000).unwrap();
                let start = Start::homed();
                let ctx = Ctx { model: &model, caps: &ex.captures, start: &start };
                let want = brute_force_nearest_neighbour(&ctx);
                assert_eq!(nearest_neighbour(&ctx, None, &Cancel::new()).unwrap(), want, "{n} captures");
                // A window as wide as the plan changes nothing.
                let wide = Some(ex.captures.len().max(1));
                assert_eq!(nearest_neighbour(&ctx, wide, &Cancel::new()).unwrap(), want, "{n} captures, wide window");
            }
        }
    }

    #[test]
    fn a_set_cancel_flag_stops_the_ordering() {
        let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
        let s = Sampling::bonn81();
        let ex = expand(&gonio, &s, &s, &PairSelection::All, 0.01, 12_000_000).unwrap();
        let model = TimingModel::new(&TimingConfig::bonn());
        let cancel = Cancel::new();
        cancel.cancel();
        let r = optimise_order_cancellable(&model, &ex.captures, &Start::homed(), &OrderOptions::default(), &cancel);
        assert_eq!(r, Err(PlanError::Cancelled));
    }
}
