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
use crate::model::{CaptureDirections, Layout};

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

/// The layout of a dome or camera-array dataset (`None`: the manifest's rig is a
/// gonioreflectometer, or a synthetic dataset without a rig config), from the manifest alone:
/// its rig config (`rig.config_toml`, the dome geometry) and its steps. Lights are the
/// manifest's light list (LEDs or flashes, rig frame); views are the dataset's view ids that
/// the plan measures (`rotation x rig cameras + camera`), in increasing order; each capture's
/// directions in the sample frame are `DomeConfig::sample_directions(camera, turntable,
/// light)`. Every expected step is marked measured.
pub fn dome_layout(manifest: &Manifest) -> std::result::Result<Option<Layout>, String> {
    if manifest.rig.config_toml.trim().is_empty() {
        return Ok(None);
    }
    // A config that does not parse is no dome this build knows: the samplings as written.
    let Ok(rig) = btfrig_core::config::RigConfig::from_toml(&manifest.rig.config_toml, "manifest rig.config_toml")
    else {
        return Ok(None);
    };
    let Some(dome) = rig.dome.as_ref().filter(|_| rig.rig.kind.is_dome()) else { return Ok(None) };
    let (ncams, nl) = (dome.camera_count(), manifest.samplings.light.len());
    if nl != dome.led_count() {
        return Err(format!(
            "the manifest lists {nl} lights, its rig config ({}) has {} {}",
            rig.rig.name,
            dome.led_count(),
            if dome.is_flash() { "flashes" } else { "LEDs" }
        ));
    }
    let expected = manifest.samplings.expected_steps();
    let mut view_ids: Vec<u32> = expected.iter().map(|s| s.view).collect();
    view_ids.dedup();
    view_ids.sort_unstable();
    view_ids.dedup();
    let camera_rotation = |id: u32| -> std::result::Result<(usize, u32), String> {
        let (c, k) = (id as usize % ncams, id / ncams as u32);
        if k >= dome.rotations {
            return Err(format!(
                "view {id} is rotation {k} of camera {c}: the rig has {} rotations and {ncams} cameras",
                dome.rotations
            ));
        }
        Ok((c, k))
    };
    let mut views = Vec::with_capacity(view_ids.len());
    for &id in &view_ids {
        let (c, k) = camera_rotation(id)?;
        views.push(dome.sample_directions(c, dome.rotation_rad(k), 0).1);
    }
    let light_dirs: Vec<Direction> =
        manifest.samplings.light.iter().map(|x| Direction::from_degrees(x.theta_deg, x.phi_deg)).collect();
    let (lname, vname) = if dome.is_flash() { ("flashes", "cameras") } else { ("dome-leds", "dome-views") };
    let light = Sampling::from_list(lname, light_dirs).map_err(|e| format!("light list: {e}"))?;
    let view = Sampling::from_list(vname, views).map_err(|e| match e {
        btfrig_core::sampling::SamplingError::Duplicate { first, second, .. } => {
            let (c1, k1) = camera_rotation(view_ids[first]).unwrap_or_default();
            let (c2, k2) = camera_rotation(view_ids[second]).unwrap_or_default();
            format!(
                "views {} (camera {c1}, rotation {k1}) and {} (camera {c2}, rotation {k2}) look along the same \
                 direction in the sample frame (a camera on the turntable axis): a model's views must differ; \
                 keep one rotation of that camera in the plan",
                view_ids[first], view_ids[second]
            )
        }
        e => format!("view list: {e}"),
    })?;
    let (w, h) = (manifest.texture.width as usize, manifest.texture.height as usize);
    let mut layout = Layout::full(light, view, w, h);
    let n = layout.n_angular();
    let (mut ld, mut vd) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for a in 0..n {
        let (l, v) = layout.pair(a);
        let (c, k) = camera_rotation(view_ids[v])?;
        let (dl, dv) = dome.sample_directions(c, dome.rotation_rad(k), l);
        ld.push(dl);
        vd.push(dv);
    }
    layout.measured.fill(false);
    for s in &expected {
        if s.light as usize >= nl {
            return Err(format!("step {s}: light {} of {nl}", s.light));
        }
        let v = view_ids.binary_search(&s.view).expect("listed above");
        let a = layout.index(s.light as usize, v);
        layout.measured[a] = true;
    }
    layout.captures = Some(CaptureDirections { view_ids, light: ld, view: vd });
    Ok(Some(layout))
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
        let mut layout = match dome_layout(&manifest).map_err(&fail)? {
            Some(l) => l,
            None => {
                let light = sampling("light", &manifest.samplings.light).map_err(|e| fail(e.to_string()))?;
                let view = sampling("view", &manifest.samplings.view).map_err(|e| fail(e.to_string()))?;
                let (w, h) = (manifest.texture.width as usize, manifest.texture.height as usize);
                Layout::full(light, view, w, h)
            }
        };
        layout.measured.fill(false);
        let mut steps = Vec::new();
        for (&s, rec) in &replay.done {
            let stem = format!("{TEXTURES_DIR}/{}.exr", s.stem());
            if rec.files.iter().any(|f| f.path == stem) {
                let v = layout.view_of_id(s.view);
                let (l, v) = match v {
                    Some(v) if (s.light as usize) < layout.n_light() => (s.light as usize, v as usize),
                    _ => return Err(fail(format!("journaled step {s} is outside the samplings"))),
                };
                let a = layout.index(l, v);
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

    /// The captured steps (the dataset's light and view ids).
    pub fn steps(&self) -> &[StepId] {
        &self.steps
    }

    /// The layout's `(light, view)` of a captured step (a dome's view id is mapped to the
    /// layout's view; a gonio dataset's is the same number).
    pub fn layout_pair(&self, step: StepId) -> (u32, u32) {
        (step.light, self.layout.view_of_id(step.view).expect("a captured step's view is in the layout"))
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
                let (l, v) = self.layout_pair(*s);
                f(l, v, &t?)?;
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
