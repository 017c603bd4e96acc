// btfrig viewer (/viewer): relights a dataset's compressed model in the browser with WebGL2,
// and plots the dataset's coverage and per-capture figures. Plain script, no build step; the
// daemon embeds it, uPlot is vendored (ui/vendor): nothing comes from the network.
//
// The model data (GET .../models/{model}/data, docs/http-api.md "viewer data") holds the
// samplings with their interpolation triangles, the angular factors and the texel
// coefficients. Per frame the page interpolates the angular factors at the chosen (light,
// view) pair exactly as btfrig does (Sampling::interpolate, then Model::query's f32 sums;
// ported below), uploads the few interpolated rows, and the fragment shader takes one dot
// product per texel and channel with the coefficients (a texture array), then the colour
// model's inverse, the display scale and the sRGB curve (as btfrig_imageio::linear_to_srgb8).
//
// For tests: window.btfViewer = { ready, header, setPair, pixels, benchmark }.
"use strict";

(() => {
  const API = "/api/v1";
  const TOKEN_KEY = "btfrig.token";
  const $ = (id) => document.getElementById(id);
  const RAD = Math.PI / 180;
  const f32 = Math.fround;

  // ---- token and API (as the operator page) ----
  let token = sessionStorage.getItem(TOKEN_KEY) || "";
  const m = /(?:^#|&)token=([^&]*)/.exec(location.hash);
  if (m) {
    token = decodeURIComponent(m[1]);
    sessionStorage.setItem(TOKEN_KEY, token);
    history.replaceState(null, "", location.pathname + location.search);
  }
  const auth = () => (token ? { Authorization: `Bearer ${token}` } : {});

  function showError(text) {
    $("error-text").textContent = text;
    $("error").hidden = false;
  }
  $("error-close").addEventListener("click", () => { $("error").hidden = true; });

  async function problemText(resp) {
    const t = await resp.text();
    try {
      const p = JSON.parse(t);
      return `${p.title || resp.status}: ${p.detail || ""}`;
    } catch (_) {
      return `${resp.status} ${t}`;
    }
  }

  async function getJson(path) {
    const r = await fetch(API + path, { headers: Object.assign({ Accept: "application/json" }, auth()) });
    if (!r.ok) throw new Error(await problemText(r));
    return r.json();
  }

  // ---- interpolation over a sampling: btfrig_core::sampling::Sampling::interpolate ----
  const project = (t, p) => [t * Math.cos(p), t * Math.sin(p)];
  const unit = (t, p) => [Math.sin(t) * Math.cos(p), Math.sin(t) * Math.sin(p), Math.cos(t)];

  class Interp {
    constructor(s) {
      this.dirs = s.dirs;
      this.proj = s.dirs.map(([t, p]) => project(t, p));
      this.units = s.dirs.map(([t, p]) => unit(t, p));
      this.tris = s.tris.map((v) => {
        const a = this.proj[v[0]], b = this.proj[v[1]], c = this.proj[v[2]];
        const det = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        return { v, a, inv: [(c[1] - a[1]) / det, -(c[0] - a[0]) / det, -(b[1] - a[1]) / det, (b[0] - a[0]) / det] };
      });
      // The hull: directed edges of the triangles, in order, whose reverse is no edge.
      const directed = [];
      for (const t of this.tris) for (let k = 0; k < 3; k++) directed.push([t.v[k], t.v[(k + 1) % 3]]);
      const has = new Set(directed.map((e) => `${e[0]},${e[1]}`));
      this.hull = directed.filter((e) => !has.has(`${e[1]},${e[0]}`));
      if (!this.tris.length && this.dirs.length === 2) this.hull = [[0, 1]];
    }

    // [[index, weight], ...] of direction (theta, phi) in radians.
    interpolate(theta, phi) {
      const q = project(theta, phi);
      for (const t of this.tris) {
        const dx = q[0] - t.a[0], dy = q[1] - t.a[1];
        const l1 = t.inv[0] * dx + t.inv[1] * dy;
        const l2 = t.inv[2] * dx + t.inv[3] * dy;
        const w = [1.0 - l1 - l2, l1, l2];
        if (w.every((x) => x >= -1e-12)) {
          const c = w.map((x) => Math.max(x, 0));
          const s = c[0] + c[1] + c[2];
          return [[t.v[0], c[0] / s], [t.v[1], c[1] / s], [t.v[2], c[2] / s]];
        }
      }
      let best = null;
      for (const e of this.hull) {
        const a = this.proj[e[0]], b = this.proj[e[1]];
        const ab = [b[0] - a[0], b[1] - a[1]];
        const len2 = ab[0] * ab[0] + ab[1] * ab[1];
        const t = len2 > 0 ? Math.min(1, Math.max(0, ((q[0] - a[0]) * ab[0] + (q[1] - a[1]) * ab[1]) / len2)) : 0;
        const p = [a[0] + t * ab[0], a[1] + t * ab[1]];
        const d2 = (q[0] - p[0]) ** 2 + (q[1] - p[1]) ** 2;
        if (best === null || d2 < best[0]) best = [d2, e[0], e[1], t];
      }
      if (best) return [[best[1], 1.0 - best[3]], [best[2], best[3]]];
      return [[this.nearest(theta, phi), 1.0]];
    }

    nearest(theta, phi) {
      const u = unit(theta, phi);
      let bi = 0, bd = -Infinity;
      this.units.forEach((v, i) => {
        const d = v[0] * u[0] + v[1] * u[1] + v[2] * u[2];
        if (d > bd) { bd = d; bi = i; }
      });
      return bi;
    }
  }

  // ---- the model ----
  let model = null;   // {h, angular: Float32Array, cluster, coef, light: Interp, view: Interp, partRows}
  let gl = null, prog = null, angTex = null, angData = null;
  const uni = {};
  let pair = { light: [0, 0], view: [0, 0] };   // degrees
  let exposureStops = 0;

  function parseData(buf) {
    const bytes = new Uint8Array(buf);
    const magic = new TextDecoder().decode(bytes.subarray(0, 8));
    if (magic !== "BTFVIEW1") throw new Error(`the model data starts with ${JSON.stringify(magic)}, not BTFVIEW1`);
    const hlen = new DataView(buf).getUint32(8, true);
    const h = JSON.parse(new TextDecoder().decode(bytes.subarray(12, 12 + hlen)));
    const base = 12 + hlen;
    const block = (name) => {
      const b = h.blocks.find((x) => x.name === name);
      return new Float32Array(buf, base + 4 * b.offset, b.floats);
    };
    const nl = h.light.dirs.length;
    const rowsOf = (p) => (h.part_rows === "view" ? nl : nl * h.view.dirs.length);
    // Offsets of each (channel, part) in the angular block.
    const angOff = [];
    let off = 0;
    for (let c = 0; c < 3; c++) {
      angOff.push([]);
      for (let p = 0; p < h.parts; p++) {
        angOff[c].push(off);
        off += rowsOf(p) * (1 + h.terms);
      }
    }
    return { h, angular: block("angular"), cluster: block("cluster"), coef: block("coef"),
      light: new Interp(h.light), view: new Interp(h.view), angOff, nl };
  }

  // Model::query: the interpolated mean and basis row of every (channel, part), in f32 as
  // btfrig sums them. Returns the parts with weight.
  function interpolateAngular(md, lightDeg, viewDeg) {
    const h = md.h, nl = md.nl;
    const lt = lightDeg[0] * RAD, lp = wrap(lightDeg[1] * RAD);
    const vt = viewDeg[0] * RAD, vp = wrap(viewDeg[1] * RAD);
    const combos = [];
    if (h.captures) {
      // A dome: the measured capture nearest to the pair (summed angles).
      const [cl, cv] = h.captures;
      const lu = unit(lt, lp), vu = unit(vt, vp);
      const ang = (a, b) => Math.acos(Math.max(-1, Math.min(1, a[0] * b[0] + a[1] * b[1] + a[2] * b[2])));
      let best = -1, bd = Infinity;
      for (let a = 0; a < cl.length; a++) {
        if (!h.measured[a]) continue;
        const d = ang(lu, unit(cl[a][0], cl[a][1])) + ang(vu, unit(cv[a][0], cv[a][1]));
        if (d < bd) { bd = d; best = a; }
      }
      if (best >= 0) combos.push([best, 1]);
    } else {
      const wv = md.view.interpolate(vt, vp);
      const wl = md.light.interpolate(lt, lp);
      for (const [v, a] of wv) for (const [l, b] of wl) if (a * b > 0) combos.push([v * nl + l, f32(a * b)]);
    }
    const k = h.terms, q = h.quads, stride = 4 * (1 + q);
    angData.fill(0);
    const active = [];
    for (let c = 0; c < 3; c++) {
      for (let p = 0; p < h.parts; p++) {
        const base = md.angOff[c][p];
        let mean = 0, any = false;
        const u = new Float32Array(k);
        for (const [a, w] of combos) {
          let r = a;
          if (h.part_rows === "view") {
            if (Math.floor(a / nl) !== p) continue;
            r = a % nl;
          }
          any = true;
          const row = base + r * (1 + k);
          mean = f32(mean + f32(w * md.angular[row]));
          for (let j = 0; j < k; j++) u[j] = f32(u[j] + f32(w * md.angular[row + 1 + j]));
        }
        if (!any) continue;
        if (c === 0) active.push(p);
        const o = (c * h.parts + p) * stride;
        angData[o] = mean;
        angData[o + 1] = 1;
        angData.set(u, o + 4);
      }
    }
    return active;
  }

  function wrap(a) {
    const t = 2 * Math.PI;
    const w = ((a % t) + t) % t;
    return w >= t ? 0 : w;
  }

  // ---- WebGL2 ----
  const VS = `#version 300 es
  void main() {
    vec2 p = vec2((gl_VertexID == 1) ? 3.0 : -1.0, (gl_VertexID == 2) ? 3.0 : -1.0);
    gl_Position = vec4(p, 0.0, 1.0);
  }`;
  const FS = `#version 300 es
  precision highp float; precision highp int; precision highp sampler2DArray;
  uniform sampler2DArray coef;
  uniform sampler2D ang;
  uniform sampler2D clus;
  uniform int quads, parts, pvmf, colorModel, height;
  uniform ivec3 act;
  uniform float logEps, scale;
  int rowBase = 0;
  out vec4 outColor;
  float partValue(int c, int p, int cp, ivec2 xy) {
    int row = rowBase + c * parts + p;
    vec4 m = texelFetch(ang, ivec2(0, row), 0);
    float v = m.x;
    for (int j = 0; j < quads; j++) {
      v += dot(texelFetch(ang, ivec2(1 + j, row), 0), texelFetch(coef, ivec3(xy, (cp * 3 + c) * quads + j), 0));
    }
    return v;
  }
  float srgb(float x) {
    if (isnan(x)) return 0.0;
    x = clamp(x, 0.0, 1.0);
    return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
  }
  vec4 shade(ivec2 xy) {
    vec3 d = vec3(0.0);
    for (int c = 0; c < 3; c++) {
      float s = 0.0;
      if (pvmf == 0) {
        int p = int(texelFetch(clus, xy, 0).r + 0.5);
        s = partValue(c, p, 0, xy);
      } else if (pvmf == 2) {
        // A PVMF on the cylinder: each column's own view parts, marked in its rows (y = 1).
        for (int p = 0; p < parts; p++) {
          if (texelFetch(ang, ivec2(0, rowBase + c * parts + p), 0).y > 0.5) s += partValue(c, p, p, xy);
        }
      } else {
        for (int i = 0; i < 3; i++) { int p = act[i]; if (p >= 0) s += partValue(c, p, p, xy); }
      }
      d[c] = s;
    }
    vec3 rgb = d;
    if (colorModel != 0) {
      float y = colorModel == 2 ? exp(d.x) - logEps : d.x;
      rgb = vec3(y + 1.13983 * d.z, y + (-0.114 * 2.03211 / 0.587) * d.y + (-0.299 * 1.13983 / 0.587) * d.z, y + 2.03211 * d.y);
    }
    rgb *= scale;
    return vec4(srgb(rgb.r), srgb(rgb.g), srgb(rgb.b), 1.0);
  }
  vec4 shadeAt(ivec2 xy, int base) { rowBase = base; return shade(xy); }
  #ifdef CYLINDER
  // The sample wrapped round a cylinder (vertical axis, radius 1, seen from the front,
  // orthographic): per column its own (light, view) pair in the surface's frame, whose
  // interpolated rows start at rowBase = column * 3 * parts; one texture tile per unit of
  // arc length and of height.
  uniform int cols, size;
  void main() {
    int px = int(gl_FragCoord.x), py = size - 1 - int(gl_FragCoord.y);
    float x = (float(px) + 0.5) / float(size) * 2.0 - 1.0;
    int col = clamp(int((x + 1.0) * 0.5 * float(cols)), 0, cols - 1);
    int base = col * 3 * parts;
    if (texelFetch(ang, ivec2(0, base), 0).z < 0.5) { outColor = vec4(0.0, 0.0, 0.0, 1.0); return; }
    ivec2 dims = textureSize(clus, 0);
    float arc = asin(clamp(x, -1.0, 1.0)) + 1.5707963;
    int tu = int(floor(arc * float(dims.x))) % dims.x;
    int tv = int(floor((float(py) + 0.5) / float(size) * 2.0 * float(dims.y))) % dims.y;
    outColor = shadeAt(ivec2(tu, tv), base);
  }
  #else
  void main() {
    outColor = shadeAt(ivec2(int(gl_FragCoord.x), height - 1 - int(gl_FragCoord.y)), 0);
  }
  #endif`;

  // The flat texture's program, or the cylinder's (the same shading, another mapping).
  const withDefine = (src, define) => src.replace("#version 300 es", `#version 300 es\n#define ${define}`);

  function compile(type, src) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(s)}`);
    return s;
  }

  function floatTexture(unitIndex, target) {
    const t = gl.createTexture();
    gl.activeTexture(gl.TEXTURE0 + unitIndex);
    gl.bindTexture(target, t);
    gl.texParameteri(target, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(target, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texParameteri(target, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(target, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    return t;
  }

  function setupGl(md) {
    const canvas = $("btf");
    const h = md.h;
    canvas.width = h.width;
    canvas.height = h.height;
    if (!gl) {
      gl = canvas.getContext("webgl2", { preserveDrawingBuffer: true, antialias: false });
      if (!gl) throw new Error("this browser gives no WebGL2 context: the viewer needs WebGL2");
      prog = gl.createProgram();
      gl.attachShader(prog, compile(gl.VERTEX_SHADER, VS));
      gl.attachShader(prog, compile(gl.FRAGMENT_SHADER, FS));
      gl.linkProgram(prog);
      if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(prog)}`);
      for (const n of ["coef", "ang", "clus", "quads", "parts", "pvmf", "colorModel", "height", "act", "logEps", "scale"]) {
        uni[n] = gl.getUniformLocation(prog, n);
      }
      cyl.prog = gl.createProgram();
      gl.attachShader(cyl.prog, compile(gl.VERTEX_SHADER, VS));
      gl.attachShader(cyl.prog, compile(gl.FRAGMENT_SHADER, withDefine(FS, "CYLINDER")));
      gl.linkProgram(cyl.prog);
      if (!gl.getProgramParameter(cyl.prog, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(cyl.prog)}`);
      for (const n of ["coef", "ang", "clus", "quads", "parts", "pvmf", "colorModel", "act", "logEps", "scale", "cols", "size"]) {
        cyl.uni[n] = gl.getUniformLocation(cyl.prog, n);
      }
      cyl.target = gl.createTexture();
      gl.activeTexture(gl.TEXTURE4);
      gl.bindTexture(gl.TEXTURE_2D, cyl.target);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, CYL_SIZE, CYL_SIZE, 0, gl.RGBA, gl.UNSIGNED_BYTE, null);
      cyl.fbo = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, cyl.fbo);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, cyl.target, 0);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    }
    const layers = h.coef_parts * 3 * h.quads;
    const maxLayers = gl.getParameter(gl.MAX_ARRAY_TEXTURE_LAYERS);
    if (layers > maxLayers) {
      throw new Error(`the model needs ${layers} texture layers; this browser allows ${maxLayers} (a PVMF of fewer views or terms fits)`);
    }
    gl.viewport(0, 0, h.width, h.height);
    gl.useProgram(prog);
    floatTexture(0, gl.TEXTURE_2D_ARRAY);
    gl.texImage3D(gl.TEXTURE_2D_ARRAY, 0, gl.RGBA32F, h.width, h.height, layers, 0, gl.RGBA, gl.FLOAT, md.coef);
    angTex = floatTexture(1, gl.TEXTURE_2D);
    angData = new Float32Array(3 * h.parts * 4 * (1 + h.quads));
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, 1 + h.quads, 3 * h.parts, 0, gl.RGBA, gl.FLOAT, angData);
    floatTexture(2, gl.TEXTURE_2D);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.R32F, h.width, h.height, 0, gl.RED, gl.FLOAT, md.cluster);
    gl.uniform1i(uni.coef, 0);
    gl.uniform1i(uni.ang, 1);
    gl.uniform1i(uni.clus, 2);
    gl.uniform1i(uni.quads, h.quads);
    gl.uniform1i(uni.parts, h.parts);
    gl.uniform1i(uni.pvmf, h.part_rows === "view" ? 1 : 0);
    gl.uniform1i(uni.colorModel, { rgb: 0, yuv: 1, "ylog-uv": 2 }[h.color]);
    gl.uniform1i(uni.height, h.height);
    gl.uniform1f(uni.logEps, h.log_eps);
    // The cylinder: one interpolated block of rows per column, as many columns as fit.
    cyl.cols = Math.max(1, Math.min(CYL_SIZE / 2, Math.floor(gl.getParameter(gl.MAX_TEXTURE_SIZE) / (3 * h.parts))));
    cyl.data = new Float32Array(cyl.cols * 3 * h.parts * 4 * (1 + h.quads));
    cyl.ang = floatTexture(3, gl.TEXTURE_2D);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, 1 + h.quads, cyl.cols * 3 * h.parts, 0, gl.RGBA, gl.FLOAT, cyl.data);
    gl.useProgram(cyl.prog);
    gl.uniform1i(cyl.uni.coef, 0);
    gl.uniform1i(cyl.uni.ang, 3);
    gl.uniform1i(cyl.uni.clus, 2);
    gl.uniform1i(cyl.uni.quads, h.quads);
    gl.uniform1i(cyl.uni.parts, h.parts);
    gl.uniform1i(cyl.uni.pvmf, h.part_rows === "view" ? 2 : 0);
    gl.uniform1i(cyl.uni.colorModel, { rgb: 0, yuv: 1, "ylog-uv": 2 }[h.color]);
    gl.uniform1f(cyl.uni.logEps, h.log_eps);
    gl.uniform1i(cyl.uni.cols, cyl.cols);
    gl.uniform1i(cyl.uni.size, CYL_SIZE);
    gl.useProgram(prog);
  }

  // ---- the sample on a cylinder ----
  const CYL_SIZE = 256;
  const cyl = { uni: {} };
  const vec = ([t, p]) => unit(t * RAD, p * RAD);
  const dot3 = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  // Direction `w` (world: x right, y up, z towards the viewer) in the frame of the surface
  // whose normal is `n` (x along the circumference, y along the axis), degrees.
  function local(w, n) {
    const ex = [n[2], 0, -n[0]], ey = [0, 1, 0];
    const v = [dot3(w, ex), dot3(w, ey), dot3(w, n)];
    const t = Math.acos(Math.max(-1, Math.min(1, v[2]))) / RAD;
    let p = Math.atan2(v[1], v[0]) / RAD;
    if (p < 0) p += 360;
    return [t, t < 1e-9 ? 0 : p];
  }

  function drawCylinder() {
    const h = model.h;
    const note = $("cyl-text");
    const L = vec(pair.light), V = vec(pair.view);
    const stride = 4 * (1 + h.quads), block = 3 * h.parts * stride;
    cyl.data.fill(0);
    for (let c = 0; c < cyl.cols; c++) {
      const x = ((c + 0.5) / cyl.cols) * 2 - 1;
      const n = [x, 0, Math.sqrt(Math.max(0, 1 - x * x))];
      const l = local(L, n), v = local(V, n);
      if (l[0] >= 90 || v[0] >= 90) continue;
      interpolateAngular(model, l, v);
      cyl.data.set(angData, c * block);
      cyl.data[c * block + 2] = 1;
    }
    gl.useProgram(cyl.prog);
    gl.activeTexture(gl.TEXTURE3);
    gl.bindTexture(gl.TEXTURE_2D, cyl.ang);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 1 + h.quads, cyl.cols * 3 * h.parts, gl.RGBA, gl.FLOAT, cyl.data);
    gl.uniform1f(cyl.uni.scale, scale());
    gl.bindFramebuffer(gl.FRAMEBUFFER, cyl.fbo);
    gl.viewport(0, 0, CYL_SIZE, CYL_SIZE);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    const px = new Uint8ClampedArray(CYL_SIZE * CYL_SIZE * 4);
    gl.readPixels(0, 0, CYL_SIZE, CYL_SIZE, gl.RGBA, gl.UNSIGNED_BYTE, px);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, h.width, h.height);
    gl.useProgram(prog);
    // readPixels is bottom-up.
    const img = new ImageData(CYL_SIZE, CYL_SIZE);
    const row = CYL_SIZE * 4;
    for (let y = 0; y < CYL_SIZE; y++) img.data.set(px.subarray((CYL_SIZE - 1 - y) * row, (CYL_SIZE - y) * row), y * row);
    const cv = $("cyl");
    cv.width = CYL_SIZE;
    cv.height = CYL_SIZE;
    cv.getContext("2d").putImageData(img, 0, 0);
    note.textContent = `${cyl.cols} columns, each with its own (light, view) pair in the surface's frame`;
  }

  // Renders the model at the current pair; returns the milliseconds it took on the CPU side.
  function draw() {
    if (!model) return;
    const h = model.h;
    const active = interpolateAngular(model, pair.light, pair.view);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, angTex);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 1 + h.quads, 3 * h.parts, gl.RGBA, gl.FLOAT, angData);
    const act = [-1, -1, -1];
    active.slice(0, 3).forEach((p, i) => { act[i] = p; });
    gl.uniform3i(uni.act, act[0], act[1], act[2]);
    gl.uniform1f(uni.scale, scale());
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  const scale = () => f32((model ? model.h.display_scale : 1) * 2 ** exposureStops);

  // ---- hemisphere widgets ----
  const hemis = {};
  function hemi(id, which) {
    const cv = $(id);
    const g = cv.getContext("2d");
    const R = cv.width / 2 - 8, cx = cv.width / 2, cy = cv.height / 2;
    const toXY = (tDeg, pDeg) => [cx + (tDeg / 90) * R * Math.cos(pDeg * RAD), cy - (tDeg / 90) * R * Math.sin(pDeg * RAD)];
    const fromXY = (x, y) => {
      const dx = x - cx, dy = cy - y;
      const t = Math.min(90, (Math.hypot(dx, dy) / R) * 90);
      let p = Math.atan2(dy, dx) / RAD;
      if (p < 0) p += 360;
      const r2 = (v) => Math.round(v * 100) / 100;
      return [r2(t), t === 0 ? 0 : r2(p) % 360];
    };
    function paint() {
      g.clearRect(0, 0, cv.width, cv.height);
      g.strokeStyle = "#c5cad5";
      for (const t of [30, 60, 90]) {
        g.beginPath();
        g.arc(cx, cy, (t / 90) * R, 0, 2 * Math.PI);
        g.stroke();
      }
      g.beginPath();
      g.moveTo(cx - R, cy); g.lineTo(cx + R, cy); g.moveTo(cx, cy - R); g.lineTo(cx, cy + R);
      g.stroke();
      if (model) {
        const dirs = model.h[which].dirs;
        g.fillStyle = "#6b7385";
        for (const [t, p] of dirs) {
          const [x, y] = toXY(t / RAD, p / RAD);
          g.fillRect(x - 1.5, y - 1.5, 3, 3);
        }
      }
      const [t, p] = pair[which];
      const [x, y] = toXY(t, p);
      g.fillStyle = which === "light" ? "#f59e0b" : "#2563eb";
      g.beginPath();
      g.arc(x, y, 6, 0, 2 * Math.PI);
      g.fill();
    }
    const set = (e) => {
      const r = cv.getBoundingClientRect();
      const [t, p] = fromXY((e.clientX - r.left) * (cv.width / r.width), (e.clientY - r.top) * (cv.height / r.height));
      setDirection(which, [t, p]);
    };
    cv.addEventListener("pointerdown", (e) => { cv.setPointerCapture(e.pointerId); set(e); });
    cv.addEventListener("pointermove", (e) => {
      if (e.buttons & 1 || $(which === "light" ? "follow" : "follow-view").checked) set(e);
    });
    hemis[which] = { paint };
  }

  function setDirection(which, dir) {
    pair[which] = dir;
    $(`${which}-theta`).value = String(dir[0]);
    $(`${which}-phi`).value = String(dir[1]);
    hemis[which].paint();
    requestDraw();
  }

  // The model beside the measurement at the nearest measured pair (GET .../compare), asked
  // for once the pair has rested for 300 ms.
  let compareTimer = null, compareUrl = null, compareSeq = 0;
  function requestCompare() {
    clearTimeout(compareTimer);
    if (!model || !model.source) return;
    compareTimer = setTimeout(updateCompare, 300);
  }
  async function updateCompare() {
    const [dataset, name] = model.source;
    const seq = ++compareSeq;
    const q = `light_theta=${pair.light[0]}&light_phi=${pair.light[1]}&view_theta=${pair.view[0]}&view_phi=${pair.view[1]}&scale=${scale()}`;
    const r = await fetch(`${API}/datasets/${encodeURIComponent(dataset)}/models/${encodeURIComponent(name)}/compare?${q}`, { headers: auth() });
    if (seq !== compareSeq) return;
    if (!r.ok) {
      $("compare-text").textContent = `no comparison: ${await problemText(r)}`;
      return;
    }
    const url = URL.createObjectURL(await r.blob());
    if (compareUrl) URL.revokeObjectURL(compareUrl);
    compareUrl = url;
    $("compare").src = url;
    const text = `${r.headers.get("x-btfrig-pair")} (${r.headers.get("x-btfrig-directions")} deg): relative RMSE ${r.headers.get("x-btfrig-rel-rmse")}`;
    $("compare-text").textContent = text;
    $("compare").dataset.pair = r.headers.get("x-btfrig-pair");
    $("compare").dataset.relRmse = r.headers.get("x-btfrig-rel-rmse");
  }

  let drawPending = false;
  function requestDraw() {
    requestCompare();
    if (drawPending) return;
    drawPending = true;
    requestAnimationFrame(() => {
      drawPending = false;
      draw();
      if (model) drawCylinder();
    });
  }

  for (const which of ["light", "view"]) {
    for (const k of ["theta", "phi"]) {
      $(`${which}-${k}`).addEventListener("change", () => {
        const t = Math.min(90, Math.max(0, Number($(`${which}-theta`).value) || 0));
        const p = ((Number($(`${which}-phi`).value) || 0) % 360 + 360) % 360;
        setDirection(which, [t, p]);
      });
    }
  }
  $("exposure").addEventListener("input", () => {
    exposureStops = Number($("exposure").value);
    $("exposure-text").textContent = `×${(2 ** exposureStops).toFixed(2)}`;
    requestDraw();
  });

  // ---- loading ----
  async function loadModel(dataset, name) {
    $("v-load-text").textContent = "loading …";
    const r = await fetch(`${API}/datasets/${encodeURIComponent(dataset)}/models/${encodeURIComponent(name)}/data`,
      { headers: auth() });
    if (!r.ok) throw new Error(await problemText(r));
    const total = Number(r.headers.get("content-length")) || 0;
    const prog = $("v-progress");
    prog.max = total || 1;
    // Read as it streams: the progress bar shows the bytes received.
    const reader = r.body.getReader();
    let buf = new Uint8Array(total || 1 << 20), got = 0;
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      if (got + value.length > buf.length) {
        const bigger = new Uint8Array(Math.max(buf.length * 2, got + value.length));
        bigger.set(buf.subarray(0, got));
        buf = bigger;
      }
      buf.set(value, got);
      got += value.length;
      prog.value = got;
      $("v-load-text").textContent = `${(got / 1048576).toFixed(1)} of ${(total / 1048576).toFixed(1)} MiB`;
    }
    const data = buf.buffer.slice(0, got);
    const md = parseData(data);
    model = md;
    model.source = [dataset, name];
    setupGl(md);
    const h = md.h;
    $("v-info").textContent = `${h.label}, ${h.width} x ${h.height} texels, ${h.light.dirs.length} x ${h.view.dirs.length} directions, ${h.terms} terms, ${h.color}; ${(got / 1048576).toFixed(1)} MiB`;
    $("v-load-text").textContent = "loaded";
    hemis.light.paint();
    hemis.view.paint();
    draw();
    drawCylinder();
    requestCompare();
    $("btf").dataset.model = `${dataset}/${name}`;
    // The model's error per capture, below the other plots (a model without textures to
    // compare with says why not).
    getJson(`/datasets/${encodeURIComponent(dataset)}/models/${encodeURIComponent(name)}/errors`)
      .then((e) => BtfPlots.modelErrors($("model-errors"), h.label, e.errors))
      .catch((e) => { $("model-errors").textContent = `no compression error: ${e.message || e}`; });
  }

  // ---- datasets and plots ----
  let datasets = [];
  async function loadDatasets() {
    const d = await getJson("/datasets");
    datasets = d.datasets;
    const sel = $("v-dataset");
    sel.textContent = "";
    for (const ds of datasets) {
      const o = document.createElement("option");
      o.value = ds.name;
      o.textContent = `${ds.name} (${ds.state}, ${ds.captures} captures${ds.models.length ? "" : ", no model"})`;
      sel.append(o);
    }
    const want = new URLSearchParams(location.search).get("dataset");
    if (want && datasets.some((x) => x.name === want)) sel.value = want;
    datasetChosen();
  }

  function datasetChosen() {
    const ds = datasets.find((x) => x.name === $("v-dataset").value);
    const sel = $("v-model");
    sel.textContent = "";
    for (const mname of ds ? ds.models : []) {
      const o = document.createElement("option");
      o.value = mname;
      o.textContent = mname;
      sel.append(o);
    }
    if (ds) loadPlots(ds.name).catch((e) => showError(String(e.message || e)));
  }
  $("v-dataset").addEventListener("change", datasetChosen);

  let plotTimer = null;
  async function loadPlots(name) {
    clearTimeout(plotTimer);
    $("plots-info").textContent = `dataset ${name}`;
    const cov = await getJson(`/datasets/${encodeURIComponent(name)}/coverage`);
    BtfPlots.coverage($("coverage"), cov);
    // The per-capture series come from the report data, which the coverage has too.
    const r = await fetch(`${API}/datasets/${encodeURIComponent(name)}/files/journal.btfj`, { headers: auth() });
    if (r.ok) {
      const rows = parseJournal(await r.text());
      BtfPlots.series($("registration"), "Registration", "pixels / texels", rows, [
        { label: "marker RMS reprojection (px)", values: rows.map((c) => c.registration?.rms_px ?? null) },
        { label: "texel position sigma (texel)", values: rows.map((c) => c.registration?.texel_sigma ?? null) },
      ]);
      BtfPlots.series($("exposure-plot"), "Exposure", "seconds", rows, [
        { label: "base exposure (s)", values: rows.map((c) => (c.hdr ? c.hdr.exposures_s[0] : null)) },
      ]);
      const stages = [...new Set(rows.flatMap((c) => Object.keys(c.timing.stage_s || {})))].sort();
      BtfPlots.series($("stages"), "Stage times", "seconds", rows,
        stages.map((s) => ({ label: s, values: rows.map((c) => (c.timing.stage_s || {})[s] ?? null) })));
    }
    // A dome's multiplex gain per view group is in its report, written when the run ends (so
    // not asked for while it runs).
    const ds = datasets.find((x) => x.name === name);
    const live = Boolean(ds && LIVE_STATES.includes(ds.state));
    const rep = live ? null : await fetch(`${API}/datasets/${encodeURIComponent(name)}/files/report.json`, { headers: auth() });
    BtfPlots.multiplexGain($("multiplex-gain"), rep && rep.ok ? await rep.json().catch(() => null) : null);
    // A dataset being measured: the plots fill in as captures are committed, until its run
    // ends (its state is asked again each time, so the last poll shows the finished run).
    if (live) {
      plotTimer = setTimeout(() => refreshLive(name).catch(() => {}), 3000);
    }
  }
  const LIVE_STATES = ["running", "paused", "starting"];

  async function refreshLive(name) {
    if ($("v-dataset").value !== name) return;
    const d = await getJson("/datasets");
    const now = d.datasets.find((x) => x.name === name);
    const i = datasets.findIndex((x) => x.name === name);
    if (now && i >= 0) {
      datasets[i] = now;
      const o = [...$("v-dataset").options].find((x) => x.value === name);
      if (o) o.textContent = `${now.name} (${now.state}, ${now.captures} captures${now.models.length ? "" : ", no model"})`;
    }
    $("coverage").dataset.live = String(Boolean(now && LIVE_STATES.includes(now.state)));
    await loadPlots(name);
  }

  // The journal's step records (one JSON object a line after a length and checksum).
  function parseJournal(text) {
    const rows = [];
    for (const line of text.split("\n")) {
      const i = line.indexOf("{");
      if (i < 0) continue;
      try {
        const r = JSON.parse(line.slice(i));
        if (r.type === "step") rows.push(r);
      } catch (_) { /* a torn tail */ }
    }
    rows.sort((a, b) => a.timing.started_unix_s - b.timing.started_unix_s);
    return rows;
  }

  $("v-load").addEventListener("click", () => {
    const ds = $("v-dataset").value, mname = $("v-model").value;
    if (!ds || !mname) {
      showError("choose a dataset that has a compressed model (btfrig compress DIR, or [outputs] compressed_model in the plan)");
      return;
    }
    loadModel(ds, mname).catch((e) => showError(String(e.message || e)));
  });

  hemi("light-hemi", "light");
  hemi("view-hemi", "view");
  hemis.light.paint();
  hemis.view.paint();

  // ---- for tests and scripts ----
  window.btfViewer = {
    get ready() { return !!model; },
    get header() { return model && model.h; },
    get pair() { return JSON.parse(JSON.stringify(pair)); },
    load: (dataset, name) => loadModel(dataset, name),
    setPair(light, view) {
      setDirection("light", light);
      setDirection("view", view);
      draw();
    },
    // The cylinder view at the current pair, RGBA rows top first.
    cylinderPixels() {
      drawCylinder();
      return Array.from($("cyl").getContext("2d").getImageData(0, 0, CYL_SIZE, CYL_SIZE).data);
    },
    // The comparison at the current pair, once it has arrived: {pair, relRmse}.
    async compared() {
      clearTimeout(compareTimer);
      await updateCompare();
      return { pair: $("compare").dataset.pair, relRmse: Number($("compare").dataset.relRmse), text: $("compare-text").textContent };
    },
    // The canvas as RGBA rows, top row first (as the texture's row 0).
    pixels() {
      draw();
      const w = model.h.width, h = model.h.height;
      const px = new Uint8Array(w * h * 4);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
      const out = new Uint8Array(w * h * 4);
      for (let y = 0; y < h; y++) out.set(px.subarray((h - 1 - y) * w * 4, (h - y) * w * 4), y * w * 4);
      return Array.from(out);
    },
    // Frames per second over `frames` renders, each at a new light direction (interpolation,
    // upload and draw, finished by reading one pixel back).
    benchmark(frames) {
      const one = new Uint8Array(4);
      const t0 = performance.now();
      for (let i = 0; i < frames; i++) {
        pair.light = [20 + 40 * ((i * 7) % 13) / 13, (i * 37) % 360];
        draw();
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, one);
      }
      const s = (performance.now() - t0) / 1000;
      return frames / s;
    },
  };

  getJson("/me")
    .then((me) => {
      $("connection").textContent = `${me.name} (${me.role})`;
      $("connection").dataset.state = "ok";
      return loadDatasets();
    })
    .catch((e) => {
      $("connection").textContent = "token missing or rejected";
      $("connection").dataset.state = "denied";
      showError(String(e.message || e));
    });
})();
