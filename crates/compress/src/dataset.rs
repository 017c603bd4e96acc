//! Reading a dataset directory (`docs/dataset-format.md`) as a BTF, read only: the manifest
//! for samplings and texture size, the journal for the captured steps, the texture files.
//! Nothing is written or changed.

use std::path::{Path, PathBuf};

use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;
use btfrig_store::{journal, Manifest, StepId, JOURNAL_FILE, MANIFEST_FILE, TEXTURES_DIR};
use rayon::prelude::*;

use crate::build::{check_finite, RowSink, RowSource};
use crate::error::{CompressError, Result};
use crate::model::Layout;

/// A finished (or partial) dataset as a source of textures.
pub struct DatasetSource {
    dir: PathBuf,
    manifest: Manifest,
    steps: Vec<StepId>,
    layout: Layout,
    /// Textures read per parallel chunk.
    pub chunk: usize,
}

fn sampling(name: &str, d: &[btfrig_store::DirectionDeg]) -> Result<Sampling> {
    let dirs: Vec<Direction> = d.iter().map(|x| Direction::from_degrees(x.theta_deg, x.phi_deg)).collect();
    // Name the Bonn table when it is one (model files and exports keep the name).
    let bonn = Sampling::bonn81();
    let is_bonn = dirs.len() == bonn.len() && dirs.iter().zip(bonn.directions()).all(|(a, b)| a.angle_to(*b) < 1e-9);
    Sampling::from_list(if is_bonn { "bonn81" } else { name }, dirs)
        .map_err(|e| CompressError::Dataset { dir: PathBuf::new(), what: format!("{name} sampling: {e}") })
}

impl DatasetSource {
    /// Opens `dir`: every journaled step with a texture is a measured capture.
    pub fn open(dir: &Path) -> Result<Self> {
        let fail = |what: String| CompressError::Dataset { dir: dir.into(), what };
        let io = |p: PathBuf| move |source| CompressError::Io { path: p, source };
        let mp = dir.join(MANIFEST_FILE);
        let text = std::fs::read(&mp).map_err(io(mp.clone()))?;
        let manifest: Manifest = serde_json::from_slice(&text).map_err(|e| fail(format!("{MANIFEST_FILE}: {e}")))?;
        if !manifest.textures {
            return Err(fail(
                "the dataset keeps raw frames only (manifest textures = false): nothing to compress".into(),
            ));
        }
        let jp = dir.join(JOURNAL_FILE);
        let jb = std::fs::read(&jp).map_err(io(jp.clone()))?;
        let replay = journal::replay(&jp.display().to_string(), &jb).map_err(|e| fail(e.to_string()))?;
        let light = sampling("light", &manifest.samplings.light).map_err(|e| fail(e.to_string()))?;
        let view = sampling("view", &manifest.samplings.view).map_err(|e| fail(e.to_string()))?;
        let (w, h) = (manifest.texture.width as usize, manifest.texture.height as usize);
        let mut layout = Layout::full(light, view, w, h);
        layout.measured.fill(false);
        let mut steps = Vec::new();
        for (&s, rec) in &replay.done {
            let stem = format!("{TEXTURES_DIR}/{}.exr", s.stem());
            if rec.files.iter().any(|f| f.path == stem) {
                let a = layout.index(s.light as usize, s.view as usize);
                if s.light as usize >= layout.n_light() || s.view as usize >= layout.n_view() {
                    return Err(fail(format!("journaled step {s} is outside the samplings")));
                }
                layout.measured[a] = true;
                steps.push(s);
            }
        }
        if steps.is_empty() {
            return Err(fail("no journaled captures with textures".into()));
        }
        Ok(DatasetSource { dir: dir.into(), manifest, steps, layout, chunk: 32 })
    }

    /// The dataset's BTF layout.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The captured steps.
    pub fn steps(&self) -> &[StepId] {
        &self.steps
    }

    /// Reads the texture of `step`, checking size and finiteness.
    pub fn read(&self, step: StepId) -> Result<Vec<[f32; 3]>> {
        let p = self.dir.join(TEXTURES_DIR).join(format!("{}.exr", step.stem()));
        let (w, h, data) = btfrig_imageio::read_rgb_exr(&p)
            .map_err(|e| CompressError::Io { path: p.clone(), source: std::io::Error::other(e.to_string()) })?;
        if (w, h) != (self.layout.width, self.layout.height) {
            return Err(CompressError::WrongTextureSize {
                light: step.light,
                view: step.view,
                got: w * h,
                expected: self.layout.texels(),
                width: self.layout.width,
                height: self.layout.height,
            });
        }
        check_finite(step.light, step.view, &data, w)?;
        Ok(data)
    }
}

impl RowSource for DatasetSource {
    fn for_each(&mut self, f: &mut RowSink<'_>) -> Result<()> {
        for chunk in self.steps.chunks(self.chunk.max(1)) {
            let read: Vec<Result<Vec<[f32; 3]>>> = chunk.par_iter().map(|&s| self.read(s)).collect();
            for (s, t) in chunk.iter().zip(read) {
                f(s.light, s.view, &t?)?;
            }
        }
        Ok(())
    }
}

/// Writes an in-memory BTF as a new dataset in `dir` (synthetic and simulated BTFs for
/// benchmarks and tests): a manifest with the layout's samplings (unmeasured pairs listed as
/// skipped, reason `not-measured`), one journaled float or half EXR texture per measured
/// pair. `textures[a]` is the texture of angular index `a`.
pub fn write_dataset(
    dir: &Path,
    layout: &Layout,
    textures: &mut dyn FnMut(usize) -> Vec<[f32; 3]>,
    rig_name: &str,
    note: &str,
    half: bool,
) -> Result<()> {
    use btfrig_store::{
        Dataset, RigInfo, Samplings, SkippedStep, StepTiming, TextureFormat, TextureRegion, TextureSpec,
    };
    let store = |e: btfrig_store::StoreError| CompressError::Dataset { dir: dir.into(), what: e.to_string() };
    let mut samplings = Samplings::full(layout.light.directions(), layout.view.directions());
    for a in 0..layout.n_angular() {
        if !layout.measured[a] {
            let (l, v) = layout.pair(a);
            samplings
                .skipped
                .push(SkippedStep { step: StepId { light: l as u32, view: v as u32 }, reason: "not-measured".into() });
        }
    }
    let texture = TextureSpec {
        width: layout.width as u32,
        height: layout.height as u32,
        region: TextureRegion { center_m: [0.0, 0.0], size_m: [0.05, 0.05] },
        format: if half { TextureFormat::ExrHalf } else { TextureFormat::ExrFloat },
    };
    let plan = format!("# written by btfrig_compress::dataset::write_dataset\n# {note}\n");
    let manifest = btfrig_store::Manifest::new(
        RigInfo { name: rig_name.into(), config_toml: String::new() },
        &plan,
        samplings,
        texture,
        false,
        0,
    );
    let ds = Dataset::create(dir, manifest).map_err(store)?;
    for a in 0..layout.n_angular() {
        if layout.measured[a] {
            let (l, v) = layout.pair(a);
            let step = StepId { light: l as u32, view: v as u32 };
            let t = textures(a);
            let f = ds.write_texture(step, &t, layout.width, layout.height).map_err(store)?;
            ds.commit_step(step, vec![f], 1, StepTiming::default()).map_err(store)?;
        }
    }
    Ok(())
}
