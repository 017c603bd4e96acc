// btfrig operator page. Plain script, no framework, no build step, no network beyond the
// daemon's own public API (/api/v1). The daemon embeds this file in its binary.
//
// Token: from the URL fragment `#token=...` (moved into sessionStorage and removed from the
// address bar) or the token field. Every request sends `Authorization: Bearer <token>`; the
// event stream (EventSource cannot send headers) uses `?access_token=`.
//
// Live state: the current run's Server-Sent Events (`status`, `warning`, `end`) when the
// stream is open, otherwise a poll of the run once a second; the rig (devices, who holds it)
// every two seconds; slower while the tab is hidden, so a forgotten tab costs the rig nothing.
"use strict";

(() => {
  const API = "/api/v1";
  const TOKEN_KEY = "btfrig.token";
  // "interrupted": the daemon was shut down during the run (resumable, like "aborted").
  const TERMINAL = new Set(["finished", "aborted", "interrupted", "failed"]);
  const MAX_WARNINGS = 50;

  const $ = (id) => document.getElementById(id);

  const ui = {
    token: $("token"), tokenForm: $("token-form"), connection: $("connection"),
    error: $("error"), errorText: $("error-text"), errorClose: $("error-close"),
    rigName: $("rig-name"), rigKind: $("rig-kind"),
    plan: $("plan"), planFile: $("plan-file"), planFileClear: $("plan-file-clear"),
    dataset: $("dataset"), planInfo: $("plan-info"),
    dryRun: $("dry-run"), start: $("start"), pause: $("pause"), resume: $("resume"), abort: $("abort"),
    runState: $("run-state"), runId: $("run-id"), runOwner: $("run-owner"), runPlan: $("run-plan"),
    runDataset: $("run-dataset"), progress: $("progress"), progressText: $("progress-text"),
    eta: $("eta"), runMessage: $("run-message"),
    preview: $("preview"), previewCaption: $("preview-caption"),
    devices: $("devices").tBodies[0], warnings: $("warnings"), datasets: $("datasets").tBodies[0],
    updated: $("updated"),
  };

  const state = {
    token: "",
    plans: [],
    planFile: null,     // {name, text} of a plan file chosen instead of a named plan
    rig: null,          // last GET /rig
    run: null,          // last RunStatus of the current run
    runId: null,
    events: null,       // EventSource of runId
    eventsRunId: null,
    previewSeq: null,   // seq of the image on screen
    previewUrl: null,   // its blob URL
    previewBusy: false,
    previewWanted: false,
    warnings: [],       // newest first: {text, at}
    warningSeen: new Set(),
    abortArmed: null,   // timer while the abort button waits for its confirmation click
    inFlight: 0,        // button actions in progress
    tick: 0,
  };

  // ---- API ---------------------------------------------------------------------------

  class ApiError extends Error {
    constructor(status, title, detail) {
      super(detail ? `${title}: ${detail}` : title);
      this.status = status;
      this.title = title;
      this.detail = detail;
    }
  }

  function headers(extra) {
    const h = Object.assign({ Accept: "application/json" }, extra || {});
    if (state.token) h.Authorization = `Bearer ${state.token}`;
    return h;
  }

  // A problem+json body (RFC 9457) becomes an ApiError with its title and detail.
  async function problem(resp) {
    let title = `${resp.status} ${resp.statusText || "error"}`;
    let detail = "";
    try {
      const text = await resp.text();
      try {
        const p = JSON.parse(text);
        if (p && typeof p === "object") {
          if (p.title) title = String(p.title);
          if (p.detail) detail = String(p.detail);
        }
      } catch (_) {
        detail = text.slice(0, 300);
      }
    } catch (_) { /* body unreadable: keep the status line */ }
    if (resp.status === 401) setConnection("denied", "token missing or rejected");
    return new ApiError(resp.status, title, detail);
  }

  async function api(method, path, body) {
    const init = { method, headers: headers(body === undefined ? {} : { "Content-Type": "application/json" }) };
    if (body !== undefined) init.body = JSON.stringify(body);
    let resp;
    try {
      resp = await fetch(API + path, init);
    } catch (e) {
      setConnection("offline", "daemon unreachable");
      throw new ApiError(0, "The daemon cannot be reached", String(e.message || e));
    }
    if (!resp.ok) throw await problem(resp);
    setConnection("ok", "connected");
    ui.updated.textContent = new Date().toLocaleTimeString();
    const type = resp.headers.get("Content-Type") || "";
    return type.includes("json") ? resp.json() : resp.text();
  }

  // ---- small helpers -----------------------------------------------------------------

  function setConnection(kind, text) {
    ui.connection.dataset.state = kind;
    ui.connection.textContent = text;
  }

  function showError(err) {
    const msg = err instanceof Error ? err.message : String(err);
    ui.errorText.textContent = msg;
    ui.error.hidden = false;
  }

  function clearError() {
    ui.error.hidden = true;
    ui.errorText.textContent = "";
  }

  function el(tag, text, cls) {
    const e = document.createElement(tag);
    if (text !== undefined && text !== null) e.textContent = String(text);
    if (cls) e.className = cls;
    return e;
  }

  function fmtDuration(s) {
    if (s === null || s === undefined || !isFinite(s)) return "–";
    s = Math.max(0, Math.round(s));
    if (s < 60) return `${s} s`;
    const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), r = s % 60;
    return h > 0 ? `${h} h ${String(m).padStart(2, "0")} min` : `${m} min ${String(r).padStart(2, "0")} s`;
  }

  function fmtClock(secondsFromNow) {
    const t = new Date(Date.now() + secondsFromNow * 1000);
    return t.toLocaleTimeString([], { hour: "2-digit", minute: "2-digit" });
  }

  const isActive = (run) => !!run && !TERMINAL.has(run.state);

  // The simulated rig runs in virtual time: its ETA is rig time, not a time of day.
  const simulated = () => !!state.rig && Array.isArray(state.rig.devices) &&
    state.rig.devices.some((d) => /\bsim/i.test(String(d.kind)));

  // ---- rig and devices -----------------------------------------------------------------

  function renderRig(r) {
    state.rig = r;
    ui.rigName.textContent = (r.rig && r.rig.name) || "";
    ui.rigKind.textContent = (r.rig && r.rig.kind) || "";
    const body = ui.devices;
    body.replaceChildren();
    const devices = Array.isArray(r.devices) ? r.devices : [];
    if (devices.length === 0) {
      const tr = el("tr");
      const td = el("td", "no devices reported", "muted");
      td.colSpan = 4;
      tr.append(td);
      body.append(tr);
    }
    for (const d of devices) {
      const tr = el("tr");
      tr.dataset.device = d.name;
      const st = el("span", d.state, "state");
      st.dataset.state = String(d.state || "").toLowerCase();
      const tdState = el("td");
      tdState.append(st);
      tr.append(el("td", d.name), el("td", d.kind), tdState, el("td", d.detail));
      body.append(tr);
    }
    // Somebody (maybe another operator) holds the rig: follow that run.
    if (r.busy && r.busy.run_id && r.busy.run_id !== state.runId) {
      follow(r.busy.run_id);
    }
    updateButtons();
  }

  async function refreshRig() {
    try {
      renderRig(await api("GET", "/rig"));
    } catch (e) {
      if (e.status !== 0) showError(e);
    }
  }

  // ---- plans -----------------------------------------------------------------------------

  async function loadPlans() {
    let r;
    try {
      r = await api("GET", "/plans");
    } catch (e) {
      showError(e);
      return;
    }
    state.plans = Array.isArray(r.plans) ? r.plans : [];
    const keep = ui.plan.value;
    ui.plan.replaceChildren();
    if (state.plans.length === 0) ui.plan.append(new Option("(no plans)", ""));
    for (const p of state.plans) ui.plan.append(new Option(`${p.name} (${p.captures} captures)`, p.name));
    if (keep && state.plans.some((p) => p.name === keep)) ui.plan.value = keep;
    showPlanInfo();
    updateButtons();
  }

  function showPlanInfo() {
    if (state.planFile) {
      ui.planInfo.textContent = `plan file ${state.planFile.name} (${state.planFile.text.length} bytes): Dry run checks it`;
      return;
    }
    const p = state.plans.find((x) => x.name === ui.plan.value);
    ui.planInfo.textContent = p ? `${p.description || ""}` : "";
  }

  // What to run: the chosen file's text, else the selected named plan.
  function planBody() {
    if (state.planFile) return { plan_text: state.planFile.text };
    return ui.plan.value ? { plan: ui.plan.value } : null;
  }

  async function choosePlanFile() {
    const f = ui.planFile.files && ui.planFile.files[0];
    if (!f) return clearPlanFile();
    if (f.size > 1024 * 1024) {
      showError(new Error(`${f.name} is ${f.size} bytes; a plan file is a small TOML file`));
      return clearPlanFile();
    }
    state.planFile = { name: f.name, text: await f.text() };
    ui.plan.disabled = true;
    ui.planFileClear.hidden = false;
    showPlanInfo();
    updateButtons();
  }

  function clearPlanFile() {
    state.planFile = null;
    ui.planFile.value = "";
    ui.plan.disabled = false;
    ui.planFileClear.hidden = true;
    showPlanInfo();
    updateButtons();
  }

  async function dryRun() {
    const body = planBody();
    if (!body) return;
    clearError();
    ui.planInfo.textContent = "checking…";
    try {
      const r = await api("POST", "/plans/dry-run", body);
      if (r.valid) {
        const est = r.estimate_s === null || r.estimate_s === undefined ? "no estimate" : `about ${fmtDuration(r.estimate_s)}`;
        ui.planInfo.textContent = `valid: ${r.captures} captures, ${est}`;
      } else {
        ui.planInfo.textContent = `invalid: ${(r.errors || []).join("; ")}`;
      }
    } catch (e) {
      ui.planInfo.textContent = "";
      showError(e);
    }
  }

  // ---- the current run -------------------------------------------------------------------

  function renderRun(run) {
    if (!run || (state.runId && run.id !== state.runId)) return;
    const prev = state.run;
    state.run = run;
    ui.runState.textContent = run.state;
    ui.runState.dataset.state = run.state;
    ui.runId.textContent = run.id;
    ui.runOwner.textContent = run.owner || "–";
    ui.runPlan.textContent = run.plan || "–";
    ui.runDataset.textContent = run.dataset || "–";
    const total = Number(run.total) || 0;
    const done = Number(run.done) || 0;
    ui.progress.max = total > 0 ? total : 1;
    ui.progress.value = total > 0 ? Math.min(done, total) : 0;
    const pct = isFinite(run.fraction) ? (100 * run.fraction).toFixed(1) : total > 0 ? (100 * done / total).toFixed(1) : "0.0";
    ui.progress.textContent = `${pct}%`;
    // A dome run counts steps (a pattern at a rotation) and commits textures per view group.
    const unit = run.unit ? ` ${run.unit}` : "";
    const textures = typeof run.textures === "number" ? `, ${run.textures} / ${run.textures_total} textures` : "";
    ui.progressText.textContent = total > 0 ? `${done} / ${total}${unit} (${pct}%)${textures}` : "–";
    if (run.state === "finished") ui.eta.textContent = "done";
    else if (TERMINAL.has(run.state)) ui.eta.textContent = "–";
    else if (run.eta_s === null || run.eta_s === undefined) ui.eta.textContent = "estimating…";
    else if (simulated()) ui.eta.textContent = `${fmtDuration(run.eta_s)} of rig time (simulated rig)`;
    else ui.eta.textContent = `${fmtDuration(run.eta_s)} (about ${fmtClock(run.eta_s)})`;
    ui.runMessage.textContent = run.message || "–";
    for (const w of run.warnings || []) addWarning(w);
    if (typeof run.preview_seq === "number" && run.preview_seq > 0 && run.preview_seq !== state.previewSeq) {
      loadPreview();
    }
    if (!prev || prev.state !== run.state) refreshDatasets();
    if (TERMINAL.has(run.state)) {
      closeEvents();
    } else {
      openEvents();
    }
    updateButtons();
  }

  // Make `id` the run the page shows.
  async function follow(id) {
    if (state.runId === id) return;
    state.runId = id;
    state.run = null;
    closeEvents();
    try {
      renderRun(await api("GET", `/runs/${encodeURIComponent(id)}`));
    } catch (e) {
      if (e.status !== 0) showError(e);
    }
  }

  async function refreshRun() {
    if (!state.runId) return;
    try {
      renderRun(await api("GET", `/runs/${encodeURIComponent(state.runId)}`));
    } catch (e) {
      if (e.status !== 0) showError(e);
    }
  }

  // With no run holding the rig, show the latest run (an active one first).
  async function pickRun() {
    try {
      const r = await api("GET", "/runs");
      const runs = Array.isArray(r.runs) ? r.runs.slice() : [];
      if (runs.length === 0 || state.runId) return;
      // Latest last: by start time where the daemon gives one, else in the list's order.
      runs.sort((a, b) => (Number(a.started_unix_s) || 0) - (Number(b.started_unix_s) || 0));
      const active = runs.filter(isActive);
      const run = active.length ? active[active.length - 1] : runs[runs.length - 1];
      state.runId = run.id;
      renderRun(run);
    } catch (e) {
      if (e.status !== 0) showError(e);
    }
  }

  function openEvents() {
    if (!state.runId || typeof EventSource === "undefined") return;
    if (state.events && state.eventsRunId === state.runId) return;
    closeEvents();
    const q = state.token ? `?access_token=${encodeURIComponent(state.token)}` : "";
    const es = new EventSource(`${API}/runs/${encodeURIComponent(state.runId)}/events${q}`);
    const id = state.runId;
    const parse = (ev) => {
      try { return JSON.parse(ev.data); } catch (_) { return null; }
    };
    es.addEventListener("status", (ev) => { if (id === state.runId) renderRun(parse(ev)); });
    es.addEventListener("warning", (ev) => {
      const w = parse(ev);
      if (w && w.message) addWarning(w.message);
    });
    es.addEventListener("end", (ev) => {
      if (id === state.runId) renderRun(parse(ev));
      closeEvents();
    });
    es.onerror = () => {
      // The browser retries by itself; a closed stream falls back to polling.
      if (es.readyState === EventSource.CLOSED && state.events === es) {
        state.events = null;
        state.eventsRunId = null;
      }
    };
    state.events = es;
    state.eventsRunId = id;
  }

  function closeEvents() {
    if (state.events) state.events.close();
    state.events = null;
    state.eventsRunId = null;
  }

  function eventsLive() {
    return !!state.events && state.events.readyState === EventSource.OPEN;
  }

  // ---- preview ---------------------------------------------------------------------------

  async function loadPreview() {
    if (state.previewBusy) {
      state.previewWanted = true;
      return;
    }
    state.previewBusy = true;
    try {
      const resp = await fetch(`${API}/preview`, { headers: headers({ Accept: "image/png" }) });
      if (resp.status === 404) return; // nothing captured yet
      if (!resp.ok) throw await problem(resp);
      const seq = Number(resp.headers.get("X-Preview-Seq"));
      const blob = await resp.blob();
      const url = URL.createObjectURL(blob);
      const old = state.previewUrl;
      state.previewUrl = url;
      state.previewSeq = isFinite(seq) ? seq : state.run ? state.run.preview_seq : null;
      ui.preview.src = url;
      ui.preview.dataset.seq = String(state.previewSeq);
      ui.previewCaption.textContent = `preview #${state.previewSeq}, ${new Date().toLocaleTimeString()}`;
      if (old) setTimeout(() => URL.revokeObjectURL(old), 2000);
    } catch (e) {
      if (e.status !== 0) showError(e);
    } finally {
      state.previewBusy = false;
      if (state.previewWanted) {
        state.previewWanted = false;
        if (state.run && state.run.preview_seq !== state.previewSeq) loadPreview();
      }
    }
  }

  // ---- warnings --------------------------------------------------------------------------

  function addWarning(text) {
    text = String(text);
    const run = state.runId || "";
    const key = `${run}\u0000${text}`;
    if (state.warningSeen.has(key)) return;
    state.warningSeen.add(key);
    state.warnings.unshift({ text, run, at: new Date() });
    state.warnings.length = Math.min(state.warnings.length, MAX_WARNINGS);
    ui.warnings.replaceChildren();
    for (const w of state.warnings) {
      const li = el("li");
      li.append(el("time", w.at.toLocaleTimeString(), "muted"), " ");
      if (w.run) li.append(el("span", w.run, "run"), " ");
      li.append(w.text);
      ui.warnings.append(li);
    }
  }

  // ---- datasets --------------------------------------------------------------------------

  async function refreshDatasets() {
    let r;
    try {
      r = await api("GET", "/datasets");
    } catch (e) {
      if (e.status !== 0) showError(e);
      return;
    }
    const body = ui.datasets;
    body.replaceChildren();
    const list = Array.isArray(r.datasets) ? r.datasets : [];
    if (list.length === 0) {
      const tr = el("tr");
      const td = el("td", "no datasets yet", "muted");
      td.colSpan = 4;
      tr.append(td);
      body.append(tr);
    }
    for (const d of list) {
      const tr = el("tr");
      tr.dataset.dataset = d.name;
      const btn = el("button", "manifest");
      btn.type = "button";
      btn.addEventListener("click", () => showManifest(d.name, tr));
      const td = el("td");
      td.append(btn);
      tr.append(el("td", d.name), el("td", d.state), el("td", d.captures), td);
      body.append(tr);
    }
  }

  async function showManifest(name, row) {
    clearError();
    const next = row.nextElementSibling;
    if (next && next.classList.contains("manifest")) {
      next.remove();
      return;
    }
    try {
      const m = await api("GET", `/datasets/${encodeURIComponent(name)}`);
      const tr = el("tr", null, "manifest");
      const td = el("td");
      td.colSpan = 4;
      td.append(el("pre", typeof m === "string" ? m : JSON.stringify(m, null, 2)));
      tr.append(td);
      row.after(tr);
    } catch (e) {
      showError(e);
    }
  }

  // ---- buttons ---------------------------------------------------------------------------

  function updateButtons() {
    const run = state.run;
    const busy = !!(state.rig && state.rig.busy) || isActive(run);
    const s = run ? run.state : null;
    const working = state.inFlight > 0;
    const plan = !!(state.planFile || ui.plan.value);
    ui.start.disabled = working || busy || !plan;
    ui.dryRun.disabled = working || !plan;
    ui.pause.disabled = working || !(s === "running" || s === "starting");
    ui.resume.disabled = working || s !== "paused";
    ui.abort.disabled = working || !(s === "running" || s === "starting" || s === "paused");
    if (ui.abort.disabled) disarmAbort();
  }

  async function action(fn) {
    clearError();
    state.inFlight++;
    updateButtons();
    try {
      await fn();
    } catch (e) {
      showError(e);
    } finally {
      state.inFlight--;
      updateButtons();
    }
  }

  async function start() {
    const body = planBody();
    if (!body) return;
    const ds = ui.dataset.value.trim();
    if (ds) body.dataset = ds;
    const run = await api("POST", "/runs", body);
    state.runId = run.id;
    state.run = null;
    closeEvents();
    renderRun(run);
    refreshRig();
    refreshDatasets();
  }

  async function control(verb) {
    if (!state.runId) return;
    renderRun(await api("POST", `/runs/${encodeURIComponent(state.runId)}/${verb}`));
  }

  // Abort ends a run for good: the first click asks, a second within 5 s aborts.
  function disarmAbort() {
    if (state.abortArmed) clearTimeout(state.abortArmed);
    state.abortArmed = null;
    ui.abort.textContent = "Abort";
    ui.abort.dataset.armed = "false";
  }

  function abortClicked() {
    if (!state.abortArmed) {
      ui.abort.textContent = "Confirm abort";
      ui.abort.dataset.armed = "true";
      state.abortArmed = setTimeout(disarmAbort, 5000);
      return;
    }
    disarmAbort();
    action(() => control("abort"));
  }

  // ---- token -----------------------------------------------------------------------------

  function readToken() {
    const m = /(?:^#|&)token=([^&]*)/.exec(location.hash);
    if (m) {
      state.token = decodeURIComponent(m[1]);
      sessionStorage.setItem(TOKEN_KEY, state.token);
      // Keep the secret out of the address bar and the history.
      history.replaceState(null, "", location.pathname + location.search);
    } else {
      state.token = sessionStorage.getItem(TOKEN_KEY) || "";
    }
    ui.token.value = state.token;
  }

  function useToken(ev) {
    ev.preventDefault();
    state.token = ui.token.value.trim();
    if (state.token) sessionStorage.setItem(TOKEN_KEY, state.token);
    else sessionStorage.removeItem(TOKEN_KEY);
    clearError();
    closeEvents();
    reloadAll();
  }

  // ---- main loop -------------------------------------------------------------------------

  async function reloadAll() {
    await Promise.all([refreshRig(), loadPlans(), refreshDatasets()]);
    if (!state.runId) await pickRun();
    if (state.previewSeq === null) loadPreview();
  }

  // One tick a second: the run (unless its event stream is live), the rig every 2 s,
  // datasets every 15 s; a hidden tab ticks every 5 s.
  function loop() {
    state.tick++;
    const hidden = document.visibilityState === "hidden";
    if (state.token || state.tick % 5 === 0) {
      if (isActive(state.run) && !eventsLive()) refreshRun();
      if (state.tick % 2 === 0) refreshRig();
      if (state.tick % 15 === 0) refreshDatasets();
    }
    setTimeout(loop, hidden ? 5000 : 1000);
  }

  ui.tokenForm.addEventListener("submit", useToken);
  ui.errorClose.addEventListener("click", clearError);
  ui.plan.addEventListener("change", () => { showPlanInfo(); updateButtons(); });
  ui.planFile.addEventListener("change", () => { choosePlanFile().catch(showError); });
  ui.planFileClear.addEventListener("click", clearPlanFile);
  ui.dryRun.addEventListener("click", () => action(dryRun));
  ui.start.addEventListener("click", () => action(start));
  ui.pause.addEventListener("click", () => action(() => control("pause")));
  ui.resume.addEventListener("click", () => action(() => control("resume")));
  ui.abort.addEventListener("click", abortClicked);
  window.addEventListener("hashchange", () => { readToken(); reloadAll(); });

  readToken();
  updateButtons();
  reloadAll().finally(() => setTimeout(loop, 1000));
})();
