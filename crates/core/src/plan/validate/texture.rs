//! `[texture]`: region, size and resampling filter.

use crate::config::RigConfig;

use super::{Region, ResampleFilter, TextureSettings};
use crate::plan::{FilterSpec, Plan, PlanError, RegionSpec};

pub(super) fn resolve_texture(
    plan: &Plan,
    rig: Option<&RigConfig>,
    errors: &mut Vec<PlanError>,
) -> Option<TextureSettings> {
    let t = &plan.texture;
    let n_before = errors.len();
    if !(8..=4096).contains(&t.size) {
        errors.push(PlanError::out_of_range(
            "texture.size",
            t.size,
            "8..=4096 texels per side (typical 256, 512, 800)",
        ));
    }
    let filter = resolve_filter(&t.filter, errors);
    let side = rig.map(|r| r.plate.sample_side_m);
    let region = match (&t.region, side) {
        (None, Some(a)) => Some(Region { x_min_m: -a / 2.0, x_max_m: a / 2.0, y_min_m: -a / 2.0, y_max_m: a / 2.0 }),
        (None, None) => None,
        (Some(r), side) => resolve_region(r, side, errors),
    };
    // Without a rig (already reported) the region cannot be put in metres.
    match (region, filter) {
        (Some(region), Some(filter)) if errors.len() == n_before => {
            Some(TextureSettings { size: t.size as usize, region, filter })
        }
        _ => None,
    }
}

const FILTER_NAMES: &str = "\"bilinear\", \"supersample\", \"footprint\", \"ewa\"";

fn resolve_filter(f: &FilterSpec, errors: &mut Vec<PlanError>) -> Option<ResampleFilter> {
    let (name, field, n, max) = match f {
        FilterSpec::Name(name) => (name.as_str(), "texture.filter", None, None),
        FilterSpec::Table(t) => (t.name.as_str(), "texture.filter.name", t.n, t.max),
    };
    let n_before = errors.len();
    let param = |key: &str, v: Option<u32>, default: usize, errors: &mut Vec<PlanError>| match v {
        None => default,
        Some(v) if (1..=16).contains(&v) => v as usize,
        Some(v) => {
            errors.push(PlanError::out_of_range(
                format!("texture.filter.{key}"),
                v,
                "1..=16 sub-samples per texel axis",
            ));
            default
        }
    };
    let only = |key: &str, v: Option<u32>, errors: &mut Vec<PlanError>| {
        if let Some(v) = v {
            let allowed = match key {
                "n" => "n only with name = \"supersample\"",
                _ => "max only with name = \"footprint\"",
            };
            errors.push(PlanError::invalid(
                format!("texture.filter.{key}"),
                v,
                format!("filter {name:?} has no parameter {key}"),
                allowed,
            ));
        }
    };
    let filter = match name {
        "bilinear" | "ewa" => {
            only("n", n, errors);
            only("max", max, errors);
            if name == "ewa" {
                ResampleFilter::Ewa
            } else {
                ResampleFilter::Bilinear
            }
        }
        "supersample" => {
            only("max", max, errors);
            ResampleFilter::Supersample { n: param("n", n, ResampleFilter::DEFAULT_SUPERSAMPLE_N, errors) }
        }
        "footprint" => {
            only("n", n, errors);
            ResampleFilter::Footprint { max: param("max", max, ResampleFilter::DEFAULT_FOOTPRINT_MAX, errors) }
        }
        other => {
            errors.push(PlanError::unknown(field, other, FILTER_NAMES));
            return None;
        }
    };
    (errors.len() == n_before).then_some(filter)
}

fn resolve_region(r: &RegionSpec, side: Option<f64>, errors: &mut Vec<PlanError>) -> Option<Region> {
    let allowed_form =
        "either x_m = [lo, hi] and y_m = [lo, hi] (metres), or u = [lo, hi] and v = [lo, hi] (fractions)";
    let metric = (r.x_m, r.y_m);
    let fraction = (r.u, r.v);
    let n_before = errors.len();
    let check = |field: &str, range: [f64; 2], lo: f64, hi: f64, unit: &str, errors: &mut Vec<PlanError>| {
        let ok = range.iter().all(|x| x.is_finite() && *x >= lo - 1e-12 && *x <= hi + 1e-12) && range[0] < range[1];
        if !ok {
            errors.push(PlanError::out_of_range(
                field,
                format!("[{}, {}]", range[0], range[1]),
                format!("[lo, hi] with {lo} <= lo < hi <= {hi} ({unit})"),
            ));
        }
    };
    let region = match (metric, fraction) {
        ((Some(x), Some(y)), (None, None)) => {
            let h = side.map_or(f64::INFINITY, |a| a / 2.0);
            let unit = if side.is_some() { "metres, within the sample square" } else { "metres" };
            check("texture.region.x_m", x, -h, h, unit, errors);
            check("texture.region.y_m", y, -h, h, unit, errors);
            Region { x_min_m: x[0], x_max_m: x[1], y_min_m: y[0], y_max_m: y[1] }
        }
        ((None, None), (Some(u), Some(v))) => {
            check("texture.region.u", u, 0.0, 1.0, "fractions of the sample side", errors);
            check("texture.region.v", v, 0.0, 1.0, "fractions of the sample side", errors);
            let a = side.unwrap_or(1.0);
            // u runs along +x from the left edge, v along -y from the top edge.
            Region {
                x_min_m: -a / 2.0 + u[0] * a,
                x_max_m: -a / 2.0 + u[1] * a,
                y_min_m: a / 2.0 - v[1] * a,
                y_max_m: a / 2.0 - v[0] * a,
            }
        }
        _ => {
            let given: Vec<&str> =
                [("x_m", r.x_m.is_some()), ("y_m", r.y_m.is_some()), ("u", r.u.is_some()), ("v", r.v.is_some())]
                    .iter()
                    .filter(|(_, g)| *g)
                    .map(|(n, _)| *n)
                    .collect();
            errors.push(PlanError::invalid(
                "texture.region",
                format!("{{ {} }}", given.join(", ")),
                "incomplete or mixed region",
                allowed_form,
            ));
            return None;
        }
    };
    if errors.len() != n_before {
        return None;
    }
    let (w, h) = (region.x_max_m - region.x_min_m, region.y_max_m - region.y_min_m);
    if (w - h).abs() > 1e-6 * w.max(h) {
        errors.push(PlanError::invalid(
            "texture.region",
            format!("{w} x {h} m"),
            "the region is not square (textures are square)",
            "equal extents along x and y",
        ));
        return None;
    }
    side.map(|_| region)
}
