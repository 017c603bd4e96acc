//! The pipeline sink: a model built while the rig is still measuring.
//!
//! [`StreamingCompressor::accept`] is called with every committed texture (the pipeline's
//! `btfrig_process::TextureSink` hook); it hands the texture to a worker thread over a
//! bounded channel (back-pressure policy *Block*, as the dataset's), which feeds pass 1 of a
//! [`Builder`]. The time `accept` spends waiting for room in the channel is measured: zero
//! means the pipeline never waited on compression. [`StreamingCompressor::finish`] completes
//! pass 1 from the dataset on disk for any capture the sink did not see (a resumed run), then
//! runs the remaining passes over the dataset's textures and returns the model.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;
use btfrig_store::{Manifest, MANIFEST_FILE};

use crate::build::{Builder, ModelParams, RowSource};
use crate::dataset::DatasetSource;
use crate::error::{CompressError, Result};
use crate::model::{Layout, Model};

type Item = (u32, u32, Vec<[f32; 3]>);
/// The worker thread: pass 1 of the builder (none if no texture arrived).
type Worker = JoinHandle<Result<Option<Builder<f32>>>>;

#[derive(Default)]
struct Counters {
    pushed: AtomicUsize,
    popped: AtomicUsize,
    max_depth: AtomicUsize,
    blocked_ns: AtomicU64,
    busy_ns: AtomicU64,
}

/// What streaming cost, for the run summary.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SinkReport {
    /// Textures received from the pipeline.
    pub streamed: usize,
    /// Captures pass 1 had to read from disk (not streamed: an earlier session's).
    pub from_disk: usize,
    /// Seconds `accept` waited for room in the channel (0: the pipeline never waited).
    pub blocked_s: f64,
    /// Largest number of textures queued at once.
    pub max_queue: usize,
    /// Channel capacity.
    pub capacity: usize,
    /// Seconds the worker spent in pass 1 (colour transform and sketch updates).
    pub pass1_busy_s: f64,
    /// Seconds `finish` took (rest of pass 1, passes 2.., assembling the model).
    pub finish_s: f64,
    /// Passes over the data in all.
    pub passes: usize,
    /// Peak bytes held by the builder.
    pub builder_peak_bytes: usize,
}

/// A model builder fed by the pipeline (see the module documentation).
pub struct StreamingCompressor {
    dir: PathBuf,
    params: ModelParams,
    capacity: usize,
    tx: Mutex<Option<SyncSender<Item>>>,
    worker: Mutex<Option<Worker>>,
    counters: Arc<Counters>,
}

/// The layout a dataset is meant to have: its samplings (a dome or camera array: its
/// per-capture directions, [`crate::dataset::dome_layout`]), texture size and expected steps.
pub fn expected_layout(dir: &Path) -> Result<Layout> {
    let fail = |what: String| CompressError::Dataset { dir: dir.into(), what };
    let p = dir.join(MANIFEST_FILE);
    let text = std::fs::read(&p).map_err(|source| CompressError::Io { path: p.clone(), source })?;
    let m: Manifest = serde_json::from_slice(&text).map_err(|e| fail(format!("{MANIFEST_FILE}: {e}")))?;
    if let Some(layout) = crate::dataset::dome_layout(&m).map_err(&fail)? {
        return Ok(layout);
    }
    let s = |name: &str, d: &[btfrig_store::DirectionDeg]| {
        Sampling::from_list(name, d.iter().map(|x| Direction::from_degrees(x.theta_deg, x.phi_deg)).collect())
            .map_err(|e| fail(format!("{name} sampling: {e}")))
    };
    let mut layout = Layout::full(
        s("light", &m.samplings.light)?,
        s("view", &m.samplings.view)?,
        m.texture.width as usize,
        m.texture.height as usize,
    );
    layout.measured.fill(false);
    for st in m.samplings.expected_steps() {
        let a = layout.index(st.light as usize, st.view as usize);
        layout.measured[a] = true;
    }
    Ok(layout)
}

impl StreamingCompressor {
    /// A sink for the dataset in `dir` (its manifest is read when the first texture
    /// arrives, i.e. after the run created it), queueing at most `capacity` textures.
    pub fn new(dir: &Path, params: ModelParams, capacity: usize) -> Result<Self> {
        params.validate()?;
        let capacity = capacity.max(1);
        let (tx, rx) = sync_channel::<Item>(capacity);
        let counters = Arc::new(Counters::default());
        let c = counters.clone();
        let (d, p) = (dir.to_path_buf(), params.clone());
        let worker = std::thread::Builder::new()
            .name("btfrig-compress".into())
            .spawn(move || -> Result<Option<Builder<f32>>> {
                let mut b: Option<Builder<f32>> = None;
                for (l, id, t) in rx {
                    c.popped.fetch_add(1, Ordering::Relaxed);
                    let start = Instant::now();
                    if b.is_none() {
                        b = Some(Builder::new(expected_layout(&d)?, p.clone())?);
                    }
                    let b = b.as_mut().expect("just set");
                    // A dome's view ids map to the layout's measured views.
                    let v = b.layout().view_of_id(id).ok_or_else(|| CompressError::UnknownCapture {
                        light: l,
                        view: id,
                        why: "the view is not among the dataset's expected views".into(),
                    })?;
                    b.push(l, v, &t)?;
                    c.busy_ns.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
                }
                Ok(b)
            })
            .map_err(|source| CompressError::Io { path: dir.into(), source })?;
        Ok(StreamingCompressor {
            dir: dir.into(),
            params,
            capacity,
            tx: Mutex::new(Some(tx)),
            worker: Mutex::new(Some(worker)),
            counters,
        })
    }

    /// Takes one committed texture. Waits (and counts the wait) only if `capacity` textures
    /// are already queued. After a worker error the textures are dropped; `finish` reports it.
    pub fn accept(&self, light: u32, view: u32, texels: &[[f32; 3]]) {
        let guard = self.tx.lock().unwrap_or_else(|e| e.into_inner());
        let Some(tx) = guard.as_ref() else { return };
        let c = &self.counters;
        let pushed = c.pushed.fetch_add(1, Ordering::Relaxed) + 1;
        let depth = pushed.saturating_sub(c.popped.load(Ordering::Relaxed));
        c.max_depth.fetch_max(depth, Ordering::Relaxed);
        match tx.try_send((light, view, texels.to_vec())) {
            Ok(()) => {}
            Err(TrySendError::Full(item)) => {
                let t = Instant::now();
                let _ = tx.send(item);
                c.blocked_ns.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
            }
            Err(TrySendError::Disconnected(_)) => {}
        }
    }

    /// Ends streaming and builds the model: the rest of pass 1 and the other passes from the
    /// dataset's textures.
    pub fn finish(&self) -> Result<(Model, SinkReport)> {
        let t = Instant::now();
        drop(self.tx.lock().unwrap_or_else(|e| e.into_inner()).take());
        let worker = self.worker.lock().unwrap_or_else(|e| e.into_inner()).take();
        let streamed =
            worker.map(|w| w.join().map_err(|_| CompressError::State("the compression worker panicked".into())));
        let mut b = match streamed {
            Some(r) => r??,
            None => return Err(CompressError::State("finish called twice".into())),
        };
        let mut src = DatasetSource::open(&self.dir)?;
        let mut b = match b.take() {
            Some(b) => b,
            None => Builder::new(expected_layout(&self.dir)?, self.params.clone())?,
        };
        // Pass 1: the captures the sink did not see.
        let mut from_disk = 0;
        for &s in src.steps().to_vec().iter() {
            let (l, v) = src.layout_pair(s);
            if !b.seen(l, v) {
                let tex = src.read(s)?;
                b.push(l, v, &tex)?;
                from_disk += 1;
            }
        }
        let mut more = b.end_pass()?;
        while more {
            src.for_each(&mut |l, v, tex| b.push(l, v, tex))?;
            more = b.end_pass()?;
        }
        let (passes, peak) = (b.pass(), b.peak_bytes());
        let model = b.finish()?;
        let c = &self.counters;
        Ok((
            model,
            SinkReport {
                streamed: c.popped.load(Ordering::Relaxed),
                from_disk,
                blocked_s: c.blocked_ns.load(Ordering::Relaxed) as f64 * 1e-9,
                max_queue: c.max_depth.load(Ordering::Relaxed),
                capacity: self.capacity,
                pass1_busy_s: c.busy_ns.load(Ordering::Relaxed) as f64 * 1e-9,
                finish_s: t.elapsed().as_secs_f64(),
                passes,
                builder_peak_bytes: peak,
            },
        ))
    }
}
