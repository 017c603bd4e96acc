//! `[sampling.light]` and `[sampling.view]`: presets, lists and rings, their filters, and
//! duplicate directions.

use crate::direction::{angle_between, Direction};
use crate::sampling::{Sampling, BONN81_RINGS, BONN_DOME1_RINGS, DUPLICATE_TOLERANCE_RAD};

use crate::plan::limits::MAX_DIRECTIONS;
use crate::plan::{PlanError, SamplingSpec, SamplingTable};

/// Sampling presets a plan may name, with their directions' source.
const PRESETS: &str = "\"bonn81\", \"dome1-151\"";

/// One candidate direction with the field path it came from (for duplicate messages).
struct Candidate {
    dir: Direction,
    source_index: usize,
    field: String,
    written: String,
}

/// The directions a sampling keeps after its filters, before the [`Sampling`] (and its
/// triangulation) is built.
pub(super) struct KeptDirections {
    name: String,
    pub(super) dirs: Vec<Direction>,
    indices: Vec<usize>,
}

impl KeptDirections {
    pub(super) fn build(self, prefix: &str, errors: &mut Vec<PlanError>) -> Option<(Sampling, Vec<usize>)> {
        match Sampling::from_list(&self.name, self.dirs) {
            Ok(s) => Some((s, self.indices)),
            Err(e) => {
                // Unreachable after the checks of `resolve_sampling`; reported rather than panicking.
                errors.push(PlanError::invalid(prefix, &self.name, e.to_string(), "a valid sampling"));
                None
            }
        }
    }
}

pub(super) fn resolve_sampling(
    spec: &SamplingSpec,
    prefix: &str,
    errors: &mut Vec<PlanError>,
) -> Option<KeptDirections> {
    let table = match spec {
        SamplingSpec::Preset(p) => SamplingTable { preset: Some(p.clone()), ..Default::default() },
        SamplingSpec::Table(t) => t.clone(),
    };
    let n_before = errors.len();
    let sources = [table.preset.is_some(), table.list.is_some(), table.rings.is_some()];
    let n_sources = sources.iter().filter(|s| **s).count();
    let mut candidates: Vec<Candidate> = Vec::new();
    let mut base_name = String::new();
    if n_sources != 1 {
        errors.push(PlanError::invalid(
            prefix,
            format!("{n_sources} sources"),
            "give exactly one source of directions",
            format!("one of preset ({PRESETS}), list = [[theta, phi], ...], rings = [{{ theta_deg, count, phi_offset_deg }}, ...]"),
        ));
    } else if let Some(p) = &table.preset {
        let sampling = match p.as_str() {
            "bonn81" => Some(Sampling::from_rings("bonn81", &BONN81_RINGS)),
            "dome1-151" | "bonn-dome1-151" => Some(Sampling::from_rings("dome1-151", &BONN_DOME1_RINGS)),
            _ => None,
        };
        let field =
            if matches!(spec, SamplingSpec::Preset(_)) { prefix.to_string() } else { format!("{prefix}.preset") };
        match sampling {
            Some(s) => {
                let s = s.expect("presets are valid");
                base_name = s.name().to_string();
                candidates = s
                    .directions()
                    .iter()
                    .enumerate()
                    .map(|(i, d)| Candidate { dir: *d, source_index: i, field: field.clone(), written: String::new() })
                    .collect();
            }
            None => errors.push(PlanError::unknown(field, p, PRESETS)),
        }
    } else if too_many_directions(&table, prefix, errors).is_some() {
        // Counted before expanding (reported): nothing of the refused size is built.
    } else if let Some(list) = &table.list {
        base_name = "list".into();
        if list.is_empty() {
            errors.push(PlanError::invalid(
                format!("{prefix}.list"),
                "[]",
                "no directions",
                "at least one [theta, phi]",
            ));
        }
        for (i, [t, p]) in list.iter().copied().enumerate() {
            let field = format!("{prefix}.list[{i}]");
            let ok_t = check_theta(t, &format!("{field}.theta"), errors);
            let ok_p = check_phi(p, &format!("{field}.phi"), errors);
            if ok_t && ok_p {
                candidates.push(Candidate {
                    dir: Direction::from_degrees(t, p),
                    source_index: i,
                    field,
                    written: format!("[{t}, {p}]"),
                });
            }
        }
    } else if let Some(rings) = &table.rings {
        base_name = "rings".into();
        if rings.is_empty() {
            errors.push(PlanError::invalid(format!("{prefix}.rings"), "[]", "no rings", "at least one ring"));
        }
        let mut k = 0;
        for (r, ring) in rings.iter().enumerate() {
            let field = format!("{prefix}.rings[{r}]");
            let ok_t = check_theta(ring.theta_deg, &format!("{field}.theta_deg"), errors);
            let ok_c = (1..=360).contains(&ring.count);
            if !ok_c {
                errors.push(PlanError::out_of_range(
                    format!("{field}.count"),
                    ring.count,
                    "1..=360 (1 for theta_deg = 0)",
                ));
            }
            let ok_p = ring.phi_offset_deg.is_finite() && ring.phi_offset_deg.abs() <= 360.0;
            if !ok_p {
                errors.push(PlanError::out_of_range(
                    format!("{field}.phi_offset_deg"),
                    ring.phi_offset_deg,
                    "-360..=360 (degrees)",
                ));
            }
            if ok_t && ok_c && ok_p {
                for j in 0..ring.count {
                    let phi = ring.phi_offset_deg + j as f64 * 360.0 / ring.count as f64;
                    candidates.push(Candidate {
                        dir: Direction::from_degrees(ring.theta_deg, phi),
                        source_index: k,
                        field: field.clone(),
                        written: format!("direction {j} ({}, {phi})", ring.theta_deg),
                    });
                    k += 1;
                }
            }
        }
    }
    if errors.len() == n_before {
        check_duplicates(&candidates, errors);
    }

    // Filters.
    let mut name = base_name;
    let mut theta_range = [0.0f64, 90.0];
    for (i, (key, v)) in
        [("theta_min_deg", table.theta_min_deg), ("theta_max_deg", table.theta_max_deg)].into_iter().enumerate()
    {
        if let Some(v) = v {
            if v.is_finite() && (0.0..=90.0).contains(&v) {
                theta_range[i] = v;
                name.push_str(&format!("[{key}={v}]"));
            } else {
                errors.push(PlanError::out_of_range(format!("{prefix}.{key}"), v, "0..=90 (degrees)"));
            }
        }
    }
    if let (Some(lo), Some(hi)) = (table.theta_min_deg, table.theta_max_deg) {
        if lo > hi {
            errors.push(PlanError::invalid(
                format!("{prefix}.theta_max_deg"),
                hi,
                format!("smaller than theta_min_deg = {lo}"),
                "theta_max_deg >= theta_min_deg",
            ));
        }
    }
    let every = table.every.unwrap_or(1);
    if !(1..=1000).contains(&every) {
        errors.push(PlanError::out_of_range(format!("{prefix}.every"), every, "1..=1000"));
    } else if every > 1 {
        name.push_str(&format!("[every={every}]"));
    }
    if errors.len() != n_before || candidates.is_empty() {
        return None;
    }
    // A small tolerance so that `theta_max_deg = 30` keeps a ring written as 30 degrees.
    let tol = 1e-9;
    let kept: Vec<&Candidate> = candidates
        .iter()
        .filter(|c| {
            let t = c.dir.theta.to_degrees();
            t >= theta_range[0] - tol && t <= theta_range[1] + tol
        })
        .collect::<Vec<_>>()
        .into_iter()
        .step_by(every)
        .collect();
    if kept.is_empty() {
        errors.push(PlanError::invalid(
            prefix,
            format!("{} directions", candidates.len()),
            format!("the filters (theta {}..={} deg, every {every}) keep none", theta_range[0], theta_range[1]),
            "filters that keep at least one direction",
        ));
        return None;
    }
    let dirs: Vec<Direction> = kept.iter().map(|c| c.dir).collect();
    let indices: Vec<usize> = kept.iter().map(|c| c.source_index).collect();
    Some(KeptDirections { name, dirs, indices })
}

/// The number of directions a `list` or `rings` source would give, when it exceeds
/// [`MAX_DIRECTIONS`] (reported); counted from the table without expanding it.
fn too_many_directions(table: &SamplingTable, prefix: &str, errors: &mut Vec<PlanError>) -> Option<usize> {
    let (field, n) = if let Some(list) = &table.list {
        (format!("{prefix}.list"), list.len())
    } else if let Some(rings) = &table.rings {
        // Rings with a count out of range are reported by the ring check, not counted here.
        (format!("{prefix}.rings"), rings.iter().map(|r| if r.count <= 360 { r.count } else { 0 }).sum())
    } else {
        return None;
    };
    (n > MAX_DIRECTIONS).then(|| {
        errors.push(PlanError::TooLarge {
            field,
            value: format!("{n} directions"),
            limit: format!("{MAX_DIRECTIONS} directions per sampling (a fixed limit)"),
            remedy: "use fewer or sparser rings, or a shorter list".into(),
        });
        n
    })
}

fn check_theta(t: f64, field: &str, errors: &mut Vec<PlanError>) -> bool {
    let ok = t.is_finite() && (0.0..90.0).contains(&t);
    if !ok {
        errors.push(PlanError::out_of_range(field, t, "0 <= theta < 90 (degrees from the sample normal)"));
    }
    ok
}

fn check_phi(p: f64, field: &str, errors: &mut Vec<PlanError>) -> bool {
    let ok = p.is_finite() && (-360.0..=360.0).contains(&p);
    if !ok {
        errors.push(PlanError::out_of_range(field, p, "-360 <= phi <= 360 (degrees from the sample x axis)"));
    }
    ok
}

fn check_duplicates(candidates: &[Candidate], errors: &mut Vec<PlanError>) {
    let units: Vec<_> = candidates.iter().map(|c| c.dir.to_vector()).collect();
    // For each direction the first earlier one it repeats. Two directions closer than the
    // tolerance differ in z by less than it, so only neighbours in z order are compared:
    // O(n log n) but for many directions of one height (at most a ring's 360, or a list's).
    let mut by_z: Vec<usize> = (0..units.len()).collect();
    by_z.sort_by(|&a, &b| units[a].z.total_cmp(&units[b].z));
    let mut first: Vec<Option<usize>> = vec![None; units.len()];
    for (k, &a) in by_z.iter().enumerate() {
        for &b in by_z[k + 1..].iter().take_while(|&&b| units[b].z - units[a].z <= DUPLICATE_TOLERANCE_RAD) {
            if angle_between(&units[a], &units[b]) < DUPLICATE_TOLERANCE_RAD {
                let (i, j) = (a.min(b), a.max(b));
                first[j] = Some(first[j].map_or(i, |f| f.min(i)));
            }
        }
    }
    for (j, i) in first.iter().enumerate() {
        if let Some(i) = *i {
            let (a, b) = (&candidates[i], &candidates[j]);
            let first = if a.field == b.field { a.written.clone() } else { format!("{} = {}", a.field, a.written) };
            errors.push(PlanError::invalid(
                &b.field,
                &b.written,
                format!("the same direction as {first}"),
                "distinct directions (at theta = 0 every phi is the same direction)",
            ));
        }
    }
}
