// A stand-in for `btfrig serve`, for working on the operator page without building the
// daemon: serves crates/daemon/ui and a simulated run behind the same public API contract
// (tokens from tests/api/auth.toml, problem+json errors, SSE events, PNG preview).
// Not used by the tests: they run against the real daemon. Run with
//   BTFRIG_WEB_FAKE=1 tests/web/run.sh      (the browser test against this server), or
//   node tests/web/fake-server.mjs [PORT]   (then open http://127.0.0.1:PORT/#token=operator-token)
import http from "node:http";
import fs from "node:fs";
import path from "node:path";
import zlib from "node:zlib";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const uiDir = path.join(here, "..", "..", "crates", "daemon", "ui");
const TOKENS = {
  "viewer-token": { name: "viewer", role: "viewer" },
  "operator-token": { name: "ada", role: "operator" },
  "admin-token": { name: "root", role: "admin" },
};
const RANK = { viewer: 0, operator: 1, admin: 2 };
const PLANS = [
  { name: "demo", captures: 60, description: "quick subset of the Bonn sampling, 60 captures, 64 texels" },
  { name: "grazing", captures: 40, description: "grazing angles" },
];

// ---- a tiny PNG encoder (RGB, 8 bit) ----
const crcTable = Array.from({ length: 256 }, (_, n) => {
  let c = n;
  for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
  return c >>> 0;
});
function crc32(buf) {
  let c = 0xffffffff;
  for (const b of buf) c = crcTable[(c ^ b) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
}
function chunk(type, data) {
  const len = Buffer.alloc(4);
  len.writeUInt32BE(data.length);
  const td = Buffer.concat([Buffer.from(type), data]);
  const crc = Buffer.alloc(4);
  crc.writeUInt32BE(crc32(td));
  return Buffer.concat([len, td, crc]);
}
function png(w, h, pixel) {
  const raw = Buffer.alloc((w * 3 + 1) * h);
  for (let y = 0; y < h; y++) {
    raw[y * (w * 3 + 1)] = 0;
    for (let x = 0; x < w; x++) {
      const [r, g, b] = pixel(x, y);
      const o = y * (w * 3 + 1) + 1 + x * 3;
      raw[o] = r; raw[o + 1] = g; raw[o + 2] = b;
    }
  }
  const ihdr = Buffer.alloc(13);
  ihdr.writeUInt32BE(w, 0); ihdr.writeUInt32BE(h, 4);
  ihdr[8] = 8; ihdr[9] = 2; ihdr[10] = 0; ihdr[11] = 0; ihdr[12] = 0;
  return Buffer.concat([Buffer.from([137, 80, 78, 71, 13, 10, 26, 10]), chunk("IHDR", ihdr),
    chunk("IDAT", zlib.deflateSync(raw)), chunk("IEND", Buffer.alloc(0))]);
}

// ---- the simulated rig ----
let runs = [];
let current = null; // the run holding the rig
let preview = null; // {seq, png}
let previewSeq = 0;
const subscribers = new Set(); // {run, res}
const datasets = [];

function status(r) {
  const fraction = r.total ? r.done / r.total : 0;
  const eta = r.state === "running" && r.done > 0 ? (r.total - r.done) * 0.4 : null;
  return { id: r.id, state: r.state, owner: r.owner, plan: r.plan, dataset: r.dataset, done: r.done,
    total: r.total, fraction, eta_s: eta, warnings: r.warnings.slice(-10), message: r.message, preview_seq: r.preview_seq };
}
function emit(r, event, data) {
  for (const s of subscribers) if (s.run === r) s.res.write(`event: ${event}\ndata: ${JSON.stringify(data)}\n\n`);
  if (event === "end") for (const s of subscribers) if (s.run === r) { s.res.end(); subscribers.delete(s); }
}
function changed(r) {
  emit(r, "status", status(r));
  if (["finished", "aborted", "failed"].includes(r.state)) {
    emit(r, "end", status(r));
    if (current === r) current = null;
    const d = datasets.find((x) => x.name === r.dataset);
    if (d) d.state = r.state === "finished" ? "complete" : "incomplete";
  }
}
setInterval(() => {
  const r = current;
  if (!r) return;
  if (r.state === "starting") { r.state = "running"; changed(r); return; }
  if (r.state === "running") {
    r.done++;
    const seq = ++previewSeq;
    const hue = (seq * 37) % 255;
    preview = { seq, png: png(64, 64, (x, y) => [(x * 4 + hue) % 256, (y * 4) % 256, (hue * 3) % 256]) };
    r.preview_seq = seq;
    const d = datasets.find((x) => x.name === r.dataset);
    if (d) d.captures = r.done;
    if (r.done % 7 === 0) {
      const msg = `capture ${r.done}: exposure clipped, retried`;
      r.warnings.push(msg);
      emit(r, "warning", { message: msg });
    }
    if (r.done >= r.total) { r.state = "finished"; r.message = "all captures done"; }
    changed(r);
  }
}, 400);

// ---- HTTP ----
function send(res, code, body, type = "application/json") {
  const data = typeof body === "string" || Buffer.isBuffer(body) ? body : JSON.stringify(body);
  res.writeHead(code, { "Content-Type": type, "Cache-Control": "no-store" });
  res.end(data);
}
function problem(res, status, title, detail) {
  send(res, status, { type: "about:blank", title, status, detail }, "application/problem+json");
}
async function body(req) {
  let s = "";
  for await (const c of req) s += c;
  try { return JSON.parse(s || "{}"); } catch { return null; }
}

const server = http.createServer(async (req, res) => {
  const url = new URL(req.url, "http://x");
  const p = url.pathname;
  if (req.method === "GET" && (p === "/" || p.startsWith("/ui/"))) {
    const file = p === "/" ? "index.html" : p.slice(4);
    if (!/^[a-z.]+$/.test(file)) return problem(res, 404, "Not found", p);
    const types = { html: "text/html; charset=utf-8", js: "text/javascript", css: "text/css" };
    try { return send(res, 200, fs.readFileSync(path.join(uiDir, file)), types[file.split(".").pop()]); }
    catch { return problem(res, 404, "Not found", p); }
  }
  if (p === "/healthz") return send(res, 200, { ok: true });
  if (!p.startsWith("/api/v1/")) return problem(res, 404, "Not found", p);
  const auth = req.headers.authorization || "";
  let tok = auth.startsWith("Bearer ") ? auth.slice(7) : null;
  if (!tok && req.method === "GET") tok = url.searchParams.get("access_token");
  const who = TOKENS[tok];
  if (!who) return problem(res, 401, "Not authenticated", "send Authorization: Bearer <token>");
  const need = (role) => {
    if (RANK[who.role] < RANK[role]) { problem(res, 403, "Forbidden", `${who.name} is a ${who.role}; this needs ${role}`); return false; }
    return true;
  };
  const route = p.slice("/api/v1".length);
  let m;
  if (req.method === "GET" && route === "/rig") {
    return send(res, 200, {
      rig: { name: "bonn-gonio-sim", kind: "gonioreflectometer (simulated)" },
      devices: [
        { name: "camera", kind: "camera", state: current && current.state === "running" ? "busy" : "idle", detail: "simulated 2 MP Bayer" },
        { name: "robot", kind: "positioner", state: "idle", detail: "theta 0, phi 0" },
        { name: "lamp", kind: "light", state: "on", detail: "temperature 41 C" },
      ],
      busy: current ? { run_id: current.id, owner: current.owner } : null,
    });
  }
  if (req.method === "GET" && route === "/plans") return send(res, 200, { plans: PLANS });
  if (req.method === "POST" && (route === "/plans/validate" || route === "/plans/dry-run")) {
    const b = await body(req);
    const plan = b && (b.plan_text ? { captures: 60 } : PLANS.find((x) => x.name === b.plan));
    if (!plan) return send(res, 200, { valid: false, captures: 0, estimate_s: null, errors: ["no such plan"] });
    return send(res, 200, { valid: true, captures: plan.captures, estimate_s: plan.captures * 0.4, errors: [] });
  }
  if (req.method === "GET" && route === "/runs") return send(res, 200, { runs: runs.map(status) });
  if (req.method === "POST" && route === "/runs") {
    if (!need("operator")) return;
    const b = await body(req);
    const plan = b && (b.plan_text ? { name: (/^name = "(.*)"/m.exec(b.plan_text) || [])[1] || "file", captures: 60 }
      : PLANS.find((x) => x.name === b.plan));
    if (!plan) return problem(res, 422, "Unknown plan", `there is no plan named ${JSON.stringify(b && b.plan)}`);
    if (current) return problem(res, 409, "The rig is busy", `run ${current.id} of ${current.owner} holds the rig`);
    const id = `run-${runs.length + 1}`;
    const r = { id, state: "starting", owner: who.name, plan: plan.name, dataset: (b.dataset || `${plan.name}-${runs.length + 1}`),
      done: 0, total: plan.captures, warnings: [], message: null, preview_seq: previewSeq };
    runs.push(r);
    current = r;
    datasets.push({ name: r.dataset, state: "recording", captures: 0 });
    return send(res, 201, status(r));
  }
  if ((m = /^\/runs\/([^/]+)(?:\/(pause|resume|abort|events))?$/.exec(route))) {
    const r = runs.find((x) => x.id === decodeURIComponent(m[1]));
    if (!r) return problem(res, 404, "No such run", m[1]);
    const verb = m[2];
    if (!verb && req.method === "GET") return send(res, 200, status(r));
    if (verb === "events" && req.method === "GET") {
      res.writeHead(200, { "Content-Type": "text/event-stream", "Cache-Control": "no-store" });
      res.write(`event: status\ndata: ${JSON.stringify(status(r))}\n\n`);
      if (["finished", "aborted", "failed"].includes(r.state)) { res.write(`event: end\ndata: ${JSON.stringify(status(r))}\n\n`); return res.end(); }
      const s = { run: r, res };
      subscribers.add(s);
      req.on("close", () => subscribers.delete(s));
      return;
    }
    if (req.method === "POST" && verb && verb !== "events") {
      if (!need("operator")) return;
      const ok = { pause: ["starting", "running"], resume: ["paused"], abort: ["starting", "running", "paused"] }[verb];
      if (!ok.includes(r.state)) return problem(res, 409, `Cannot ${verb}`, `run ${r.id} is ${r.state}`);
      r.state = { pause: "paused", resume: "running", abort: "aborted" }[verb];
      if (verb === "abort") r.message = `aborted by ${who.name}`;
      changed(r);
      return send(res, 200, status(r));
    }
    return problem(res, 405, "Method not allowed", req.method);
  }
  if (req.method === "GET" && route === "/preview") {
    if (!preview) return problem(res, 404, "No preview yet", "nothing has been captured yet");
    res.writeHead(200, { "Content-Type": "image/png", "X-Preview-Seq": String(preview.seq), "Cache-Control": "no-store" });
    return res.end(preview.png);
  }
  if (req.method === "GET" && route === "/datasets") return send(res, 200, { datasets });
  if ((m = /^\/datasets\/([^/]+)$/.exec(route)) && req.method === "GET") {
    const d = datasets.find((x) => x.name === decodeURIComponent(m[1]));
    if (!d) return problem(res, 404, "No such dataset", m[1]);
    return send(res, 200, { name: d.name, captures: d.captures, files: [] });
  }
  return problem(res, 404, "Not found", p);
});

server.listen(Number(process.argv[2] || 0), "127.0.0.1", () => {
  console.log(`listening on http://127.0.0.1:${server.address().port}`);
});
process.on("SIGTERM", () => process.exit(0));
