// Browser test of the BTF viewer (/viewer) and of `btfrig dataset report`, in Debian's
// headless Chromium (WebGL2 through SwiftShader) driven by playwright-core.
// usage: node tests/web/viewer.test.mjs BASE_URL OUT_DIR   (tests/web/run.sh makes the demo's
// dataset with `btfrig demo`, its report, a CLI render, and the synthetic 256 x 256 model).
//
// 1. as a viewer (the role that may read, not steer): /viewer opens on dataset "demo", loads
//    its FMF model (streamed), and for three (light, view) pairs — the first set by dragging
//    on the hemisphere widgets — the canvas equals btfrig's own render of the model at the
//    same pair (GET .../render) within TOLERANCE; moving the light changes the image;
//    a screenshot per pair; its PCMF (log-Y) and PVMF (RGB) models at one pair each; the
//    side-by-side comparison with the measured texture at the nearest measured pair; the
//    sample on a cylinder (FMF, and PVMF) brighter on the side towards the light;
// 2. the coverage plot's counts equal report.json's (captures, skipped by reason); the
//    compression error per capture is plotted, one point per capture;
// 3. `btfrig dataset render` (the CLI) gives the API's pixels;
// 4. frame rate with the synthetic 256 x 256, 81 x 81 FMF model: printed, not asserted;
// 5. the report file opens from disk with every request refused, and shows the coverage
//    (counts as report.json) and the per-capture plots (registration, stage times,
//    compression error) with one point per capture.
import { createRequire } from "node:module";
import fs from "node:fs";
import os from "node:os";
import path from "node:path";

const [base, out] = process.argv.slice(2);
if (!base || !out) {
  console.error("usage: node viewer.test.mjs BASE_URL OUT_DIR");
  process.exit(2);
}
const { chromium } = createRequire(path.join(process.env.BTFRIG_WEBDEPS, "package.json"))("playwright-core");

// The canvas against btfrig's render, 8-bit sRGB levels per channel: the shader sums the
// same f32 values in another order (and SwiftShader's pow may differ in the last bits), so a
// level may flip where a value sits on a rounding edge. Every channel within 2 levels, the
// mean absolute difference under 0.1 level.
const TOLERANCE = { max: 2, mean: 0.1 };

let failures = 0, passes = 0;
function check(ok, what, extra) {
  if (ok) { passes++; console.log(`ok - ${what}`); } else { failures++; console.log(`not ok - ${what}${extra ? `: ${extra}` : ""}`); }
  return ok;
}

const profile = fs.mkdtempSync(path.join(os.tmpdir(), "btfrig-chromium-viewer-"));
const context = await chromium.launchPersistentContext(profile, {
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  // WebGL2 without a GPU: SwiftShader through ANGLE.
  args: ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-quic",
    "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync"],
  viewport: { width: 1280, height: 1000 },
});
const pageErrors = [];
const external = [];

// Pixel statistics of two RGBA arrays (alpha ignored).
function compare(a, b) {
  let max = 0, sum = 0, n = 0;
  for (let i = 0; i < a.length; i += 4) {
    for (let c = 0; c < 3; c++) {
      const d = Math.abs(a[i + c] - b[i + c]);
      max = Math.max(max, d);
      sum += d;
      n++;
    }
  }
  return { max, mean: sum / n };
}

// Decodes PNG bytes (base64) into RGBA in the page.
const decodePng = (page, b64) => page.evaluate(async (b64) => {
  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
  const bmp = await createImageBitmap(new Blob([bytes], { type: "image/png" }));
  const cv = new OffscreenCanvas(bmp.width, bmp.height);
  const g = cv.getContext("2d");
  g.drawImage(bmp, 0, 0);
  return Array.from(g.getImageData(0, 0, bmp.width, bmp.height).data);
}, b64);

try {
  const page = await context.newPage();
  page.on("pageerror", (e) => pageErrors.push(`viewer: ${e.message}`));
  page.on("console", (m) => { if (m.type() === "error") console.log(`# viewer console: ${m.text()}`); });
  page.on("request", (r) => { if (!r.url().startsWith(base) && !r.url().startsWith("blob:") && !r.url().startsWith("data:")) external.push(r.url()); });
  const token = "viewer-token";
  await page.goto(`${base}/viewer?dataset=demo#token=${token}`);
  await page.locator('#v-model option[value="fmf"]').waitFor({ state: "attached", timeout: 20000 });
  check(await page.$eval("#v-dataset", (s) => s.value) === "demo", "viewer opens on dataset demo");
  await page.click("#v-load");
  await page.waitForFunction(() => window.btfViewer && window.btfViewer.ready, null, { timeout: 30000 });
  const h = await page.evaluate(() => window.btfViewer.header);
  console.log(`# model: ${h.label}, ${h.width} x ${h.height}, ${h.light.dirs.length} x ${h.view.dirs.length} directions, ${h.terms} terms, colour ${h.color}, display scale ${h.display_scale}`);

  // Pair 1 by dragging: the light from the widget's centre towards the upper right, the view
  // towards the left.
  const drag = async (sel, fx, fy) => {
    const b = await page.locator(sel).boundingBox();
    await page.mouse.move(b.x + b.width / 2, b.y + b.height / 2);
    await page.mouse.down();
    await page.mouse.move(b.x + b.width * fx, b.y + b.height * fy, { steps: 5 });
    await page.mouse.up();
  };
  await drag("#light-hemi", 0.7, 0.35);
  await drag("#view-hemi", 0.35, 0.55);
  const dragged = await page.evaluate(() => window.btfViewer.pair);
  check(dragged.light[0] > 10 && dragged.view[0] > 10, `dragging set light ${JSON.stringify(dragged.light)}, view ${JSON.stringify(dragged.view)} (deg)`);
  const fields = await page.evaluate(() => ["light-theta", "light-phi", "view-theta", "view-phi"].map((id) => Number(document.getElementById(id).value)));
  check(JSON.stringify(fields) === JSON.stringify([...dragged.light, ...dragged.view]), `the fields show the dragged pair ${fields}`);

  // "follows the mouse": the view (then the light) moves with the pointer, no button pressed;
  // unchecked, moving leaves it.
  const hover = async (sel, fx, fy) => {
    const b = await page.locator(sel).boundingBox();
    await page.mouse.move(b.x + b.width * fx, b.y + b.height * fy, { steps: 3 });
  };
  await page.locator("#follow-view").check();
  await hover("#view-hemi", 0.85, 0.5);
  const followed = await page.evaluate(() => window.btfViewer.pair);
  await page.locator("#follow-view").uncheck();
  await page.locator("#follow").check();
  await hover("#light-hemi", 0.5, 0.2);
  const lit = await page.evaluate(() => window.btfViewer.pair);
  await page.locator("#follow").uncheck();
  await hover("#view-hemi", 0.3, 0.3);
  await hover("#light-hemi", 0.7, 0.7);
  const left = await page.evaluate(() => window.btfViewer.pair);
  console.log(`# follow the mouse: view ${JSON.stringify(followed.view)}, then light ${JSON.stringify(lit.light)}; unchecked ${JSON.stringify(left)}`);
  check(followed.view[0] > 30 && (followed.view[1] < 5 || followed.view[1] > 355) && JSON.stringify(followed.light) === JSON.stringify(dragged.light),
    `view follows the mouse (to the right: phi 0), light unchanged`);
  check(lit.light[0] > 30 && Math.abs(lit.light[1] - 90) < 5 && JSON.stringify(lit.view) === JSON.stringify(followed.view),
    `light follows the mouse (upwards: phi 90), view unchanged`);
  check(JSON.stringify(left) === JSON.stringify(lit), "unchecked, moving the mouse changes nothing");

  const pairs = [dragged, { light: [25, 40], view: [10, 200] }, { light: [0, 0], view: [28, 300] }];
  const images = [];
  for (const [i, p] of pairs.entries()) {
    const px = await page.evaluate((p) => { window.btfViewer.setPair(p.light, p.view); return window.btfViewer.pixels(); }, p);
    const q = `light_theta=${p.light[0]}&light_phi=${p.light[1]}&view_theta=${p.view[0]}&view_phi=${p.view[1]}`;
    const r = await page.request.get(`${base}/api/v1/datasets/demo/models/fmf/render?${q}`, { headers: { Authorization: `Bearer ${token}` } });
    check(r.ok(), `GET render at pair ${i + 1}: ${r.status()}`);
    const ref = await decodePng(page, (await r.body()).toString("base64"));
    check(ref.length === px.length, `render and canvas have the same size (${ref.length / 4} texels)`);
    const s = compare(px, ref);
    console.log(`# pair ${i + 1}: light ${JSON.stringify(p.light)}, view ${JSON.stringify(p.view)}: canvas vs btfrig's render: max ${s.max}, mean ${s.mean.toFixed(4)} levels (of 255)`);
    check(s.max <= TOLERANCE.max && s.mean <= TOLERANCE.mean, `pair ${i + 1}: canvas equals btfrig's render within ${TOLERANCE.max} levels (mean under ${TOLERANCE.mean})`, JSON.stringify(s));
    images.push(px);
    await page.screenshot({ path: path.join(out, `viewer-pair${i + 1}.png`), fullPage: true });
    if (i === 1) {
      // The model beside the measured texture at the nearest measured pair, with their difference.
      const c = await page.evaluate(() => window.btfViewer.compared());
      console.log(`# comparison at pair 2: ${c.text}`);
      check(/^light \d+ view \d+$/.test(c.pair || "") && c.relRmse > 0 && c.relRmse < 0.1,
        `side by side with the measurement: nearest measured ${c.pair}, relative RMSE ${c.relRmse} (under 0.1)`, JSON.stringify(c));
      await page.locator("#model-section").screenshot({ path: path.join(out, "viewer-model.png") });
    }
  }
  // Moving the light (alone) changes the image.
  const moved = await page.evaluate((p) => { window.btfViewer.setPair([25, 220], p.view); return window.btfViewer.pixels(); }, pairs[1]);
  const change = compare(images[1], moved);
  console.log(`# light moved from [25, 40] to [25, 220]: mean change ${change.mean.toFixed(2)} levels, max ${change.max}`);
  check(change.mean > 1, "moving the light changes the image");

  // The sample on a cylinder: lit from the right, then from the left; each side brighter
  // when lit (per-column light directions), and the image changes.
  const cylMeans = async (light) => page.evaluate((light) => {
    window.btfViewer.setPair(light, [0, 0]);
    const px = window.btfViewer.cylinderPixels();
    const side = (x0, x1) => {
      let s = 0, n = 0;
      for (let y = 0; y < 256; y++) for (let x = x0; x < x1; x++) { const i = (y * 256 + x) * 4; s += px[i] + px[i + 1] + px[i + 2]; n += 3; }
      return s / n;
    };
    return { left: side(20, 100), right: side(156, 236), px };
  }, light);
  const fromRight = await cylMeans([60, 0]);
  const fromLeft = await cylMeans([60, 180]);
  console.log(`# cylinder: lit from the right: left ${fromRight.left.toFixed(1)}, right ${fromRight.right.toFixed(1)}; from the left: left ${fromLeft.left.toFixed(1)}, right ${fromLeft.right.toFixed(1)} (mean sRGB level)`);
  check(fromRight.right > fromRight.left && fromLeft.left > fromLeft.right && compare(fromRight.px, fromLeft.px).mean > 1,
    "the cylinder's side towards the light is the brighter one, and it changes with the light");
  await page.locator("#model-section").screenshot({ path: path.join(out, "viewer-cylinder.png") });

  // The PCMF (log-Y colour model) and PVMF (RGB) models of the same dataset at one pair each.
  for (const other of ["pcmf", "pvmf"]) {
    await page.evaluate((m) => window.btfViewer.load("demo", m), other);
    const oh = await page.evaluate(() => window.btfViewer.header);
    const p = pairs[1];
    const px = await page.evaluate((p) => { window.btfViewer.setPair(p.light, p.view); return window.btfViewer.pixels(); }, p);
    const q = `light_theta=${p.light[0]}&light_phi=${p.light[1]}&view_theta=${p.view[0]}&view_phi=${p.view[1]}`;
    const r = await page.request.get(`${base}/api/v1/datasets/demo/models/${other}/render?${q}`, { headers: { Authorization: `Bearer ${token}` } });
    const s = compare(px, await decodePng(page, (await r.body()).toString("base64")));
    console.log(`# ${oh.label} (${oh.parts} parts, colour ${oh.color}) at pair 2: canvas vs btfrig's render: max ${s.max}, mean ${s.mean.toFixed(4)} levels`);
    check(r.ok() && s.max <= TOLERANCE.max && s.mean <= TOLERANCE.mean, `${other}: canvas equals btfrig's render within the tolerance`, JSON.stringify(s));
    if (other === "pvmf") {
      // A PVMF on the cylinder: each column sums its own view parts.
      const [cr, cl] = [await cylMeans([60, 0]), await cylMeans([60, 180])];
      console.log(`# pvmf cylinder: lit from the right: left ${cr.left.toFixed(1)}, right ${cr.right.toFixed(1)}; from the left: left ${cl.left.toFixed(1)}, right ${cl.right.toFixed(1)}`);
      check(cr.right > cr.left && cl.left > cl.right && cr.right > 20 && compare(cr.px, cl.px).mean > 1,
        "pvmf: the cylinder's side towards the light is the brighter one");
    }
  }

  await page.evaluate(() => window.btfViewer.load("demo", "fmf"));
  await page.locator('#model-errors[data-points]').waitFor({ state: "attached", timeout: 20000 });

  // ---- 2. coverage against report.json ----
  const rep = JSON.parse((await (await page.request.get(`${base}/api/v1/datasets/demo/files/report.json`, { headers: { Authorization: `Bearer ${token}` } })).body()).toString());
  await page.locator("#coverage[data-measured]").waitFor({ state: "attached", timeout: 20000 });
  const cov = await page.$eval("#coverage", (e) => ({ measured: Number(e.dataset.measured), skipped: JSON.parse(e.dataset.skipped), pending: Number(e.dataset.pending) }));
  console.log(`# coverage plot: ${cov.measured} measured, skipped ${JSON.stringify(cov.skipped)}, ${cov.pending} pending; report.json: ${rep.captures} captures, skipped ${JSON.stringify(rep.skipped)}`);
  check(cov.measured === rep.captures, `coverage plot's measured pairs (${cov.measured}) = report's captures (${rep.captures})`);
  check(JSON.stringify(Object.entries(cov.skipped).sort()) === JSON.stringify(Object.entries(rep.skipped).sort()), "coverage plot's skipped pairs by reason = report's");
  check(await page.locator("#coverage canvas.coverage-matrix").count() === 1, "coverage matrix drawn");
  check(await page.locator("#stages .uplot canvas").count() >= 1, "stage-time plot drawn (uPlot)");
  const errPoints = await page.$eval("#model-errors", (e) => Number(e.dataset.points));
  check(errPoints === rep.captures && await page.locator("#model-errors .uplot canvas").count() === 1,
    `compression error per capture plotted: ${errPoints} points`);
  await page.locator("#plots-section").screenshot({ path: path.join(out, "viewer-coverage.png") });

  // ---- 3. the CLI's render equals the API's ----
  const cliPng = path.join(out, "render-cli.png");
  if (check(fs.existsSync(cliPng), "btfrig dataset render wrote render-cli.png")) {
    const p = pairs[1];
    const q = `light_theta=${p.light[0]}&light_phi=${p.light[1]}&view_theta=${p.view[0]}&view_phi=${p.view[1]}`;
    const api = await decodePng(page, (await (await page.request.get(`${base}/api/v1/datasets/demo/models/fmf/render?${q}`, { headers: { Authorization: `Bearer ${token}` } })).body()).toString("base64"));
    const cli = await decodePng(page, fs.readFileSync(cliPng).toString("base64"));
    check(compare(api, cli).max === 0, "btfrig dataset render gives the API's pixels");
  }

  // ---- 4. frame rate with a 256 x 256, 81 x 81 FMF model ----
  const t0 = Date.now();
  await page.evaluate(() => window.btfViewer.load("fps-synthetic-256", "fmf"));
  const loadS = (Date.now() - t0) / 1000;
  const big = await page.evaluate(() => window.btfViewer.header);
  check(big.width === 256 && big.light.dirs.length === 81 && big.view.dirs.length === 81, `synthetic model loaded: ${big.width} x ${big.height}, ${big.light.dirs.length} x ${big.view.dirs.length}, ${big.terms} terms`);
  const fps = await page.evaluate(() => window.btfViewer.benchmark(40));
  console.log(`# frame rate: ${fps.toFixed(1)} frames/s (256 x 256 FMF, 81 x 81, ${big.terms} terms, headless Chromium, SwiftShader, 40 frames); model data loaded in ${loadS.toFixed(1)} s`);
  await page.close();

  // ---- 5. the report file, with no network ----
  const reportFile = path.join(out, "report.html");
  if (check(fs.existsSync(reportFile), "btfrig dataset report wrote report.html")) {
    const rp = await context.newPage();
    const refused = [];
    await rp.route("**/*", (r) => {
      if (r.request().url().startsWith("file:")) return r.continue();
      refused.push(r.request().url());
      return r.abort();
    });
    rp.on("pageerror", (e) => pageErrors.push(`report: ${e.message}`));
    await rp.goto(`file://${reportFile}`);
    await rp.locator("#coverage[data-measured]").waitFor({ state: "attached", timeout: 10000 });
    const rc = await rp.$eval("#coverage", (e) => ({ measured: Number(e.dataset.measured), skipped: JSON.parse(e.dataset.skipped) }));
    check(rc.measured === rep.captures && JSON.stringify(Object.entries(rc.skipped).sort()) === JSON.stringify(Object.entries(rep.skipped).sort()),
      `report file: coverage ${rc.measured} measured, skipped ${JSON.stringify(rc.skipped)} = report.json`);
    for (const id of ["registration", "stages", "compression"]) {
      const n = await rp.$eval(`#${id}`, (e) => Number(e.dataset.points));
      const drawn = await rp.locator(`#${id} .uplot canvas`).count();
      check(n === rep.captures && drawn >= 1, `report file: ${id} plot drawn with ${n} points (one per capture)`);
    }
    // Multiplex gain per view group: none for the gonio demo; a dome-shaped report (the
    // stuck-LED dome test's figures, crates/measurement/tests/dome.rs) plots one point a group.
    const none = await rp.$eval("#multiplex-gain", (e) => ({ points: e.dataset.points, text: e.textContent }));
    check(none.points === "0" && none.text.includes("none"), `report file: no multiplex gain for a gonio run ("${none.text}")`);
    const mg = await rp.evaluate(() => {
      const el = document.createElement("div");
      document.body.append(el);
      const u = BtfPlots.multiplexGain(el, { multiplex_gain_predicted: 1.972, multiplex_gain_measured: 1.95,
        multiplex_gain_per_group: [{ view: 15, camera: 4, rotation: 1, gain: 1.598, lights: 198, faults: 1 },
          { view: 16, camera: 5, rotation: 1, gain: 1.972, lights: 198, faults: 0 }] });
      const out = { points: el.dataset.points, series: el.dataset.series, canvas: el.querySelectorAll(".uplot canvas").length,
        data: u ? u.data.map((s) => Array.from(s)) : null };
      el.remove();
      return out;
    });
    console.log(`# multiplex gain plot of a dome-shaped report: ${JSON.stringify(mg)}`);
    check(mg.points === "2" && mg.canvas >= 1 && JSON.stringify(mg.data) === JSON.stringify([[1, 2], [1.598, 1.972], [1.972, 1.972], [1.95, null]]),
      "report file: multiplex gain per view group plotted (group, predicted after faults, run's predicted, measured first group)");
    check(refused.length === 0, "the report file asked for nothing beyond itself", refused.join(", "));
    await rp.screenshot({ path: path.join(out, "report.png"), fullPage: true });
    await rp.close();
  }
} catch (e) {
  check(false, "viewer test ran to the end", e.stack || String(e));
} finally {
  check(pageErrors.length === 0, "no script errors on the pages", pageErrors.join("; "));
  check(external.length === 0, "no request left the daemon", external.join(", "));
  await context.close();
  fs.rmSync(profile, { recursive: true, force: true });
}
console.log(`${passes} passed, ${failures} failed`);
process.exit(failures ? 1 : 0);
