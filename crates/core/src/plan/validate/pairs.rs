//! `[sampling] pairs` and `[sparse]`: which (light, view) pairs are requested.

use crate::kinematics::Unreachable;

use super::UnreachablePair;
use crate::plan::limits;
use crate::plan::{PairsSpec, PlanError, SparseSpec};

/// The requested pairs; more than `max_pairs` (`[limits] max_captures`) are refused from
/// their count, before the list is built.
pub(super) fn resolve_pairs(
    spec: &PairsSpec,
    nl: usize,
    nv: usize,
    max_pairs: usize,
    errors: &mut Vec<PlanError>,
) -> Option<Vec<(usize, usize)>> {
    let allowed_modes = "\"all\", or a list of [light_index, view_index]";
    let count = match spec {
        PairsSpec::List(list) => list.len(),
        PairsSpec::Mode(_) => nl.saturating_mul(nv),
    };
    if count > max_pairs {
        let value = match spec {
            PairsSpec::List(_) => format!("{count} pairs"),
            PairsSpec::Mode(m) => format!("{m:?}: {count} pairs ({nl} light x {nv} view directions)"),
        };
        errors.push(PlanError::TooLarge {
            field: "sampling.pairs".into(),
            value,
            limit: format!("{max_pairs} requested pairs per plan (limits.max_captures)"),
            remedy: limits::raise_captures(),
        });
        return None;
    }
    match spec {
        PairsSpec::Mode(m) if m == "all" => Some((0..nl).flat_map(|l| (0..nv).map(move |v| (l, v))).collect()),
        PairsSpec::Mode(m) => {
            errors.push(PlanError::unknown("sampling.pairs", m, allowed_modes));
            None
        }
        PairsSpec::List(list) => {
            let n_before = errors.len();
            if list.is_empty() {
                errors.push(PlanError::invalid("sampling.pairs", "[]", "no pairs", allowed_modes));
            }
            let mut seen = std::collections::HashMap::new();
            let mut out = Vec::with_capacity(list.len());
            for (k, [l, v]) in list.iter().copied().enumerate() {
                let field = format!("sampling.pairs[{k}]");
                let ok = l >= 0 && (l as u64) < nl as u64 && v >= 0 && (v as u64) < nv as u64;
                if !ok {
                    errors.push(PlanError::out_of_range(
                        field,
                        format!("[{l}, {v}]"),
                        format!(
                            "light index 0..={}, view index 0..={} (indices into the filtered samplings)",
                            nl - 1,
                            nv - 1
                        ),
                    ));
                    continue;
                }
                let p = (l as usize, v as usize);
                if let Some(first) = seen.insert(p, k) {
                    errors.push(PlanError::invalid(
                        field,
                        format!("[{l}, {v}]"),
                        format!("the same pair as sampling.pairs[{first}]"),
                        "each pair once",
                    ));
                }
                out.push(p);
            }
            (errors.len() == n_before).then_some(out)
        }
    }
}

/// Checks the `[sparse]` subset: not empty, every pair in range, once, among the requested
/// pairs and reachable.
pub(super) fn resolve_sparse(
    sp: &SparseSpec,
    n_light: usize,
    n_view: usize,
    pairs: &[(usize, usize)],
    unreachable: &[UnreachablePair],
    errors: &mut Vec<PlanError>,
) -> Option<std::collections::BTreeSet<(usize, usize)>> {
    if sp.pairs.is_empty() {
        errors.push(PlanError::invalid("sparse.pairs", "[]", "no pairs", "at least one [light, view] pair"));
        return None;
    }
    let requested: std::collections::HashSet<(usize, usize)> = pairs.iter().copied().collect();
    let blocked: std::collections::HashMap<(usize, usize), &Unreachable> =
        unreachable.iter().map(|u| ((u.light, u.view), &u.reason)).collect();
    let mut first_at: std::collections::HashMap<(usize, usize), usize> = std::collections::HashMap::new();
    let before = errors.len();
    for (i, &[l, v]) in sp.pairs.iter().enumerate() {
        let field = format!("sparse.pairs[{i}]");
        if l >= n_light || v >= n_view {
            errors.push(PlanError::out_of_range(
                field,
                format!("[{l}, {v}]"),
                format!("light 0..={}, view 0..={} (indices into the filtered samplings)", n_light - 1, n_view - 1),
            ));
            continue;
        }
        if let Some(&j) = first_at.get(&(l, v)) {
            errors.push(PlanError::invalid(
                field,
                format!("[{l}, {v}]"),
                format!("repeats sparse.pairs[{j}]"),
                "each pair once",
            ));
            continue;
        }
        first_at.insert((l, v), i);
        if !requested.contains(&(l, v)) {
            errors.push(PlanError::invalid(
                field,
                format!("[{l}, {v}]"),
                "is not among the requested pairs (sampling.pairs)",
                "a subset of the requested pairs",
            ));
        } else if let Some(r) = blocked.get(&(l, v)) {
            errors.push(PlanError::invalid(
                field,
                format!("[{l}, {v}]"),
                format!("the rig cannot reach it ({r})"),
                "pairs the rig can reach",
            ));
        }
    }
    (errors.len() == before).then(|| first_at.into_keys().collect())
}
