//! The control daemon, `btfrig serve`: an HTTP API (axum) over the run engine, for scripts
//! and for the operator page it serves.
//!
//! Brief overview: [`serve`] loads the rig config, the auth file and the named plans into an
//! [`AppState`], binds the listen address and answers [`router`]'s routes until SIGTERM or
//! SIGINT, which interrupts the run under way (frames in flight committed, journal flushed,
//! dataset resumable) before the daemon exits. Handlers ([`api`]) are thin: runs go through
//! [`btfrig_measurement::run`] (gonio plans) and [`btfrig_measurement::dome::run_controlled`] (dome
//! plans), plan checks through [`btfrig_measurement::check`] and the dry runs
//! ([`btfrig_measurement::dry_run`], [`btfrig_measurement::dome_dry_run`] for dome plans), exactly as the
//! CLI does. Tokens and roles: [`auth`]; errors: [`problem`]; `/metrics`: [`metrics`].
//! The HTTP API is documented in `docs/http-api.md` and by `/api/v1/openapi.json`.

#![warn(missing_docs)]

// The files, one job each:
// - lib:          ServeConfig, AppState, serve and the router
// - api:          the HTTP handlers under /api/v1
// - runs:         the one run the rig can hold, and the runs before it
// - calibrations: calibrations started through the API
// - plan_jobs:    plan checks and dry runs in flight
// - look:         model renders, the viewer's model data, dataset coverage, the report page
// - auth:         tokens and roles; problem: errors as problem+json
// - metrics:      Prometheus /metrics; server: the HTTP server and its limits

pub mod api;
pub mod auth;
pub mod calibrations;
pub mod look;
pub mod metrics;
pub mod plan_jobs;
pub mod problem;
pub mod runs;
pub mod server;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use axum::extract::DefaultBodyLimit;
use axum::http::header;
use axum::routing::{get, post};
use axum::Router;
use btfrig_core::config::RigConfig;

use crate::api::{DatasetEntry, DeviceStatus, DomeDryRun, PlanBody, PlanCheck, PlanKind, RigStatus, RigSummary};
use crate::auth::Auth;
use crate::calibrations::Calibrations;
use crate::metrics::Metrics;
use crate::problem::Problem;
use crate::runs::{Run, RunState, Runs};

/// Largest request body accepted (a plan file is a few kB).
pub const BODY_LIMIT: usize = 256 * 1024;

/// The plans `{"plan": name}` refers to when the daemon is given no plans directory.
pub const EMBEDDED_PLANS: &[(&str, &str)] = &[
    ("demo", include_str!("../../../rig-configs/plans/demo.toml")),
    ("hdr-glossy", include_str!("../../../rig-configs/plans/hdr-glossy.toml")),
    ("grazing", include_str!("../../../rig-configs/plans/grazing.toml")),
    ("bonn-full", include_str!("../../../rig-configs/plans/bonn-full.toml")),
    ("dome-demo", include_str!("../../../rig-configs/plans/dome-demo.toml")),
    ("camera-array-demo", include_str!("../../../rig-configs/plans/camera-array-demo.toml")),
];

/// A plan offered by name.
#[derive(Debug, Clone)]
pub struct NamedPlan {
    /// Its name (the file stem).
    pub name: String,
    /// Its text.
    pub text: String,
    /// Its file (anchors relative paths in it).
    pub path: PathBuf,
    /// Captures it makes.
    pub captures: u64,
    /// Its description.
    pub description: String,
}

/// How to start the daemon.
#[derive(Debug, Clone)]
pub struct ServeConfig {
    /// The rig config file; `None`: the embedded simulated gonioreflectometer.
    pub rig: Option<PathBuf>,
    /// The listen address (default loopback).
    pub listen: SocketAddr,
    /// Where datasets and calibrations go.
    pub data: PathBuf,
    /// The auth file; `None`: one random admin token, written to `<data>/daemon-token`
    /// (mode 0600; its path, not the token, is printed on stderr).
    pub auth: Option<PathBuf>,
    /// A directory of plan files offered by name (instead of the embedded ones).
    pub plans: Option<PathBuf>,
    /// Time a client has to send a request's head before its connection is closed:
    /// [`server::HEADER_READ_TIMEOUT`] (tests use less).
    pub header_read_timeout: std::time::Duration,
    /// Longest a plan check or dry run may take before it is cancelled:
    /// [`plan_jobs::PLAN_JOB_TIME_LIMIT`] (tests use less).
    pub plan_job_time_limit: std::time::Duration,
}

/// Everything the handlers share.
pub struct AppState {
    /// Accepted tokens.
    pub auth: Auth,
    /// The rig config.
    pub rig: RigConfig,
    /// The rig config's file, if not embedded.
    pub rig_path: Option<PathBuf>,
    /// Where the rig config came from, for people.
    pub rig_source: String,
    /// The data directory.
    pub data: PathBuf,
    /// The plans directory (`--plans`), canonical: the only place besides the rig config
    /// file whose files a plan sent over the API may name ([`AppState::confine_plan_files`]).
    pub plans_dir: Option<PathBuf>,
    /// Plans by name.
    pub plans: Vec<NamedPlan>,
    /// Longest a plan check or dry run may take ([`ServeConfig::plan_job_time_limit`]).
    pub plan_job_time_limit: std::time::Duration,
    /// Runs.
    pub runs: Runs,
    /// Calibrations.
    pub calibrations: Calibrations,
    /// Counters.
    pub metrics: Arc<Metrics>,
    /// The last compressed model read for the viewer.
    pub models: look::ModelCache,
}

/// Why the daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// A file or directory it was given is unusable.
    #[error("{0}")]
    Config(String),
    /// The listen address cannot be bound.
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
    /// Serving failed.
    #[error("serving: {0}")]
    Io(#[from] std::io::Error),
}

impl AppState {
    /// Loads the rig, the auth file and the plans; creates the data directory. Returns the
    /// generated admin token when no auth file is given.
    pub fn load(cfg: &ServeConfig) -> Result<(AppState, Option<String>), ServeError> {
        let bad = |m: String| ServeError::Config(m);
        let (rig, rig_source) = match &cfg.rig {
            None => {
                let (name, text) = btfrig_core::plan::BUILTIN_RIGS
                    .iter()
                    .find(|(n, _)| *n == btfrig_core::plan::BUILTIN_RIG)
                    .ok_or_else(|| bad("no embedded rig".into()))?;
                (RigConfig::from_toml(text, name).map_err(|e| bad(e.to_string()))?, name.to_string())
            }
            Some(p) => {
                let text = std::fs::read_to_string(p).map_err(|e| bad(format!("--rig {}: {e}", p.display())))?;
                (
                    RigConfig::from_toml(&text, &p.display().to_string()).map_err(|e| bad(e.to_string()))?,
                    p.display().to_string(),
                )
            }
        };
        // Options that pass the config's own ranges but would fail when a run builds the
        // devices (a NaN jitter, an inverted exposure range) stop the daemon here, not a run.
        btfrig_measurement::plan::check_rig_options(&rig, &rig_source).map_err(|e| bad(e.to_string()))?;
        std::fs::create_dir_all(&cfg.data)
            .map_err(|e| bad(format!("--data {}: cannot create it: {e}", cfg.data.display())))?;
        let (auth, generated) = match &cfg.auth {
            Some(p) => {
                let text = std::fs::read_to_string(p).map_err(|e| bad(format!("--auth {}: {e}", p.display())))?;
                (Auth::from_toml(&text, &p.display().to_string()).map_err(bad)?, None)
            }
            None => {
                let (a, token) = Auth::generated("admin");
                write_secret(&cfg.data.join("daemon-token"), &token).map_err(bad)?;
                (a, Some(token))
            }
        };
        let plans = load_plans(cfg.plans.as_deref(), &cfg.data, &rig).map_err(bad)?;
        let metrics = Arc::new(Metrics::default());
        let state = AppState {
            auth,
            rig,
            rig_path: cfg.rig.clone(),
            rig_source,
            data: cfg.data.clone(),
            plans_dir: cfg.plans.as_deref().and_then(|d| d.canonicalize().ok()),
            plan_job_time_limit: cfg.plan_job_time_limit,
            plans,
            runs: Runs::new(cfg.data.clone(), metrics.clone()),
            calibrations: Calibrations::default(),
            metrics,
            models: look::ModelCache::default(),
        };
        Ok((state, generated))
    }

    fn rig_status(&self) -> RigStatus {
        let current = self.runs.current().map(|r| r.status());
        let cal = self.calibrations.running();
        let state = match (&current, &cal) {
            (Some(s), _) if s.state == RunState::Paused => "paused".to_string(),
            (Some(_), _) | (_, Some(_)) => "in use".to_string(),
            _ => "idle".to_string(),
        };
        let d = &self.rig.devices;
        let cam = &self.rig.camera;
        // A dome (LED dome, camera array) has no robot, rail or lamp.
        let mut devices = Vec::new();
        if !self.rig.rig.kind.is_dome() {
            devices.push(("robot", &d.robot, "sample orientation, 3 joints".to_string()));
            devices.push(("rail", &d.rail, "camera rail".to_string()));
            devices.push(("lamp", &d.lamp, "light source".to_string()));
        }
        devices.push(("camera", &d.camera, format!("{} x {} px", cam.width_px, cam.height_px)));
        if let Some(t) = &d.turntable {
            devices.push(("turntable", t, "turntable".into()));
        }
        if let Some(l) = &d.led_array {
            devices.push(("led_array", l, "LED array".into()));
        }
        let busy_detail = current
            .as_ref()
            .map(|s| format!("; run {} at {}/{} {}", s.id, s.done, s.total, s.unit.as_str()))
            .unwrap_or_default();
        RigStatus {
            rig: RigSummary {
                name: self.rig.rig.name.clone(),
                kind: self.rig.rig.kind.as_str().into(),
                source: self.rig_source.clone(),
            },
            devices: devices
                .into_iter()
                .map(|(name, e, detail)| DeviceStatus {
                    name: name.into(),
                    kind: e.kind.clone(),
                    state: state.clone(),
                    detail: format!("{detail}{busy_detail}"),
                })
                .collect(),
            busy: current
                .map(|s| api::Busy { run_id: s.id, owner: s.owner })
                .or(cal.map(|c| api::Busy { run_id: c.id, owner: c.owner })),
        }
    }

    /// The plan a body names: (text, file, name given).
    fn plan_source(
        &self,
        plan: Option<String>,
        text: Option<String>,
    ) -> Result<(String, PathBuf, Option<String>), Problem> {
        match (plan, text) {
            (Some(name), None) => {
                let p = self.plans.iter().find(|p| p.name == name).ok_or_else(|| {
                    let names: Vec<&str> = self.plans.iter().map(|p| p.name.as_str()).collect();
                    Problem::not_found(format!("no plan named {name:?}; the daemon offers {names:?}"))
                })?;
                Ok((p.text.clone(), p.path.clone(), Some(p.name.clone())))
            }
            (None, Some(text)) => {
                // Relative paths in a plan sent over the API resolve in the plans directory
                // (and only there may they point; without one, nowhere).
                let anchor = self.plans_dir.as_deref().unwrap_or(&self.data).join("api-plan.toml");
                self.confine_plan_files(&text, &anchor)?;
                Ok((text, anchor, None))
            }
            _ => Err(Problem::unprocessable(
                "give exactly one of \"plan\" (a name from GET /api/v1/plans) and \"plan_text\" (a plan file's TOML)",
            )),
        }
    }

    /// Refuses (422) a plan sent over the API that names a file it may not read: plans over
    /// the API may name embedded rigs, materials and fault scenarios, the daemon's own rig
    /// config file, and files inside the plans directory, nothing else on the host. Each file
    /// it may name is loaded here, and when it does not load, the refusal says where the
    /// parser stopped but never quotes the file (a viewer must not read host files through
    /// error messages).
    fn confine_plan_files(&self, text: &str, anchor: &Path) -> Result<(), Problem> {
        for f in btfrig_measurement::check::named_files(text, anchor) {
            let allowed = || {
                let mut places = vec!["embedded names".to_string()];
                if let Some(r) = &self.rig_path {
                    places.push(format!("the daemon's rig config {}", r.display()));
                }
                match &self.plans_dir {
                    Some(d) => places.push(format!("files inside the plans directory {}", d.display())),
                    None => places.push("(no files: the daemon was started without --plans DIR)".into()),
                }
                places.join(", ")
            };
            let refused = || {
                Problem::unprocessable(format!(
                    "{} = {:?}: a plan sent over the API may not name this file; allowed: {}",
                    f.field,
                    f.value,
                    allowed()
                ))
            };
            let lexical = lexically_normal(&f.path);
            let in_plans = |p: &Path| self.plans_dir.as_deref().is_some_and(|d| p.starts_with(d));
            let rig_file = self.rig_path.as_deref().map(|r| {
                let abs = std::env::current_dir().map(|d| d.join(r)).unwrap_or_else(|_| r.to_path_buf());
                (lexically_normal(&abs), abs.canonicalize().ok())
            });
            let is_rig = |p: &Path| {
                f.field == "rig.config"
                    && rig_file.as_ref().is_some_and(|(lex, real)| lex == p || real.as_deref() == Some(p))
            };
            // Nothing outside the allowed places is even opened (its existence stays unknown).
            if !(in_plans(&lexical) || is_rig(&lexical)) {
                return Err(refused());
            }
            // Links are resolved before the final check.
            let real = f.path.canonicalize().map_err(|_| refused())?;
            if !(in_plans(&real) || is_rig(&real)) {
                return Err(refused());
            }
            check_named_file(&self.rig, &f, &real)?;
        }
        Ok(())
    }

    /// Validates the plan a body names against this rig ([`btfrig_measurement::check`]) and, with
    /// `dry`, dry-runs it: a gonio plan through [`btfrig_measurement::dry_run`], a dome plan
    /// through [`btfrig_measurement::dome_dry_run`] (as `btfrig plan show` does).
    async fn check_plan(self: &Arc<Self>, b: PlanBody, dry: bool) -> PlanCheck {
        let invalid = |kind: Option<PlanKind>, errors: Vec<String>| PlanCheck {
            valid: false,
            kind,
            captures: 0,
            estimate_s: None,
            naive_order_s: None,
            lower_bound_s: None,
            disk_bytes: None,
            text: None,
            dome: None,
            errors,
        };
        let (text, path, given) = match self.plan_source(b.plan, b.plan_text) {
            Ok(p) => p,
            Err(e) => return invalid(None, vec![e.detail]),
        };
        let kind = btfrig_measurement::check::PlanKind::of_toml(&text);
        let state = self.clone();
        // Cancelled when this future is dropped (the client went away), at the time limit,
        // or at shutdown; the work checks the flag (crate::plan_jobs).
        let (guard, record) = self.metrics.plan_jobs.start();
        let job = tokio::task::spawn_blocking(move || -> Result<PlanCheck, Vec<String>> {
            let cancel = record.cancel();
            let errors = |e: btfrig_measurement::RunError| match e {
                btfrig_measurement::RunError::Plan(p) => p.errors.iter().map(|e| e.to_string()).collect(),
                e => vec![e.to_string()],
            };
            let checked = btfrig_measurement::check::check_for_rig(&text, &path, &state.rig).map_err(errors)?;
            let mut c = PlanCheck {
                valid: true,
                kind: kind.map(Into::into),
                captures: checked.captures(),
                estimate_s: None,
                naive_order_s: None,
                lower_bound_s: None,
                disk_bytes: None,
                text: None,
                dome: None,
                errors: vec![],
            };
            if !dry {
                return Ok(c);
            }
            match checked.kind() {
                btfrig_measurement::check::PlanKind::Gonio => {
                    let d = btfrig_measurement::dry_run::dry_run_cancellable(&text, &path, cancel).map_err(errors)?;
                    let mut shown = d.schedule.to_string();
                    if let Some(h) = &d.hdr {
                        shown.push('\n');
                        shown.push_str(h);
                    }
                    c.estimate_s = Some(d.schedule.hardware_s);
                    c.naive_order_s = Some(d.schedule.naive_order_hardware_s);
                    c.lower_bound_s = Some(d.schedule.critical_path_s);
                    c.disk_bytes = Some(d.schedule.disk_bytes());
                    c.text = Some(shown);
                }
                btfrig_measurement::check::PlanKind::Dome => {
                    let d = btfrig_measurement::dome_dry_run::dry_run(&text, &path).map_err(errors)?;
                    // The text names the plan as given, not the daemon's paths.
                    let shown_as = PathBuf::from(given.as_deref().unwrap_or("plan_text"));
                    c.estimate_s = Some(d.rig_time_s);
                    c.disk_bytes = Some(d.texture_bytes);
                    c.text = Some(d.lines(&shown_as).join("\n"));
                    c.dome = Some(DomeDryRun::from_runner(&d, &state.rig));
                }
            }
            Ok(c)
        });
        let limit = self.plan_job_time_limit;
        let job = match tokio::time::timeout(limit, job).await {
            Ok(j) => j,
            Err(_) => {
                guard.cancel();
                return invalid(
                    kind.map(Into::into),
                    vec![format!(
                        "the plan check took longer than its time limit of {} s and was cancelled: allowed are plans \
                         that check and plan within it (fewer pairs; `btfrig plan show` has no time limit)",
                        limit.as_secs_f64()
                    )],
                );
            }
        };
        drop(guard);
        match job {
            Ok(Ok(c)) => c,
            Ok(Err(errors)) => invalid(kind.map(Into::into), errors),
            Err(e) => invalid(kind.map(Into::into), vec![format!("the plan check crashed: {e}")]),
        }
    }

    fn new_dataset_name(&self, plan: &str) -> String {
        let stem: String = plan
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '-' })
            .take(40)
            .collect();
        let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
        let mut name = format!("{stem}-{secs}");
        let mut k = 2;
        while self.data.join(&name).exists() {
            name = format!("{stem}-{secs}-{k}");
            k += 1;
        }
        name
    }

    /// 409 when `dataset` exists and holds another plan (the store would refuse it later).
    fn check_dataset_plan(&self, dataset: &str, plan_text: &str) -> Result<(), Problem> {
        let dir = self.data.join(dataset);
        let Ok(meta) = std::fs::symlink_metadata(&dir) else { return Ok(()) };
        if !meta.is_dir() {
            // A run writes into its dataset: never through a link out of the data directory.
            return Err(Problem::conflict(format!(
                "{dataset:?} exists and is not a directory (the daemon does not follow links in its data directory): choose another name"
            )));
        }
        let manifest = std::fs::read(dir.join(btfrig_store::MANIFEST_FILE)).ok();
        let hash = manifest
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .and_then(|v| v["plan"]["hash"].as_str().map(String::from));
        match hash {
            Some(h) if h == btfrig_store::plan_hash(plan_text) => Ok(()),
            Some(_) => Err(Problem::conflict(format!(
                "dataset {dataset:?} holds another plan's captures: choose another dataset name, or its own plan to resume it"
            ))),
            None => Err(Problem::conflict(format!("{dataset:?} exists and is not a dataset: choose another name"))),
        }
    }

    fn run(&self, id: &str) -> Result<Arc<Run>, Problem> {
        let r = if id == "current" { self.runs.current().or_else(|| self.runs.latest()) } else { self.runs.get(id) };
        r.ok_or_else(|| Problem::not_found(format!("no run {id:?}")))
    }

    fn datasets(&self) -> Vec<DatasetEntry> {
        let current = self.runs.current().map(|r| r.status());
        let mut out = Vec::new();
        let Ok(dir) = std::fs::read_dir(&self.data) else { return out };
        for e in dir.flatten() {
            // Only real directories are datasets (a link could lead anywhere on the host).
            if !e.file_type().is_ok_and(|t| t.is_dir()) {
                continue;
            }
            let name = e.file_name().to_string_lossy().to_string();
            let path = e.path();
            let Ok(m) = std::fs::read(path.join(btfrig_store::MANIFEST_FILE)) else { continue };
            let plan = serde_json::from_slice::<serde_json::Value>(&m)
                .ok()
                .and_then(|v| v["plan"]["text"].as_str().and_then(plan_name_of))
                .unwrap_or_default();
            let report = std::fs::read(path.join(btfrig_store::REPORT_FILE))
                .ok()
                .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
            let (mut state, captures) = match &report {
                Some(r) => (
                    r["status"].as_str().unwrap_or("incomplete").to_string(),
                    r["summary"]["captures"].as_u64().or(r["captures"].as_u64()).unwrap_or(0),
                ),
                None => ("incomplete".into(), 0),
            };
            let mut captures = captures;
            if let Some(c) = current.as_ref().filter(|c| c.dataset == name) {
                state = api::state_name(c.state).into();
                // A dome run's `done` counts steps; its dataset holds textures.
                captures = c.textures.unwrap_or(c.done);
            }
            let models = look::models_of(&self.data, &name);
            out.push(DatasetEntry { name, state, captures, plan, models });
        }
        out.sort_by(|a, b| a.name.cmp(&b.name));
        out
    }

    /// The directory of dataset `name`: a real directory directly inside the data directory.
    /// A symbolic link there (or anything that resolves elsewhere) is no dataset: a link
    /// `DATA/x -> /` would otherwise serve the host's files.
    fn dataset_root(&self, name: &str) -> Result<PathBuf, Problem> {
        api::check_name(name).map_err(Problem::bad_request)?;
        let none = || Problem::not_found(format!("no dataset named {name:?}"));
        let path = self.data.join(name);
        let meta = std::fs::symlink_metadata(&path).map_err(|_| none())?;
        if !meta.is_dir() {
            // Links (to directories or not) and plain files are not datasets.
            tracing::warn!("refused dataset {name:?}: {} is not a directory (links are not followed)", path.display());
            return Err(none());
        }
        let data = self.data.canonicalize().map_err(|_| none())?;
        let root = path.canonicalize().map_err(|_| none())?;
        if root.parent() != Some(data.as_path()) {
            tracing::warn!("refused dataset {name:?}: {} resolves outside {}", path.display(), data.display());
            return Err(none());
        }
        Ok(root)
    }

    /// Dataset `name`'s compressed model `model` (`DATA/<name>.<model>.btfm`, a regular
    /// file, not a link), read on a blocking thread (the last one is cached).
    async fn load_model(self: &Arc<Self>, name: &str, model: &str) -> Result<Arc<btfrig_compress::Model>, Problem> {
        self.dataset_root(name)?;
        look::check_model_name(model).map_err(Problem::bad_request)?;
        let file = look::model_file(&self.data, name, model);
        let none = || {
            Problem::not_found(format!(
                "dataset {name:?} has no model {model:?}; its models: {:?}",
                look::models_of(&self.data, name)
            ))
        };
        if !std::fs::symlink_metadata(&file).is_ok_and(|m| m.is_file()) {
            return Err(none());
        }
        let state = self.clone();
        tokio::task::spawn_blocking(move || state.models.get(&file))
            .await
            .map_err(|e| Problem::internal(format!("reading the model crashed: {e}")))?
            .map_err(|e| Problem::unprocessable(format!("model {model:?} of dataset {name:?} does not read: {e}")))
    }

    /// `rel` inside dataset `name`, refusing anything that leaves it (also through links).
    fn dataset_file(&self, name: &str, rel: &str) -> Result<PathBuf, Problem> {
        let root = self.dataset_root(name)?;
        let rel = api::relative_inside(rel)?;
        let file = root.join(&rel);
        let real = file
            .canonicalize()
            .map_err(|_| Problem::not_found(format!("dataset {name:?} has no file {:?}", rel.display())))?;
        if !real.starts_with(&root) || !real.is_file() {
            return Err(Problem::not_found(format!("dataset {name:?} has no file {:?}", rel.display())));
        }
        Ok(real)
    }
}

/// `p` with `.` and `..` folded away without touching the file system (`..` at the root
/// stays at the root).
fn lexically_normal(p: &Path) -> PathBuf {
    use std::path::Component;
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            c => out.push(c),
        }
    }
    out
}

/// Loads a file a plan sent over the API names (already confined) as what its key says (a
/// material or fault scenario through the device backend of `rig`, which builds them);
/// when it does not load, the error names the key, the file and the parser's position only.
fn check_named_file(rig: &RigConfig, f: &btfrig_measurement::check::NamedFile, real: &Path) -> Result<(), Problem> {
    let real_name = real.display().to_string();
    let scene = |options: btfrig_measurement::backend::SceneOptions<'_>| {
        btfrig_measurement::backend::installed()
            .for_rig(rig)
            .and_then(|b| b.check_scene(&options))
            .map_err(|e| e.to_string())
    };
    let (what, result) = match f.field {
        "rig.config" => (
            "a rig config",
            std::fs::read_to_string(real)
                .map_err(|e| e.to_string())
                .and_then(|t| RigConfig::from_toml(&t, &f.value).map(drop).map_err(|e| e.to_string())),
        ),
        "rig.material" => (
            "a material",
            scene(btfrig_measurement::backend::SceneOptions { material: Some(&real_name), faults: None }),
        ),
        _ => (
            "a fault scenario",
            scene(btfrig_measurement::backend::SceneOptions {
                material: None,
                faults: Some((&real_name, Path::new("/"), f.field)),
            }),
        ),
    };
    result.map_err(|message| {
        // Only where the parser stopped: the message itself may quote the file.
        let at = message
            .find("at line ")
            .map(|i| {
                let rest = &message[i..];
                let end = rest.find(['\n', '\r']).unwrap_or(rest.len());
                format!(" (parse error {})", &rest[..end])
            })
            .unwrap_or_default();
        Problem::unprocessable(format!(
            "{} = {:?}: the file does not load as {what}{at}; check it on the daemon's host with `btfrig plan check`",
            f.field, f.value
        ))
    })
}

fn plan_name_of(text: &str) -> Option<String> {
    let v: toml::Value = toml::from_str(text).ok()?;
    v.get("name")?.as_str().map(String::from)
}

/// Writes the generated token to `path` (`DATA/daemon-token`), readable by this user only.
///
/// The file is never written through: a new file is created beside it with `O_CREAT |
/// O_EXCL` (which never follows a link) and mode 0600, and renamed over `path`, so a symbolic
/// link planted at `path` cannot redirect the token (or truncate its target). An existing
/// token file that others could read, or that another user owns, is refused, not reused.
fn write_secret(path: &Path, secret: &str) -> Result<(), String> {
    use std::io::Write;
    let shown = path.display();
    let existing = match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => {
            return Err(format!(
                "the token file {shown} is a symbolic link: the daemon does not write its token through links; \
                 remove it, or give --auth FILE (docs/http-api.md)"
            ))
        }
        Ok(m) if !m.is_file() => {
            return Err(format!(
                "the token file {shown} exists and is not a regular file: remove it, or give --auth FILE"
            ))
        }
        Ok(m) => Some(m),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(format!("cannot inspect the token file {shown}: {e}")),
    };
    let tmp = path.with_file_name(format!(".daemon-token.{}.tmp", std::process::id()));
    let mut o = std::fs::OpenOptions::new();
    o.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.mode(0o600);
    }
    let mut f = o.open(&tmp).map_err(|e| format!("cannot create {}: {e}", tmp.display()))?;
    let written = (|| -> Result<(), String> {
        #[cfg(unix)]
        if let Some(old) = &existing {
            use std::os::unix::fs::{MetadataExt, PermissionsExt};
            // The new file is ours: its owner is this process's user.
            let me = f.metadata().map_err(|e| format!("cannot inspect {}: {e}", tmp.display()))?.uid();
            let mode = old.permissions().mode() & 0o777;
            if mode & 0o077 != 0 || old.uid() != me {
                return Err(format!(
                    "the token file {shown} has mode {mode:04o} and owner uid {} (this daemon runs as uid {me}): a token \
                     written there could be read by others; remove the file (the daemon creates it with mode 0600), \
                     or give --auth FILE",
                    old.uid()
                ));
            }
        }
        #[cfg(not(unix))]
        let _ = &existing;
        writeln!(f, "{secret}")
            .and_then(|()| f.sync_all())
            .and_then(|()| std::fs::rename(&tmp, path))
            .map_err(|e| format!("cannot write the token file {shown}: {e}"))
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

fn load_plans(dir: Option<&Path>, data: &Path, rig: &RigConfig) -> Result<Vec<NamedPlan>, String> {
    let mut sources: Vec<(String, String, PathBuf)> = Vec::new();
    match dir {
        None => {
            for (name, text) in EMBEDDED_PLANS {
                sources.push((name.to_string(), text.to_string(), data.join(format!("{name}.toml"))));
            }
        }
        Some(d) => {
            let entries = std::fs::read_dir(d).map_err(|e| format!("--plans {}: {e}", d.display()))?;
            for e in entries.flatten() {
                let p = e.path();
                if p.extension().and_then(|x| x.to_str()) != Some("toml") {
                    continue;
                }
                let name = p.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_default();
                let text = std::fs::read_to_string(&p).map_err(|e| format!("{}: {e}", p.display()))?;
                sources.push((name, text, p));
            }
        }
    }
    let mut plans = Vec::new();
    for (name, text, path) in sources {
        // Plans for other rigs (or another kind of rig), or that do not validate, are not
        // offered (logged).
        match btfrig_measurement::check::check_for_rig(&text, &path, rig) {
            Ok(c) => plans.push(NamedPlan { name, captures: c.captures(), description: c.description(), text, path }),
            Err(e @ btfrig_measurement::RunError::WrongRig { .. }) => tracing::info!("plan {name}: not offered: {e}"),
            Err(e) => tracing::warn!("plan {name}: not offered: {e}"),
        }
    }
    plans.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(plans)
}

const INDEX_HTML: &str = include_str!("../ui/index.html");
const APP_JS: &str = include_str!("../ui/app.js");
const STYLE_CSS: &str = include_str!("../ui/style.css");
const VIEWER_HTML: &str = include_str!("../ui/viewer.html");
const VIEWER_JS: &str = include_str!("../ui/viewer.js");

/// Every route of the daemon.
pub fn router(state: Arc<AppState>) -> Router {
    let api = Router::new()
        .route("/openapi.json", get(api::openapi))
        .route("/me", get(api::me))
        .route("/rig", get(api::rig_status))
        .route("/rig/stop", post(api::rig_stop))
        .route("/plans", get(api::list_plans))
        .route("/plans/validate", post(api::validate_plan))
        .route("/plans/dry-run", post(api::dry_run_plan))
        .route("/runs", get(api::list_runs).post(api::start_run))
        .route("/runs/{id}", get(api::get_run))
        .route("/runs/{id}/pause", post(api::pause_run))
        .route("/runs/{id}/resume", post(api::resume_run))
        .route("/runs/{id}/abort", post(api::abort_run))
        .route("/runs/{id}/events", get(api::run_events))
        .route("/preview", get(api::preview))
        .route("/datasets", get(api::list_datasets))
        .route("/datasets/{name}", get(api::get_dataset))
        .route("/datasets/{name}/files/{*path}", get(api::get_dataset_file))
        .route("/datasets/{name}/coverage", get(api::get_coverage))
        .route("/datasets/{name}/models/{model}/data", get(api::get_model_data))
        .route("/datasets/{name}/models/{model}/render", get(api::render_model))
        .route("/datasets/{name}/models/{model}/compare", get(api::compare_model))
        .route("/datasets/{name}/models/{model}/errors", get(api::model_errors))
        .route("/calibrations", get(api::list_calibrations).post(api::start_calibration))
        .route("/calibrations/{id}", get(api::get_calibration));
    let metrics = state.metrics.clone();
    Router::new()
        .nest("/api/v1", api)
        .route("/", get(|| async { ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], INDEX_HTML) }))
        .route("/ui/app.js", get(|| async { ([(header::CONTENT_TYPE, "text/javascript; charset=utf-8")], APP_JS) }))
        .route("/ui/style.css", get(|| async { ([(header::CONTENT_TYPE, "text/css; charset=utf-8")], STYLE_CSS) }))
        .route("/viewer", get(|| async { ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], VIEWER_HTML) }))
        .route(
            "/ui/viewer.js",
            get(|| async { ([(header::CONTENT_TYPE, "text/javascript; charset=utf-8")], VIEWER_JS) }),
        )
        .route(
            "/ui/plots.js",
            get(|| async { ([(header::CONTENT_TYPE, "text/javascript; charset=utf-8")], look::PLOTS_JS) }),
        )
        .route(
            "/ui/vendor/uPlot.iife.min.js",
            get(|| async { ([(header::CONTENT_TYPE, "text/javascript; charset=utf-8")], look::UPLOT_JS) }),
        )
        .route(
            "/ui/vendor/uPlot.min.css",
            get(|| async { ([(header::CONTENT_TYPE, "text/css; charset=utf-8")], look::UPLOT_CSS) }),
        )
        .route("/healthz", get(api::healthz))
        .route("/metrics", get(api::metrics))
        .fallback(api::not_found)
        .method_not_allowed_fallback(api::method_not_allowed)
        .layer(DefaultBodyLimit::max(BODY_LIMIT))
        .layer(axum::middleware::from_fn(server::limit_and_log))
        .layer(axum::middleware::map_response(move |r: axum::response::Response| {
            let metrics = metrics.clone();
            async move {
                metrics.http(r.status().as_u16());
                r
            }
        }))
        .with_state(state)
}

/// Runs the daemon until SIGTERM or SIGINT. Prints `listening on http://ADDR` first (with
/// the real port when asked for port 0).
pub async fn serve(cfg: ServeConfig) -> Result<(), ServeError> {
    let (state, generated) = AppState::load(&cfg)?;
    let state = Arc::new(state);
    let listener = tokio::net::TcpListener::bind(cfg.listen)
        .await
        .map_err(|source| ServeError::Bind { addr: cfg.listen, source })?;
    let addr = listener.local_addr()?;
    println!("listening on http://{addr}");
    if generated.is_some() {
        // The token itself is never printed: stderr ends up in service logs.
        eprintln!(
            "no --auth file: a new admin token is in {} (mode 0600); give an auth file for viewer/operator tokens (docs/http-api.md)",
            cfg.data.join("daemon-token").display()
        );
    }
    eprintln!(
        "rig {} ({}), data {}, {} named plans",
        state.rig.rig.name,
        state.rig_source,
        cfg.data.display(),
        state.plans.len()
    );
    let app = router(state.clone());
    let shutdown_state = state.clone();
    server::serve_connections(listener, app, cfg.header_read_timeout, async move {
        let signal = shutdown_signal().await;
        eprintln!("shutting down on {}: interrupting the run under way (its dataset stays resumable)", signal.name());
        // Plan checks and dry runs in flight stop too, so that the graceful shutdown does not
        // wait for them.
        shutdown_state.metrics.plan_jobs.cancel_all();
        let s = shutdown_state.clone();
        let _ = tokio::task::spawn_blocking(move || s.runs.interrupt_and_wait(signal)).await;
    })
    .await?;
    Ok(())
}

/// Waits for SIGTERM or SIGINT and says which came.
async fn shutdown_signal() -> btfrig_measurement::Signal {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        let mut term = match signal(SignalKind::terminate()) {
            Ok(s) => s,
            Err(_) => return std::future::pending().await,
        };
        tokio::select! {
            _ = term.recv() => btfrig_measurement::Signal::Term,
            _ = tokio::signal::ctrl_c() => btfrig_measurement::Signal::Int,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
        btfrig_measurement::Signal::Int
    }
}
