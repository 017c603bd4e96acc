//! What `btfrig model …` was given when it is not a dataset: a compressed model file or
//! another command's material maps are named as such, with what the command needs instead.

use std::path::Path;

use btfrig_store::MANIFEST_FILE;

/// What a material-maps directory holds, from its `model.json`: `(model, dataset it came from)`.
fn material_maps(dir: &Path) -> Option<(String, String)> {
    let text = std::fs::read(dir.join("model.json")).ok()?;
    let d: serde_json::Value = serde_json::from_slice(&text).ok()?;
    if d["format"] != "btfrig-material-maps" {
        return None;
    }
    // `model ps` names its method, the fits their model.
    let model = d["model"].as_str().map_or_else(|| "ps".to_string(), str::to_string);
    Some((model, d["source"]["dataset"].as_str().unwrap_or("?").to_string()))
}

/// Refuses anything but a dataset directory, naming what `path` is and what is needed.
pub(super) fn ensure_dataset(path: &Path) -> anyhow::Result<()> {
    const NEED: &str = "`btfrig model` fits from a dataset directory's textures (manifest.json, journal and textures/)";
    if path.is_file() {
        let mut head = [0u8; 8];
        let is_model = std::fs::File::open(path)
            .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
            .is_ok_and(|()| &head == btfrig_compress::file::MAGIC);
        if is_model {
            let kind = btfrig_compress::file::read_header(path).map_or("unreadable".to_string(), |(h, _)| h.method);
            anyhow::bail!(
                "{}: a compressed BTF model file ({kind}, from `btfrig compress`), not a dataset: {NEED}; \
                 pass the dataset the model was built from",
                path.display()
            );
        }
        anyhow::bail!("{}: a file, not a dataset: {NEED}", path.display());
    }
    if path.is_dir() && !path.join(MANIFEST_FILE).exists() {
        if let Some((model, source)) = material_maps(path) {
            anyhow::bail!(
                "{}: the material maps of `btfrig model {model}` (model.json), not a dataset: {NEED}; \
                 pass the dataset they were fitted to ({source})",
                path.display()
            );
        }
        anyhow::bail!("{}: no {MANIFEST_FILE}, so not a dataset: {NEED}", path.display());
    }
    Ok(())
}
