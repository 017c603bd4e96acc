//! `[outputs]`: file format and the compressed model.

use super::{OutputFormat, Outputs};
use crate::plan::{OutputsSpec, PlanError};

pub(super) fn resolve_outputs(o: &OutputsSpec, errors: &mut Vec<PlanError>) -> Option<Outputs> {
    let n_before = errors.len();
    let format = match o.format.as_str() {
        "exr-half" => Some(OutputFormat::ExrHalf),
        "exr-float" => Some(OutputFormat::ExrFloat),
        other => {
            errors.push(PlanError::unknown("outputs.format", other, "\"exr-half\", \"exr-float\""));
            None
        }
    };
    let compressed_model = o.compressed_model.model().unwrap_or_else(|m| {
        errors.push(PlanError::unknown(
            "outputs.compressed_model",
            m,
            "\"fmf\", \"pvmf\", \"pcmf\", \"pcmf-shared\", \"none\", false, or true (= \"fmf\")",
        ));
        None
    });
    if compressed_model.is_some() && !o.textures {
        errors.push(PlanError::invalid(
            "outputs.compressed_model",
            o.compressed_model.display(),
            "the model is built from the textures, and textures = false writes none",
            "compressed_model = false, or textures = true",
        ));
    }
    if !o.textures && !o.raw_frames {
        errors.push(PlanError::invalid(
            "outputs.textures",
            false,
            "with raw_frames = false as well, the run would write nothing",
            "textures = true or raw_frames = true",
        ));
    }
    if o.texture_previews && !o.textures {
        errors.push(PlanError::invalid(
            "outputs.texture_previews",
            true,
            "with textures = false there is no texture to preview",
            "texture_previews = false, or textures = true",
        ));
    }
    (errors.len() == n_before).then(|| Outputs {
        raw_frames: o.raw_frames,
        textures: o.textures,
        preview: o.preview,
        texture_previews: o.texture_previews,
        format: format.expect("no errors"),
        compressed_model,
    })
}
