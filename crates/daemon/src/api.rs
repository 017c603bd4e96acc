//! The HTTP API under `/api/v1`: thin handlers over [`crate::runs`], the runner and the
//! store; the OpenAPI document is generated from the annotations here.

use std::path::{Component, Path, PathBuf};
use std::sync::Arc;

use axum::body::Body;
use axum::extract::rejection::JsonRejection;
use axum::extract::{FromRequest, FromRequestParts, Request, State};
use axum::http::request::Parts;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::{Deserialize, Serialize};
use utoipa::{OpenApi, ToSchema};

use crate::auth::{Caller, Role};
use crate::calibrations::{Calibration, StartCalibration};
use crate::problem::Problem;
use crate::runs::{Control, ProgressUnit, RunState, RunStatus, ServerEvent, StartRequest};
use crate::AppState;

type Shared = State<Arc<AppState>>;

// ---- extractors -------------------------------------------------------------------------

/// The caller, with at least role viewer / operator / admin; 401 or 403 otherwise.
pub struct Viewer(pub Caller);
/// See [`Viewer`].
pub struct Operator(pub Caller);
/// See [`Viewer`].
pub struct Admin(pub Caller);

macro_rules! role_extractor {
    ($t:ident, $role:expr) => {
        impl FromRequestParts<Arc<AppState>> for $t {
            type Rejection = Problem;
            async fn from_request_parts(parts: &mut Parts, state: &Arc<AppState>) -> Result<Self, Problem> {
                state.auth.check(&parts.method, &parts.uri, &parts.headers, $role).map($t)
            }
        }
    };
}
role_extractor!(Viewer, Role::Viewer);
role_extractor!(Operator, Role::Operator);
role_extractor!(Admin, Role::Admin);

/// A JSON body whose every rejection is a problem document (axum's are plain text).
pub struct ApiJson<T>(pub T);

impl<T: serde::de::DeserializeOwned, S: Send + Sync> FromRequest<S> for ApiJson<T> {
    type Rejection = Problem;
    async fn from_request(req: Request, state: &S) -> Result<Self, Problem> {
        // Parsed as a value first: every body of the API is an object, and serde would take a
        // struct from an array too (`[null, null]` as two absent fields).
        let value = match Json::<serde_json::Value>::from_request(req, state).await {
            Ok(Json(v)) => v,
            Err(e) => {
                return Err(match &e {
                    JsonRejection::MissingJsonContentType(_) => Problem::new(
                        StatusCode::UNSUPPORTED_MEDIA_TYPE,
                        "the body must be JSON: send Content-Type: application/json",
                    ),
                    JsonRejection::BytesRejection(_) if e.status() == StatusCode::PAYLOAD_TOO_LARGE => Problem::new(
                        StatusCode::PAYLOAD_TOO_LARGE,
                        format!("the body is larger than {} bytes", crate::BODY_LIMIT),
                    ),
                    _ => Problem::bad_request(format!("the body is not valid JSON: {}", e.body_text())),
                })
            }
        };
        if !value.is_object() {
            return Err(Problem::unprocessable(format!(
                "the body must be a JSON object (see the operation's schema in /api/v1/openapi.json), not {}",
                json_type(&value)
            )));
        }
        serde_json::from_value(integral_numbers(value))
            .map(ApiJson)
            .map_err(|e| Problem::unprocessable(format!("the body does not fit the schema: {e}")))
    }
}

/// `value` with every number that has no fractional part (`517.0`) as an integer: JSON Schema's
/// `integer` includes them, serde's integer fields do not.
fn integral_numbers(value: serde_json::Value) -> serde_json::Value {
    use serde_json::Value;
    match value {
        Value::Number(n) if n.is_f64() => {
            let f = n.as_f64().unwrap_or(f64::NAN);
            // 2^63 and 2^64 are exact in f64, so the casts below are exact within these bounds.
            if f.fract() == 0.0 && (0.0..18_446_744_073_709_551_616.0).contains(&f) {
                Value::from(f as u64)
            } else if f.fract() == 0.0 && (-9_223_372_036_854_775_808.0..0.0).contains(&f) {
                Value::from(f as i64)
            } else {
                Value::Number(n)
            }
        }
        Value::Array(items) => Value::Array(items.into_iter().map(integral_numbers).collect()),
        Value::Object(map) => Value::Object(map.into_iter().map(|(k, v)| (k, integral_numbers(v))).collect()),
        other => other,
    }
}

fn json_type(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    }
}

/// A path parameter, with a problem document when it does not parse.
pub struct ApiPath<T>(pub T);

impl<T: serde::de::DeserializeOwned + Send, S: Send + Sync> FromRequestParts<S> for ApiPath<T> {
    type Rejection = Problem;
    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Problem> {
        axum::extract::Path::<T>::from_request_parts(parts, state)
            .await
            .map(|axum::extract::Path(v)| ApiPath(v))
            .map_err(|e| Problem::bad_request(format!("bad path parameter: {}", e.body_text())))
    }
}

// ---- schemas ----------------------------------------------------------------------------

/// The rig and its devices.
#[derive(Debug, Serialize, ToSchema)]
pub struct RigStatus {
    /// The rig config.
    pub rig: RigSummary,
    /// One entry per device.
    pub devices: Vec<DeviceStatus>,
    /// Who holds the rig, when someone does.
    pub busy: Option<Busy>,
}

/// The rig config's identity.
#[derive(Debug, Serialize, ToSchema)]
pub struct RigSummary {
    /// The rig config's name.
    pub name: String,
    /// `gonioreflectometer`, `dome`, ...
    pub kind: String,
    /// Where the config came from.
    pub source: String,
}

/// One device.
#[derive(Debug, Serialize, ToSchema)]
pub struct DeviceStatus {
    /// `robot`, `rail`, `turntable`, `lamp`, `led_array`, `camera`.
    pub name: String,
    /// The backend (`sim`, ...).
    pub kind: String,
    /// `idle`, `in use`, `paused`.
    pub state: String,
    /// What the device is doing or what it is.
    pub detail: String,
}

/// Who holds the rig.
#[derive(Debug, Serialize, ToSchema)]
pub struct Busy {
    /// The run (or calibration) id.
    pub run_id: String,
    /// The token name that started it.
    pub owner: String,
}

/// The plans the daemon offers by name.
#[derive(Debug, Serialize, ToSchema)]
pub struct PlanList {
    /// By name.
    pub plans: Vec<PlanEntry>,
}

/// A named plan.
#[derive(Debug, Serialize, ToSchema)]
pub struct PlanEntry {
    /// What `{"plan": name}` refers to.
    pub name: String,
    /// Captures it makes.
    pub captures: u64,
    /// The plan's description.
    pub description: String,
}

/// A plan by name or as TOML text (exactly one).
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PlanBody {
    /// A name from `GET /api/v1/plans`.
    pub plan: Option<String>,
    /// A whole plan file (docs/plan-format.md).
    pub plan_text: Option<String>,
}

/// What validating or dry-running a plan found.
#[derive(Debug, Serialize, ToSchema)]
pub struct PlanCheck {
    /// True when the plan can run on this rig.
    pub valid: bool,
    /// The plan's format: `gonioreflectometer` (light and view samplings) or `dome` (a
    /// `[dome]` table: LED domes and camera arrays); `null` when no plan was given or its
    /// text is not TOML.
    pub kind: Option<PlanKind>,
    /// Captures it makes: (light, view) pairs of a gonio plan, textures (lights x views) of a
    /// dome plan (0 when invalid).
    pub captures: u64,
    /// Estimated hardware time, seconds (dry run only). A dome plan's is `dome.rig_time_s`,
    /// a lower bound.
    pub estimate_s: Option<f64>,
    /// Hardware time of the naive order, seconds (dry run of a gonio plan only).
    pub naive_order_s: Option<f64>,
    /// Lower bound on any order, seconds (dry run of a gonio plan only).
    pub lower_bound_s: Option<f64>,
    /// Estimated disk space, bytes (dry run only; a dome plan's stored textures).
    pub disk_bytes: Option<u64>,
    /// The dry run as `btfrig plan show` prints it (dry run only).
    pub text: Option<String>,
    /// The dome dry run: the multiplexing choice with its reason and every candidate mode
    /// (dry run of a dome plan only).
    pub dome: Option<DomeDryRun>,
    /// Every problem, each naming its field.
    pub errors: Vec<String>,
}

/// A plan's format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum PlanKind {
    /// Light and view samplings (`[sampling]`), run on a gonioreflectometer.
    Gonioreflectometer,
    /// A `[dome]` table, run on an LED dome or a camera array.
    Dome,
}

impl From<btfrig_measurement::check::PlanKind> for PlanKind {
    fn from(k: btfrig_measurement::check::PlanKind) -> PlanKind {
        match k {
            btfrig_measurement::check::PlanKind::Gonio => PlanKind::Gonioreflectometer,
            btfrig_measurement::check::PlanKind::Dome => PlanKind::Dome,
        }
    }
}

/// The dry run of a dome plan (`btfrig plan show` on it; docs/multiplexing.md): how the
/// views are captured, what the noise model predicts, and what it costs. Rig times are
/// estimates from the rig's `[timing]` that leave out the serial round trips: lower bounds
/// (measured 1 % under a run's rig time).
#[derive(Debug, Serialize, ToSchema)]
pub struct DomeDryRun {
    /// The rig's `[rig] kind`: `led_dome` or `camera_array`.
    pub rig_kind: String,
    /// What a light is: `LED`, or `flash` on a camera array.
    pub light: String,
    /// Lights of the rig (LEDs or flashes); every one is captured in every view.
    pub lights: u64,
    /// Camera indices captured.
    pub cameras: Vec<u64>,
    /// Turntable rotation indices captured.
    pub rotations: Vec<u64>,
    /// Views: cameras x rotations.
    pub views: u64,
    /// Textures the run stores: lights x views.
    pub textures: u64,
    /// The mode the plan captures with: `single-light`, `s-matrix 199`, `groups 7 x 31` (7
    /// groups of 31 lights) — the noise model's choice, or the one the plan forces.
    pub mode: String,
    /// Why, in one line (`multiplexing with ...: predicted gain ...` or `multiplexing
    /// skipped: ...`).
    pub reason: String,
    /// The mode the noise model chose (equal to `mode` unless the plan forces one).
    pub noise_model_choice: String,
    /// Predicted SNR gain of `mode` over single-light capture at equal total exposure (1 for
    /// single light).
    pub predicted_gain: f64,
    /// Fraction of the exposure time (of the frames, for flashes) single-light capture would
    /// need beyond this mode's to reach the same SNR (0 for single light).
    pub time_saved_fraction: f64,
    /// Frames per camera, reference frames included.
    pub frames_per_camera: u64,
    /// Frames of one view group's code (lights in single-light mode).
    pub frames_per_view_group: u64,
    /// Single-light reference frames in the first view group (they measure the gain; not stored).
    pub reference_frames: u64,
    /// Exposure of a pattern frame, s.
    pub pattern_exposure_s: f64,
    /// Exposure of a single-light frame, s.
    pub single_exposure_s: f64,
    /// Estimated rig time, s (a lower bound): the sum of the four parts below.
    pub rig_time_s: f64,
    /// Of it: exposing, s.
    pub exposing_s: f64,
    /// Of it: read-out and transfer, s.
    pub transfer_s: f64,
    /// Of it: turning the table, s.
    pub turntable_s: f64,
    /// Of it: LED switching, trigger latency and exposure commands, s.
    pub commands_s: f64,
    /// Homing the turntable before the run, s (not in `rig_time_s`).
    pub home_s: f64,
    /// Bytes of the stored textures (32-bit float RGB OpenEXR).
    pub disk_bytes: u64,
    /// Memory one view group's frame stack holds, bytes (all cameras).
    pub group_bytes: u64,
    /// Every mode the noise model evaluated, single light first.
    pub candidates: Vec<DomeCandidate>,
}

/// One capture mode the noise model evaluated, planned for this plan as if it forced it.
#[derive(Debug, Serialize, ToSchema)]
pub struct DomeCandidate {
    /// `single-light`, `s-matrix 199`, `groups 7 x 31`.
    pub mode: String,
    /// True for the noise model's choice.
    pub chosen: bool,
    /// True for the mode the plan captures with.
    pub used: bool,
    /// Predicted SNR gain over single light at equal total exposure time.
    pub predicted_gain: f64,
    /// Frames of one view group's code.
    pub frames_per_view_group: u64,
    /// Frames per camera in this mode, reference frames included.
    pub frames_per_camera: u64,
    /// Lights lit per frame (mean).
    pub lit: f64,
    /// Exposure per frame, s.
    pub exposure_s: f64,
    /// Exposure kept against saturation (1: none cut).
    pub saturation_factor: f64,
    /// Photon-to-signal-independent noise variance ratio `σ_p²/κ²` at this exposure.
    pub rho: f64,
    /// Estimated rig time in this mode, s (a lower bound).
    pub rig_time_s: f64,
    /// Bytes of the stored textures in this mode (the same for every mode: one texture per
    /// light and view).
    pub disk_bytes: u64,
    /// Memory one view group's frame stack holds in this mode, bytes.
    pub group_bytes: u64,
}

impl DomeDryRun {
    /// The API's view of the runner's dome dry run.
    pub fn from_runner(
        d: &btfrig_measurement::dome_dry_run::DomeDryRun,
        rig: &btfrig_core::config::RigConfig,
    ) -> DomeDryRun {
        let s = &d.schedule;
        DomeDryRun {
            rig_kind: rig.rig.kind.as_str().into(),
            light: d.light.into(),
            lights: s.leds as u64,
            cameras: d.cameras.iter().map(|&c| c as u64).collect(),
            rotations: d.rotations.iter().map(|&k| u64::from(k)).collect(),
            views: (d.cameras.len() * d.rotations.len()) as u64,
            textures: d.textures as u64,
            mode: s.mode.describe(),
            reason: s.reason.clone(),
            noise_model_choice: s.choice.best.mode.describe(),
            predicted_gain: s.predicted_gain,
            time_saved_fraction: s.time_saved_fraction,
            frames_per_camera: d.frames as u64,
            frames_per_view_group: s.patterns.len() as u64,
            reference_frames: d.reference_frames() as u64,
            pattern_exposure_s: s.exposure_s,
            single_exposure_s: s.single_exposure_s,
            rig_time_s: d.rig_time_s,
            exposing_s: d.exposure_s,
            transfer_s: d.transfer_s,
            turntable_s: d.turntable_s,
            commands_s: d.commands_s,
            home_s: d.home_s,
            disk_bytes: d.texture_bytes,
            group_bytes: d.group_bytes,
            candidates: d
                .candidates
                .iter()
                .map(|c| DomeCandidate {
                    mode: c.prediction.mode.describe(),
                    chosen: c.chosen,
                    used: c.used,
                    predicted_gain: c.prediction.gain,
                    frames_per_view_group: c.prediction.frames as u64,
                    frames_per_camera: c.frames as u64,
                    lit: c.prediction.lit,
                    exposure_s: c.prediction.exposure_s,
                    saturation_factor: c.prediction.saturation_factor,
                    rho: c.prediction.rho,
                    rig_time_s: c.rig_time_s,
                    disk_bytes: d.texture_bytes,
                    group_bytes: c.group_bytes,
                })
                .collect(),
        }
    }
}

/// Start a run.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StartRun {
    /// A name from `GET /api/v1/plans`.
    pub plan: Option<String>,
    /// A whole plan file.
    pub plan_text: Option<String>,
    /// The dataset's name under the data directory: 1 to 63 characters of any script, no `/`,
    /// `\\` or control character, not starting with `.` ([`check_name`]). An existing dataset of
    /// the same plan is resumed; default: a new name.
    // Its pattern is NAME_PATTERN (set in `document`).
    pub dataset: Option<String>,
}

/// Every run of this daemon.
#[derive(Debug, Serialize, ToSchema)]
pub struct RunList {
    /// Oldest first.
    pub runs: Vec<RunStatus>,
}

/// The datasets under the data directory.
#[derive(Debug, Serialize, ToSchema)]
pub struct DatasetList {
    /// By name.
    pub datasets: Vec<DatasetEntry>,
}

/// A dataset.
#[derive(Debug, Serialize, ToSchema)]
pub struct DatasetEntry {
    /// Its directory name.
    pub name: String,
    /// `finished`, `aborted`, `interrupted`, `paused` (its last report), `running`, or
    /// `incomplete` (no report yet).
    pub state: String,
    /// Captures done as of its last report (a dome dataset: textures; of the run under way:
    /// now).
    pub captures: u64,
    /// The plan's name.
    pub plan: String,
    /// Its compressed models: the `<method>` of each `<name>.<method>.btfm` beside it.
    pub models: Vec<String>,
}

/// The list of calibrations.
#[derive(Debug, Serialize, ToSchema)]
pub struct CalibrationList {
    /// Oldest first.
    pub calibrations: Vec<Calibration>,
}

/// `/healthz`.
#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    /// `ok`.
    pub status: String,
}

/// What `POST /api/v1/rig/stop` did.
#[derive(Debug, Serialize, ToSchema)]
pub struct Stopped {
    /// The run asked to stop, if one held the rig.
    pub run_id: Option<String>,
}

// Response sets shared by many operations (every error is a problem document).

/// 401 and 403.
#[derive(utoipa::IntoResponses)]
#[allow(dead_code)]
pub enum AuthErrors {
    /// No or unknown token.
    #[response(status = 401, description = "No or unknown token", content_type = "application/problem+json")]
    Unauthorized(Problem),
    /// Role too low (or another operator's run).
    #[response(
        status = 403,
        description = "Role too low, or another operator's run",
        content_type = "application/problem+json"
    )]
    Forbidden(Problem),
}

/// What a JSON body can be refused with.
#[derive(utoipa::IntoResponses)]
#[allow(dead_code)]
pub enum BodyErrors {
    /// Not JSON.
    #[response(status = 400, description = "Malformed JSON", content_type = "application/problem+json")]
    Malformed(Problem),
    /// Over the limit.
    #[response(status = 413, description = "Body too large", content_type = "application/problem+json")]
    TooLarge(Problem),
    /// No JSON content type.
    #[response(status = 415, description = "Not application/json", content_type = "application/problem+json")]
    NotJson(Problem),
    /// Does not fit the schema (or, on start, an unacceptable plan or dataset name).
    #[response(
        status = 422,
        description = "Does not fit the schema, or the plan or dataset name is not acceptable",
        content_type = "application/problem+json"
    )]
    Unprocessable(Problem),
}

/// A path parameter that does not parse, or names nothing.
#[derive(utoipa::IntoResponses)]
#[allow(dead_code)]
pub enum PathErrors {
    /// Bad path.
    #[response(status = 400, description = "Bad path", content_type = "application/problem+json")]
    BadPath(Problem),
    /// Nothing there.
    #[response(status = 404, description = "No such resource", content_type = "application/problem+json")]
    NotFound(Problem),
}

// ---- OpenAPI ----------------------------------------------------------------------------

#[derive(OpenApi)]
#[openapi(
    info(title = "btfrig daemon", description = "Controls a BTF measurement rig: runs, events, previews, datasets, calibrations. docs/http-api.md."),
    paths(
        healthz, me, rig_status, rig_stop, list_plans, validate_plan, dry_run_plan, start_run, list_runs, get_run,
        pause_run, resume_run, abort_run, run_events, preview, list_datasets, get_dataset, get_dataset_file,
        get_coverage, get_model_data, render_model, compare_model, model_errors, start_calibration, list_calibrations, get_calibration
    ),
    components(schemas(Problem, RunStatus, RunState, ProgressUnit, crate::look::Coverage, crate::look::PairState)),
    modifiers(&BearerScheme)
)]
/// The OpenAPI document, generated from the handlers above.
pub struct ApiDoc;

struct BearerScheme;

impl utoipa::Modify for BearerScheme {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
    }
}

/// The served document: [`ApiDoc`] with the bodies utoipa cannot describe — the event
/// stream (an event name and JSON data per event) and files of any type.
pub fn document() -> serde_json::Value {
    let mut doc = serde_json::to_value(ApiDoc::openapi()).unwrap_or_default();
    let paths = &mut doc["paths"];
    paths["/api/v1/runs/{id}/events"]["get"]["responses"]["200"]["content"]["text/event-stream"]["schema"] = serde_json::json!({
        "type": "object",
        "required": ["event", "data"],
        "properties": {
            "event": { "type": "string", "enum": ["status", "warning", "end"] },
            "data": { "type": "string", "contentMediaType": "application/json" }
        },
        "oneOf": [
            { "properties": { "event": { "enum": ["status", "end"] },
                "data": { "contentMediaType": "application/json", "contentSchema": { "$ref": "#/components/schemas/RunStatus" } } } },
            { "properties": { "event": { "const": "warning" },
                "data": { "contentMediaType": "application/json",
                    "contentSchema": { "type": "object", "required": ["message"], "properties": { "message": { "type": "string" } } } } } }
        ]
    });
    // A dataset file is JSON, PNG, EXR, TOML or the journal: its type follows its name.
    paths["/api/v1/datasets/{name}/files/{path}"]["get"]["responses"]["200"]["content"] =
        serde_json::json!({ "*/*": {} });
    paths["/api/v1/preview"]["get"]["responses"]["200"]["content"] = serde_json::json!({ "image/png": {} });
    paths["/api/v1/datasets/{name}/models/{model}/render"]["get"]["responses"]["200"]["content"] =
        serde_json::json!({ "image/png": {}, "image/x-exr": {} });
    // Dataset names as `check_name` takes them, written once.
    for op in [
        "/api/v1/datasets/{name}",
        "/api/v1/datasets/{name}/files/{path}",
        "/api/v1/datasets/{name}/coverage",
        "/api/v1/datasets/{name}/models/{model}/data",
        "/api/v1/datasets/{name}/models/{model}/render",
        "/api/v1/datasets/{name}/models/{model}/compare",
        "/api/v1/datasets/{name}/models/{model}/errors",
    ] {
        if let Some(params) = paths[op]["get"]["parameters"].as_array_mut() {
            for p in params.iter_mut() {
                if p["name"] == "name" {
                    p["schema"]["pattern"] = NAME_PATTERN.into();
                }
                if p["name"] == "model" {
                    p["schema"]["pattern"] = MODEL_PATTERN.into();
                }
            }
        }
    }
    doc["components"]["schemas"]["StartRun"]["properties"]["dataset"]["pattern"] = NAME_PATTERN.into();
    // The render's ranges, as `look::pair_from_degrees` and `render_model` check them.
    if let Some(params) =
        doc["paths"]["/api/v1/datasets/{name}/models/{model}/render"]["get"]["parameters"].as_array_mut()
    {
        for p in params.iter_mut() {
            match p["name"].as_str() {
                Some("light_theta" | "view_theta") => {
                    p["schema"]["minimum"] = 0.into();
                    p["schema"]["maximum"] = 90.into();
                }
                Some("scale") => p["schema"]["exclusiveMinimum"] = 0.into(),
                Some("format") => p["schema"]["enum"] = serde_json::json!(["png", "exr"]),
                _ => {}
            }
        }
    }
    // The calibrations the daemon runs, from the list it checks against.
    doc["components"]["schemas"]["StartCalibration"]["properties"]["kind"]["enum"] =
        crate::calibrations::KINDS.iter().map(|k| serde_json::Value::from(*k)).collect();
    add_links(&mut doc["paths"]);
    doc
}

/// OpenAPI links: what a response's identifiers lead to (a started run to its status, its
/// controls, its events and its dataset; a calibration to its state), so clients and
/// stateful testers can chain the operations.
fn add_links(paths: &mut serde_json::Value) {
    let by = |operation: &str, param: &str, value: &str| serde_json::json!({ "operationId": operation, "parameters": { param: value } });
    let run_links = |from: &str| {
        let id = format!("$response.body#/{from}");
        serde_json::json!({
            "GetRun": by("get_run", "id", &id),
            "PauseRun": by("pause_run", "id", &id),
            "ResumeRun": by("resume_run", "id", &id),
            "AbortRun": by("abort_run", "id", &id),
            "RunEvents": by("run_events", "id", &id),
            "GetDataset": by("get_dataset", "name", "$response.body#/dataset"),
        })
    };
    for (path, method, status) in [
        ("/api/v1/runs", "post", "201"),
        ("/api/v1/runs/{id}", "get", "200"),
        ("/api/v1/runs/{id}/pause", "post", "200"),
        ("/api/v1/runs/{id}/resume", "post", "200"),
        ("/api/v1/runs/{id}/abort", "post", "200"),
    ] {
        paths[path][method]["responses"][status]["links"] = run_links("id");
    }
    paths["/api/v1/calibrations"]["post"]["responses"]["202"]["links"] =
        serde_json::json!({ "GetCalibration": by("get_calibration", "id", "$response.body#/id") });
}

/// `GET /api/v1/openapi.json`.
pub async fn openapi() -> Response {
    static DOC: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    let text = DOC.get_or_init(|| document().to_string());
    ([(header::CONTENT_TYPE, "application/json")], text.clone()).into_response()
}

/// Who the token is.
#[derive(Debug, Serialize, ToSchema)]
pub struct Me {
    /// The token's name.
    pub name: String,
    /// Its role.
    pub role: Role,
}

#[utoipa::path(get, path = "/api/v1/me", tag = "daemon", security(("bearer" = [])),
    responses((status = 200, description = "The caller's name and role", body = Me), AuthErrors))]
/// The caller's name and role (a page greys out what the role may not do).
pub async fn me(_s: Shared, Viewer(c): Viewer) -> Json<Me> {
    Json(Me { name: c.name, role: c.role })
}

// ---- handlers ---------------------------------------------------------------------------

#[utoipa::path(get, path = "/healthz", tag = "daemon", responses((status = 200, description = "The daemon answers", body = Health)))]
/// Liveness.
pub async fn healthz() -> Json<Health> {
    Json(Health { status: "ok".into() })
}

#[utoipa::path(get, path = "/api/v1/rig", tag = "rig", security(("bearer" = [])),
    responses((status = 200, description = "The rig and its devices", body = RigStatus),
        AuthErrors))]
/// The rig, its devices and who holds it.
pub async fn rig_status(State(s): Shared, _v: Viewer) -> Json<RigStatus> {
    Json(s.rig_status())
}

#[utoipa::path(post, path = "/api/v1/rig/stop", tag = "rig", security(("bearer" = [])),
    responses((status = 200, description = "The current run (if any) is asked to stop after the step under way", body = Stopped),
        AuthErrors))]
/// Stops the rig: aborts whatever run holds it, whoever owns it (admin).
pub async fn rig_stop(State(s): Shared, _a: Admin) -> Json<Stopped> {
    let run_id = s.runs.current().and_then(|r| r.control(Control::Abort).ok().map(|st| st.id));
    Json(Stopped { run_id })
}

#[utoipa::path(get, path = "/api/v1/plans", tag = "plans", security(("bearer" = [])),
    responses((status = 200, description = "Plans by name", body = PlanList),
        AuthErrors))]
/// The plans the daemon offers by name.
pub async fn list_plans(State(s): Shared, _v: Viewer) -> Json<PlanList> {
    Json(PlanList {
        plans: s
            .plans
            .iter()
            .map(|p| PlanEntry { name: p.name.clone(), captures: p.captures, description: p.description.clone() })
            .collect(),
    })
}

#[utoipa::path(post, path = "/api/v1/plans/validate", tag = "plans", security(("bearer" = [])), request_body = PlanBody,
    responses((status = 200, description = "Whether the plan is valid, with every problem", body = PlanCheck),
        AuthErrors,
        BodyErrors))]
/// Validates a plan against this rig.
pub async fn validate_plan(State(s): Shared, _v: Viewer, ApiJson(b): ApiJson<PlanBody>) -> Json<PlanCheck> {
    Json(s.check_plan(b, false).await)
}

#[utoipa::path(post, path = "/api/v1/plans/dry-run", tag = "plans", security(("bearer" = [])), request_body = PlanBody,
    responses((status = 200, description = "The dry run: captures, time and disk estimates", body = PlanCheck),
        AuthErrors,
        BodyErrors))]
/// Validates and plans a plan: what `btfrig plan show` prints.
pub async fn dry_run_plan(State(s): Shared, _v: Viewer, ApiJson(b): ApiJson<PlanBody>) -> Json<PlanCheck> {
    Json(s.check_plan(b, true).await)
}

#[utoipa::path(post, path = "/api/v1/runs", tag = "runs", security(("bearer" = [])), request_body = StartRun,
    responses((status = 201, description = "Started", body = RunStatus),
        AuthErrors,
        (status = 404, description = "No plan of that name", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The rig is held (the detail says by whom), or the dataset holds another plan", body = Problem, content_type = "application/problem+json"),
        BodyErrors))]
/// Starts a run of a plan (or resumes the same plan's dataset).
pub async fn start_run(
    State(s): Shared,
    Operator(c): Operator,
    ApiJson(b): ApiJson<StartRun>,
) -> Result<Response, Problem> {
    let (plan_text, plan_path, given_name) = s.plan_source(b.plan, b.plan_text)?;
    let (text, path, st) = (plan_text.clone(), plan_path.clone(), s.clone());
    // Counted as a plan job: the validation is bounded by the plan limits (a runaway plan is
    // refused from its counts), and the daemon's shutdown does not wait for it.
    let (_guard, record) = s.metrics.plan_jobs.start();
    let checked = tokio::task::spawn_blocking(move || {
        let _record = record;
        btfrig_measurement::check::check_for_rig(&text, &path, &st.rig)
    })
    .await
    .map_err(|e| Problem::internal(format!("plan validation crashed: {e}")))?
    .map_err(|e| Problem::unprocessable(e.to_string()))?;
    let (kind, name) = (checked.kind(), checked.name().to_string());
    match checked {
        btfrig_measurement::check::CheckedPlan::Gonio { validated, .. } => check_gonio_start(&validated)?,
        btfrig_measurement::check::CheckedPlan::Dome { plan, rig } => check_dome_start(&plan, &plan_path, &rig)?,
    }
    let plan_name = given_name.unwrap_or(name);
    let dataset = match b.dataset {
        Some(d) => {
            check_name(&d).map_err(Problem::unprocessable)?;
            d
        }
        None => s.new_dataset_name(&plan_name),
    };
    s.check_dataset_plan(&dataset, &plan_text)?;
    let run = s.runs.start(StartRequest { plan_text, plan_name, plan_path, dataset, owner: c.name, kind }, || {
        s.calibrations.running().map(|c| format!("calibration {} of {}", c.id, c.owner))
    })?;
    let status = run.status();
    let mut r = (StatusCode::CREATED, Json(&status)).into_response();
    if let Ok(v) = HeaderValue::from_str(&format!("/api/v1/runs/{}", status.id)) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    Ok(r)
}

/// What a valid gonio plan still needs before the daemon starts it (422 otherwise).
fn check_gonio_start(v: &btfrig_core::plan::ValidatedPlan) -> Result<(), Problem> {
    if v.capture_list().captures.is_empty() {
        return Err(Problem::unprocessable("the plan captures nothing"));
    }
    Ok(())
}

/// What a valid dome plan still needs before the daemon starts it, checked here so the start
/// is refused (422) rather than the run failing: its material (a rig with real devices is
/// checked device by device by the run's preflight, `btfrig_measurement::preflight`).
fn check_dome_start(
    plan: &btfrig_core::plan::dome::ValidatedDomePlan,
    plan_path: &std::path::Path,
    rig: &btfrig_core::config::RigConfig,
) -> Result<(), Problem> {
    let material = btfrig_measurement::plan::dome_material_name(plan.plan.rig.material.as_deref(), plan_path);
    btfrig_measurement::backend::installed()
        .for_rig(rig)
        .and_then(|b| {
            b.check_scene(&btfrig_measurement::backend::SceneOptions { material: material.as_deref(), faults: None })
        })
        .map_err(|e| Problem::unprocessable(format!("rig.material: {e}")))?;
    Ok(())
}

#[utoipa::path(get, path = "/api/v1/runs", tag = "runs", security(("bearer" = [])),
    responses((status = 200, description = "Every run of this daemon", body = RunList),
        AuthErrors))]
/// Every run of this daemon, oldest first.
pub async fn list_runs(State(s): Shared, _v: Viewer) -> Json<RunList> {
    Json(RunList { runs: s.runs.all().iter().map(|r| r.status()).collect() })
}

#[utoipa::path(get, path = "/api/v1/runs/{id}", tag = "runs", security(("bearer" = [])),
    params(("id" = String, Path, description = "Run id, or `current`")),
    responses((status = 200, description = "Status with progress and ETA", body = RunStatus),
        AuthErrors,
        PathErrors))]
/// A run's status (`current`: the run holding the rig, else the latest).
pub async fn get_run(State(s): Shared, _v: Viewer, ApiPath(id): ApiPath<String>) -> Result<Json<RunStatus>, Problem> {
    Ok(Json(s.run(&id)?.status()))
}

async fn control(s: &AppState, c: &Caller, id: &str, what: Control) -> Result<Json<RunStatus>, Problem> {
    let run = s.run(id)?;
    let st = run.status();
    if st.owner != c.name && c.role < Role::Admin {
        return Err(Problem::new(
            StatusCode::FORBIDDEN,
            format!("run {} belongs to {}; only {} or an admin may {:?} it", st.id, st.owner, st.owner, what),
        ));
    }
    run.control(what)?;
    Ok(Json(run.status()))
}

#[utoipa::path(post, path = "/api/v1/runs/{id}/pause", tag = "runs", security(("bearer" = [])),
    params(("id" = String, Path, description = "Run id, or `current`")),
    responses((status = 200, description = "Pausing after the step under way", body = RunStatus),
        AuthErrors,
        PathErrors,
        (status = 409, description = "The run's state does not allow it", body = Problem, content_type = "application/problem+json")))]
/// Pauses a run after the step under way.
pub async fn pause_run(
    State(s): Shared,
    Operator(c): Operator,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<RunStatus>, Problem> {
    control(&s, &c, &id, Control::Pause).await
}

#[utoipa::path(post, path = "/api/v1/runs/{id}/resume", tag = "runs", security(("bearer" = [])),
    params(("id" = String, Path, description = "Run id, or `current`")),
    responses((status = 200, description = "Resuming (a failed step is tried again)", body = RunStatus),
        AuthErrors,
        PathErrors,
        (status = 409, description = "The run is not paused", body = Problem, content_type = "application/problem+json")))]
/// Resumes a paused run.
pub async fn resume_run(
    State(s): Shared,
    Operator(c): Operator,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<RunStatus>, Problem> {
    control(&s, &c, &id, Control::Resume).await
}

#[utoipa::path(post, path = "/api/v1/runs/{id}/abort", tag = "runs", security(("bearer" = [])),
    params(("id" = String, Path, description = "Run id, or `current`")),
    responses((status = 200, description = "Ending after the step under way; the dataset stays resumable", body = RunStatus),
        AuthErrors,
        PathErrors,
        (status = 409, description = "The run is over or already stopping", body = Problem, content_type = "application/problem+json")))]
/// Aborts a run after the step under way.
pub async fn abort_run(
    State(s): Shared,
    Operator(c): Operator,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<RunStatus>, Problem> {
    control(&s, &c, &id, Control::Abort).await
}

#[utoipa::path(get, path = "/api/v1/runs/{id}/events", tag = "runs", security(("bearer" = [])),
    params(("id" = String, Path, description = "Run id, or `current`")),
    responses((status = 200, description = "Server-Sent Events: `status` (RunStatus), `warning` ({message}), `end` (RunStatus); the first event is the current status", content_type = "text/event-stream", body = String),
        AuthErrors,
        PathErrors))]
/// The run's progress as Server-Sent Events, until it ends.
pub async fn run_events(State(s): Shared, _v: Viewer, ApiPath(id): ApiPath<String>) -> Result<Response, Problem> {
    let run = s.run(&id)?;
    let rx = run.subscribe();
    let first = run.status();
    let metrics = s.metrics.clone();
    let initial =
        if first.state.is_over() { ServerEvent::End(Box::new(first)) } else { ServerEvent::Status(Box::new(first)) };
    // State: the next event to send (the initial status first), the receiver, and whether the end was sent.
    let stream = futures_util::stream::unfold((Some(initial), rx, false), move |(pending, mut rx, ended)| {
        let metrics = metrics.clone();
        async move {
            if ended {
                return None;
            }
            let ev = match pending {
                Some(e) => e,
                None => loop {
                    match rx.recv().await {
                        Ok(e) => break e,
                        Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => metrics.events_dropped(n),
                        Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
                    }
                },
            };
            let (sse, end) = match &ev {
                ServerEvent::Status(st) => (Event::default().event("status").json_data(st), false),
                ServerEvent::Warning(w) => {
                    (Event::default().event("warning").json_data(serde_json::json!({ "message": w })), false)
                }
                ServerEvent::End(st) => (Event::default().event("end").json_data(st), true),
            };
            let sse = sse.unwrap_or_else(|e| Event::default().event("error").data(e.to_string()));
            Some((Ok::<_, std::convert::Infallible>(sse), (None, rx, end)))
        }
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()).into_response())
}

#[utoipa::path(get, path = "/api/v1/preview", tag = "runs", security(("bearer" = [])),
    responses((status = 200, description = "8-bit sRGB PNG of the latest processed capture; header X-Preview-Seq counts previews", content_type = "image/png", body = Vec<u8>),
        AuthErrors,
        (status = 404, description = "No preview yet", body = Problem, content_type = "application/problem+json")))]
/// The latest preview frame of the current (or latest) run.
pub async fn preview(State(s): Shared, _v: Viewer) -> Result<Response, Problem> {
    let run = s.runs.latest().ok_or_else(|| Problem::not_found("no run yet, so no preview"))?;
    let path = run.dataset_dir().join(btfrig_store::PREVIEW_FILE);
    let seq = run.status().preview_seq;
    let bytes = tokio::fs::read(&path)
        .await
        .map_err(|_| Problem::not_found(format!("run {} has no preview yet", run.status().id)))?;
    let mut r = ([(header::CONTENT_TYPE, "image/png"), (header::CACHE_CONTROL, "no-store")], bytes).into_response();
    r.headers_mut().insert("x-preview-seq", HeaderValue::from(seq));
    Ok(r)
}

#[utoipa::path(get, path = "/api/v1/datasets", tag = "datasets", security(("bearer" = [])),
    responses((status = 200, description = "Datasets under the data directory", body = DatasetList),
        AuthErrors))]
/// The datasets under the data directory.
pub async fn list_datasets(State(s): Shared, _v: Viewer) -> Result<Json<DatasetList>, Problem> {
    let st = s.clone();
    let list = tokio::task::spawn_blocking(move || st.datasets())
        .await
        .map_err(|e| Problem::internal(format!("listing datasets crashed: {e}")))?;
    Ok(Json(DatasetList { datasets: list }))
}

#[utoipa::path(get, path = "/api/v1/datasets/{name}", tag = "datasets", security(("bearer" = [])),
    params(("name" = String, Path, description = "Dataset name")),
    responses((status = 200, description = "The dataset's manifest (docs/dataset-format.md)", body = Object),
        AuthErrors,
        PathErrors))]
/// A dataset's manifest.
pub async fn get_dataset(State(s): Shared, _v: Viewer, ApiPath(name): ApiPath<String>) -> Result<Response, Problem> {
    let file = s.dataset_file(&name, btfrig_store::MANIFEST_FILE)?;
    let bytes = tokio::fs::read(&file).await.map_err(|_| Problem::not_found(format!("no dataset named {name:?}")))?;
    Ok(([(header::CONTENT_TYPE, "application/json")], bytes).into_response())
}

#[utoipa::path(get, path = "/api/v1/datasets/{name}/files/{path}", tag = "datasets", security(("bearer" = [])),
    params(("name" = String, Path, description = "Dataset name"), ("path" = String, Path, description = "File path inside the dataset, e.g. textures/l0000_v0000.exr")),
    responses((status = 200, description = "The file", content_type = "application/octet-stream", body = Vec<u8>),
        (status = 400, description = "Bad path (absolute, `..`, or outside the dataset)", body = Problem, content_type = "application/problem+json"),
        AuthErrors,
        (status = 404, description = "No such file", body = Problem, content_type = "application/problem+json")))]
/// One file of a dataset; nothing outside the data directory is reachable.
pub async fn get_dataset_file(
    State(s): Shared,
    _v: Viewer,
    ApiPath((name, path)): ApiPath<(String, String)>,
) -> Result<Response, Problem> {
    let file = s.dataset_file(&name, &path)?;
    let bytes = tokio::fs::read(&file)
        .await
        .map_err(|_| Problem::not_found(format!("dataset {name:?} has no file {path:?}")))?;
    let ct = content_type(&file);
    Ok(([(header::CONTENT_TYPE, ct)], Body::from(bytes)).into_response())
}

/// The JSON Schema pattern of a model name, as [`crate::look::check_model_name`] decides.
pub const MODEL_PATTERN: &str = "^[A-Za-z0-9_-]{1,40}$";

#[utoipa::path(get, path = "/api/v1/datasets/{name}/coverage", tag = "datasets", security(("bearer" = [])),
    params(("name" = String, Path, description = "Dataset name")),
    responses((status = 200, description = "Every (light, view) pair: measured, skipped (and why) or pending", body = crate::look::Coverage),
        AuthErrors,
        PathErrors,
        (status = 422, description = "Not a gonio dataset, or its manifest or journal does not read", body = Problem, content_type = "application/problem+json")))]
/// The coverage of a dataset's (light, view) pairs, counted as its report counts them.
pub async fn get_coverage(
    State(s): Shared,
    _v: Viewer,
    ApiPath(name): ApiPath<String>,
) -> Result<Json<crate::look::Coverage>, Problem> {
    let root = s.dataset_root(&name)?;
    tokio::task::spawn_blocking(move || crate::look::coverage(&root))
        .await
        .map_err(|e| Problem::internal(format!("the coverage crashed: {e}")))?
        .map(Json)
        .map_err(|e| Problem::unprocessable(format!("dataset {name:?}: {e}")))
}

#[utoipa::path(get, path = "/api/v1/datasets/{name}/models/{model}/data", tag = "datasets", security(("bearer" = [])),
    params(("name" = String, Path, description = "Dataset name"),
        ("model" = String, Path, description = "The model: `<method>` of `<name>.<method>.btfm` (GET /api/v1/datasets lists them)")),
    responses((status = 200, description = "The model for the browser's renderer, streamed: `BTFVIEW1`, a u32 LE header length, \
a JSON header (samplings, triangles, blocks), then little-endian f32 blocks (docs/http-api.md, \"viewer data\")",
            content_type = "application/octet-stream", body = Vec<u8>),
        AuthErrors,
        PathErrors,
        (status = 422, description = "The model file does not read", body = Problem, content_type = "application/problem+json")))]
/// A dataset's compressed model as the viewer takes it, streamed in pieces.
pub async fn get_model_data(
    State(s): Shared,
    _v: Viewer,
    ApiPath((name, model)): ApiPath<(String, String)>,
) -> Result<Response, Problem> {
    let m = s.load_model(&name, &model).await?;
    let data = tokio::task::spawn_blocking(move || crate::look::ViewerData::new(m))
        .await
        .map_err(|e| Problem::internal(format!("preparing the model crashed: {e}")))?;
    let len = data.len();
    let stream = futures_util::stream::iter(data.chunks().map(Ok::<_, std::convert::Infallible>));
    let mut r = Body::from_stream(stream).into_response();
    r.headers_mut().insert(header::CONTENT_TYPE, HeaderValue::from_static("application/octet-stream"));
    r.headers_mut().insert(header::CONTENT_LENGTH, HeaderValue::from(len));
    Ok(r)
}

/// Where `GET .../render` evaluates the model.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct RenderQuery {
    /// Light polar angle, degrees, 0 to 90.
    pub light_theta: f64,
    /// Light azimuth, degrees.
    pub light_phi: f64,
    /// View polar angle, degrees, 0 to 90.
    pub view_theta: f64,
    /// View azimuth, degrees.
    pub view_phi: f64,
    /// Display scale of the linear values before the sRGB curve (PNG only; default: the
    /// model's display scale, as the viewer starts with).
    pub scale: Option<f64>,
    /// `png` (8-bit sRGB, the default) or `exr` (linear float RGB).
    pub format: Option<String>,
}

impl RenderQuery {
    /// The query as the handler received it, checked: the pair as directions (theta 0 to 90
    /// degrees) and a finite positive scale.
    fn checked(
        query: Result<axum::extract::Query<RenderQuery>, axum::extract::rejection::QueryRejection>,
    ) -> Result<(RenderQuery, btfrig_core::Direction, btfrig_core::Direction), Problem> {
        let axum::extract::Query(q) = query
            .map_err(|e| Problem::unprocessable(format!("bad query: {}; see /api/v1/openapi.json", e.body_text())))?;
        let (light, view) = crate::look::pair_from_degrees([q.light_theta, q.light_phi], [q.view_theta, q.view_phi])
            .map_err(Problem::unprocessable)?;
        if let Some(sc) = q.scale {
            if !(sc.is_finite() && sc > 0.0) {
                return Err(Problem::unprocessable(format!("scale {sc}: allowed a finite number above 0")));
            }
        }
        Ok((q, light, view))
    }
}

#[utoipa::path(get, path = "/api/v1/datasets/{name}/models/{model}/render", tag = "datasets", security(("bearer" = [])),
    params(("name" = String, Path, description = "Dataset name"),
        ("model" = String, Path, description = "The model: `<method>` of `<name>.<method>.btfm`"),
        RenderQuery),
    responses((status = 200, description = "btfrig's own evaluation of the model at the pair", content_type = "image/png", body = Vec<u8>),
        AuthErrors,
        PathErrors,
        (status = 422, description = "A direction or scale out of range, or the model file does not read", body = Problem, content_type = "application/problem+json")))]
/// The model's texture at a (light, view) pair, evaluated as `btfrig dataset render` does.
pub async fn render_model(
    State(s): Shared,
    _v: Viewer,
    ApiPath((name, model)): ApiPath<(String, String)>,
    query: Result<axum::extract::Query<RenderQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, Problem> {
    // What the path names first: an unknown dataset or model is 404 whatever the query.
    let m = s.load_model(&name, &model).await?;
    let (q, light, view) = RenderQuery::checked(query)?;
    let exr = match q.format.as_deref() {
        None | Some("png") => false,
        Some("exr") => true,
        Some(f) => return Err(Problem::unprocessable(format!("format {f:?}: allowed png, exr"))),
    };
    let bytes =
        tokio::task::spawn_blocking(move || crate::look::render_file(&m, light, view, q.scale.map(|v| v as f32), exr))
            .await
            .map_err(|e| Problem::internal(format!("the render crashed: {e}")))?
            .map_err(Problem::internal)?;
    let ct = if exr { "image/x-exr" } else { "image/png" };
    Ok(([(header::CONTENT_TYPE, ct), (header::CACHE_CONTROL, "no-store")], bytes).into_response())
}

#[utoipa::path(get, path = "/api/v1/datasets/{name}/models/{model}/compare", tag = "datasets", security(("bearer" = [])),
    params(("name" = String, Path, description = "Dataset name"),
        ("model" = String, Path, description = "The model: `<method>` of `<name>.<method>.btfm`"),
        RenderQuery),
    responses((status = 200, description = "Three panels side by side (8-bit sRGB PNG): the model and the measured texture at the measured \
pair nearest to the query (both at `scale`), and their absolute difference at 4 x `scale` (`format` is not used: always PNG)",
            content_type = "image/png", body = Vec<u8>,
            headers(("x-btfrig-pair" = String, description = "The nearest measured pair: `light L view V`"),
                ("x-btfrig-directions" = String, description = "Its directions: `light THETA,PHI view THETA,PHI` in degrees"),
                ("x-btfrig-rel-rmse" = String, description = "Relative RMSE of the model against the measured texture there"))),
        AuthErrors,
        PathErrors,
        (status = 422, description = "A direction or scale out of range, or the dataset's textures or the model do not read", body = Problem, content_type = "application/problem+json")))]
/// The model beside the measurement at the measured pair nearest to the query, with their difference.
pub async fn compare_model(
    State(s): Shared,
    _v: Viewer,
    ApiPath((name, model)): ApiPath<(String, String)>,
    query: Result<axum::extract::Query<RenderQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, Problem> {
    let m = s.load_model(&name, &model).await?;
    let root = s.dataset_root(&name)?;
    let (q, light, view) = RenderQuery::checked(query)?;
    let c =
        tokio::task::spawn_blocking(move || crate::look::compare(&root, &m, light, view, q.scale.map(|v| v as f32)))
            .await
            .map_err(|e| Problem::internal(format!("the comparison crashed: {e}")))?
            .map_err(|e| Problem::unprocessable(format!("dataset {name:?}: {e}")))?;
    let hv = |t: String| HeaderValue::from_str(&t).unwrap_or(HeaderValue::from_static("?"));
    let mut r = ([(header::CONTENT_TYPE, "image/png"), (header::CACHE_CONTROL, "no-store")], c.png).into_response();
    let h = r.headers_mut();
    h.insert("x-btfrig-pair", hv(format!("light {} view {}", c.light, c.view)));
    h.insert(
        "x-btfrig-directions",
        hv(format!("light {:.2},{:.2} view {:.2},{:.2}", c.light_deg[0], c.light_deg[1], c.view_deg[0], c.view_deg[1])),
    );
    h.insert("x-btfrig-rel-rmse", hv(format!("{:.5}", c.rel_rmse)));
    Ok(r)
}

/// The model's error at every measured capture.
#[derive(Debug, Serialize, ToSchema)]
pub struct CaptureErrors {
    /// In capture (journal) order.
    pub errors: Vec<crate::look::CaptureError>,
}

#[utoipa::path(get, path = "/api/v1/datasets/{name}/models/{model}/errors", tag = "datasets", security(("bearer" = [])),
    params(("name" = String, Path, description = "Dataset name"),
        ("model" = String, Path, description = "The model: `<method>` of `<name>.<method>.btfm`")),
    responses((status = 200, description = "The model's relative RMSE at every measured capture, in capture order", body = CaptureErrors),
        AuthErrors,
        PathErrors,
        (status = 422, description = "The dataset's textures or the model do not read", body = Problem, content_type = "application/problem+json")))]
/// The compression error per capture: the model at each measured capture against its texture.
pub async fn model_errors(
    State(s): Shared,
    _v: Viewer,
    ApiPath((name, model)): ApiPath<(String, String)>,
) -> Result<Json<CaptureErrors>, Problem> {
    let m = s.load_model(&name, &model).await?;
    let root = s.dataset_root(&name)?;
    tokio::task::spawn_blocking(move || crate::look::capture_errors(&root, &m))
        .await
        .map_err(|e| Problem::internal(format!("the errors crashed: {e}")))?
        .map(|errors| Json(CaptureErrors { errors }))
        .map_err(|e| Problem::unprocessable(format!("dataset {name:?}: {e}")))
}

fn content_type(p: &Path) -> &'static str {
    match p.extension().and_then(|e| e.to_str()) {
        Some("json") => "application/json",
        Some("png") => "image/png",
        Some("toml") | Some("txt") => "text/plain; charset=utf-8",
        Some("exr") => "image/x-exr",
        _ => "application/octet-stream",
    }
}

#[utoipa::path(post, path = "/api/v1/calibrations", tag = "calibrations", security(("bearer" = [])), request_body = StartCalibration,
    responses((status = 202, description = "Started; poll GET /api/v1/calibrations/{id}", body = Calibration),
        AuthErrors,
        (status = 409, description = "The rig is held", body = Problem, content_type = "application/problem+json"),
        BodyErrors))]
/// Starts a calibration on the rig (admin).
pub async fn start_calibration(
    State(s): Shared,
    Admin(c): Admin,
    ApiJson(b): ApiJson<StartCalibration>,
) -> Result<Response, Problem> {
    let cal = crate::calibrations::start(&s, &c, b)?;
    Ok((StatusCode::ACCEPTED, Json(cal)).into_response())
}

#[utoipa::path(get, path = "/api/v1/calibrations", tag = "calibrations", security(("bearer" = [])),
    responses((status = 200, description = "Every calibration of this daemon", body = CalibrationList),
        AuthErrors))]
/// Every calibration of this daemon.
pub async fn list_calibrations(State(s): Shared, _v: Viewer) -> Json<CalibrationList> {
    Json(CalibrationList { calibrations: s.calibrations.all() })
}

#[utoipa::path(get, path = "/api/v1/calibrations/{id}", tag = "calibrations", security(("bearer" = [])),
    params(("id" = String, Path, description = "Calibration id")),
    responses((status = 200, description = "State and result", body = Calibration),
        AuthErrors,
        PathErrors))]
/// A calibration's state and result.
pub async fn get_calibration(
    State(s): Shared,
    _v: Viewer,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Calibration>, Problem> {
    s.calibrations.get(&id).map(Json).ok_or_else(|| Problem::not_found(format!("no calibration {id:?}")))
}

/// `GET /metrics`.
pub async fn metrics(State(s): Shared) -> Response {
    let cur = s.runs.current().map(|r| r.status());
    let state = cur.as_ref().map(|c| state_name(c.state));
    let text = s.metrics.render(state, cur.as_ref().map(|c| c.fraction));
    ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text).into_response()
}

/// The state as the API spells it.
pub fn state_name(s: RunState) -> &'static str {
    match s {
        RunState::Starting => "starting",
        RunState::Running => "running",
        RunState::Paused => "paused",
        RunState::Stopping => "stopping",
        RunState::Finished => "finished",
        RunState::Aborted => "aborted",
        RunState::Interrupted => "interrupted",
        RunState::Failed => "failed",
    }
}

/// Anything not routed: 404 as a problem document.
pub async fn not_found(uri: axum::http::Uri) -> Problem {
    Problem::not_found(format!("no such endpoint: {}; the API is documented at /api/v1/openapi.json", uri.path()))
}

/// A method the route does not take.
pub async fn method_not_allowed() -> Problem {
    Problem::new(StatusCode::METHOD_NOT_ALLOWED, "this endpoint does not take that method; see /api/v1/openapi.json")
}

/// Longest dataset name, in characters: UTF-8 takes at most 4 bytes a character, so a name
/// stays within Linux's 255-byte file name limit (`NAME_MAX`).
pub const MAX_NAME_CHARS: usize = 63;

/// The JSON Schema pattern of a dataset name, as [`check_name`] decides.
pub const NAME_PATTERN: &str = "^[^./\\\\\\u0000-\\u001f\\u007f-\\u009f][^/\\\\\\u0000-\\u001f\\u007f-\\u009f]{0,62}$";

/// A dataset name: one directory under the data directory. 1 to [`MAX_NAME_CHARS`] characters
/// of any script (unicode letters are fine file names on Linux), none of them `/` or `\` (a
/// path, not a name) or a control character (NUL ends a C string; line breaks forge log lines),
/// not starting with `.` (`.`, `..` and hidden files).
pub fn check_name(name: &str) -> Result<(), String> {
    let bad = name.chars().find(|&c| c == '/' || c == '\\' || c.is_control());
    let count = name.chars().count();
    let why = if count == 0 {
        "it is empty".to_string()
    } else if count > MAX_NAME_CHARS {
        format!("it has {count} characters")
    } else if name.starts_with('.') {
        "it starts with '.'".to_string()
    } else if let Some(c) = bad {
        format!("it holds {c:?}")
    } else {
        return Ok(());
    };
    Err(format!(
        "dataset name {name:?}: {why}; use 1 to {MAX_NAME_CHARS} letters, digits and other printable characters \
         (any script), no '/', '\\' or control characters, not starting with '.'"
    ))
}

/// `rel` as a relative path of plain components (no `..`, root or prefix), or why not.
pub fn relative_inside(rel: &str) -> Result<PathBuf, Problem> {
    let p = Path::new(rel);
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::Normal(s) => out.push(s),
            Component::CurDir => {}
            _ => {
                return Err(Problem::bad_request(format!(
                "file path {rel:?}: only plain relative paths inside the dataset are allowed (no '..', no leading '/')"
            )))
            }
        }
    }
    if out.as_os_str().is_empty() {
        return Err(Problem::bad_request("empty file path"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Schemathesis sent `{"kind": "color", "seed": 517.0}`: an integer to JSON Schema, a float
    /// to serde, refused with 422. Integral numbers become integers; others stay as they are.
    #[test]
    fn integral_floats_become_integers() {
        let v = integral_numbers(serde_json::json!({ "seed": 517.0, "list": [2.0, -3.0, 0.5, 1e300], "n": 7 }));
        assert!(v["seed"].is_u64() && v["seed"] == 517, "{v}");
        assert!(v["list"][0].is_u64() && v["list"][1].is_i64() && v["list"][1] == -3, "{v}");
        assert!(v["list"][2].is_f64() && v["list"][3].is_f64(), "{v}");
        let body = integral_numbers(serde_json::json!({ "kind": "color", "seed": 517.0 }));
        let b: crate::calibrations::StartCalibration = serde_json::from_value(body).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(b.seed, Some(517));
    }
}
