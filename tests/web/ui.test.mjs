// Browser test of the operator page, in Debian's headless Chromium driven by playwright-core.
// usage: node tests/web/ui.test.mjs BASE_URL SCREENSHOT.png   (tests/web/run.sh starts the
// daemon, installs what is missing and calls this). Exit 0: every check passed.
//
// 0. without a token: the page shows the daemon's 401 message;
// 1. as a viewer: Start is refused, the page shows the problem+json message (403);
// 2. as an operator (#token=operator-token): the token leaves the address bar, devices and
//    plans load, plan "demo" is chosen, Start; the progress bar advances at least twice and
//    the preview image changes (new blob, different bytes) at least once;
// 2b. meanwhile /viewer on the run's dataset (as a viewer): its coverage and registration
//    plots fill in as captures are committed (the counts grow, measured + pending stays);
// 3. Pause: the state shows "paused", Pause is disabled and Resume enabled; screenshot;
// 4. Abort (two clicks: the page asks for a confirmation): the state shows "aborted";
// 5. a plan file (demo.toml with the simulator's "flaky" faults) through the file field:
//    the dry run says valid, Start runs it (plan_text), a warning appears in the list, Abort.
import { createRequire } from "node:module";
import fs from "node:fs";
import os from "node:os";
import path from "node:path";

const [base, shot] = process.argv.slice(2);
if (!base || !shot) {
  console.error("usage: node ui.test.mjs BASE_URL SCREENSHOT.png");
  process.exit(2);
}
const webdeps = process.env.BTFRIG_WEBDEPS;
if (!webdeps) {
  console.error("BTFRIG_WEBDEPS (the folder holding node_modules/playwright-core) is not set");
  process.exit(2);
}
const { chromium } = createRequire(path.join(webdeps, "package.json"))("playwright-core");

const repo = path.resolve(path.dirname(new URL(import.meta.url).pathname), "..", "..");
const TIMEOUT_MS = Number(process.env.BTFRIG_WEB_TIMEOUT_MS || 120000);
let failures = 0;
let passes = 0;
function check(ok, what, extra) {
  if (ok) {
    passes++;
    console.log(`ok - ${what}`);
  } else {
    failures++;
    console.log(`not ok - ${what}${extra ? `: ${extra}` : ""}`);
  }
  return ok;
}
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const text = (page, sel) => page.locator(sel).innerText();

const profile = fs.mkdtempSync(path.join(os.tmpdir(), "btfrig-chromium-"));
const context = await chromium.launchPersistentContext(profile, {
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  headless: true,
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync"],
  viewport: { width: 1280, height: 900 },
});
const pageErrors = [];
const external = [];

async function newPage(label) {
  const page = await context.newPage();
  page.on("pageerror", (e) => pageErrors.push(`${label}: ${e.message}`));
  page.on("console", (m) => { if (m.type() === "error") console.log(`# ${label} console: ${m.text()}`); });
  // Nothing but the daemon itself may be asked for anything.
  page.on("request", (r) => { if (!r.url().startsWith(base) && !r.url().startsWith("blob:") && !r.url().startsWith("data:")) external.push(r.url()); });
  return page;
}

let page;
try {
  // ---- 0. no token: the page says so (401) and asks for one ----
  const anon = await newPage("anonymous");
  await anon.goto(`${base}/`);
  await anon.locator('#connection[data-state="denied"]').waitFor({ timeout: 20000 });
  await anon.locator("#error:not([hidden])").waitFor({ timeout: 10000 });
  const anonBadge = await text(anon, "#connection");
  const anonError = await text(anon, "#error-text");
  console.log(`# without a token: badge ${JSON.stringify(anonBadge)}, error ${JSON.stringify(anonError)}`);
  // The badge names the cause; the error line carries the daemon's 401 problem+json detail,
  // which says how to send a token.
  check(anonBadge === "token missing or rejected" && anonError.includes("Authorization: Bearer"),
    "without a token the page shows 'token missing or rejected' and the daemon's 401 detail",
    `badge ${JSON.stringify(anonBadge)}, error ${JSON.stringify(anonError)}`);
  await anon.close();

  // ---- 1. a viewer cannot start a run, and is told why ----
  const viewer = await newPage("viewer");
  await viewer.goto(`${base}/#token=viewer-token`);
  await viewer.locator('#plan option[value="demo"]').waitFor({ state: "attached", timeout: 20000 });
  await viewer.selectOption("#plan", "demo");
  await viewer.locator("#start:not([disabled])").waitFor({ timeout: 20000 });
  await viewer.click("#start");
  await viewer.locator("#error:not([hidden])").waitFor({ timeout: 10000 });
  const denied = await text(viewer, "#error-text");
  check(denied.trim().length > 0, "viewer's Start is refused with the daemon's message shown", denied);
  console.log(`# viewer sees: ${denied}`);
  check((await text(viewer, "#run-state")) !== "starting", "viewer started no run");
  await viewer.close();

  // ---- 2. an operator starts plan demo ----
  page = await newPage("operator");
  await page.goto(`${base}/#token=operator-token`);
  check(!page.url().includes("operator-token"), "token removed from the address bar", page.url());
  check(await page.evaluate(() => sessionStorage.getItem("btfrig.token")) === "operator-token", "token kept in sessionStorage");
  await page.locator('#plan option[value="demo"]').waitFor({ state: "attached", timeout: 20000 });
  await page.locator("#devices tbody tr[data-device]").first().waitFor({ timeout: 20000 });
  const devices = await page.locator("#devices tbody tr[data-device]").count();
  check(devices > 0, `device table lists ${devices} devices`);
  await page.selectOption("#plan", "demo");
  await page.locator("#start:not([disabled])").waitFor({ timeout: 20000 });
  const progress0 = await page.$eval("#progress", (p) => p.value);
  await page.click("#start");

  let advances = 0;
  let lastValue = progress0;
  const values = [progress0];
  const srcs = new Set();
  const hashes = new Set();
  let lastSrc = await page.$eval("#preview", (i) => i.getAttribute("src") || "");
  const t0 = Date.now();
  let ended = null;
  while (Date.now() - t0 < TIMEOUT_MS) {
    const s = await page.evaluate(async (prevSrc) => {
      const p = document.getElementById("progress");
      const img = document.getElementById("preview");
      const src = img.getAttribute("src") || "";
      let hash = null;
      if (src && src !== prevSrc) {
        // The bytes behind the image: FNV-1a of the blob the page fetched.
        const buf = new Uint8Array(await (await fetch(src)).arrayBuffer());
        let h = 0x811c9dc5;
        for (const b of buf) h = Math.imul(h ^ b, 16777619) >>> 0;
        hash = `${buf.length}:${h.toString(16)}`;
      }
      return { value: p.value, max: p.max, src, hash, state: document.getElementById("run-state").textContent,
        error: document.getElementById("error").hidden ? null : document.getElementById("error-text").textContent };
    }, lastSrc);
    if (s.value > lastValue) {
      advances++;
      values.push(s.value);
    }
    lastValue = s.value;
    if (s.src && s.src !== lastSrc) {
      srcs.add(s.src);
      if (s.hash) hashes.add(s.hash);
      lastSrc = s.src;
    }
    if (s.error) console.log(`# page shows an error: ${s.error}`);
    if (advances >= 2 && hashes.size >= 2) break;
    if (["finished", "aborted", "interrupted", "failed"].includes(s.state)) {
      ended = s.state;
      break;
    }
    await sleep(100);
  }
  console.log(`# progress values seen: ${values.join(", ")} (max ${await page.$eval("#progress", (p) => p.max)}); preview images: ${srcs.size}, distinct bytes: ${hashes.size}`);
  check(!ended, "run still going while the page was watched", `it ended as ${ended}`);
  check(advances >= 2, `progress bar advanced ${advances} times`);
  check(hashes.size >= 2, `preview image changed (${hashes.size} distinct images)`);
  check(/\S/.test(await text(page, "#eta")) && (await text(page, "#eta")) !== "–", `ETA shown: ${await text(page, "#eta")}`);

  // ---- 2b. the viewer's plots of the run's dataset fill in while the run goes on ----
  const runName = (await text(page, "#run-dataset")).trim();
  const live = await newPage("live viewer");
  await live.goto(`${base}/viewer?dataset=${encodeURIComponent(runName)}#token=viewer-token`);
  await live.locator("#coverage[data-measured]").waitFor({ state: "attached", timeout: 20000 });
  const liveCounts = () => live.$eval("#coverage", (e) => ({
    measured: Number(e.dataset.measured), pending: Number(e.dataset.pending),
    points: Number(document.getElementById("registration").dataset.points || 0) }));
  const c0 = await liveCounts();
  let grew = false;
  try {
    // The page polls every 3 s; the run commits a capture every fraction of a second.
    await live.waitForFunction((m) => Number(document.getElementById("coverage").dataset.measured) > m, c0.measured, { timeout: 60000 });
    grew = true;
  } catch (_) { /* reported below */ }
  const c1 = await liveCounts();
  console.log(`# live viewer on ${runName}: measured ${c0.measured} -> ${c1.measured}, pending ${c0.pending} -> ${c1.pending}, registration points ${c0.points} -> ${c1.points}`);
  check(grew && c1.pending < c0.pending && c1.measured + c1.pending === c0.measured + c0.pending,
    `the viewer's coverage plot of the running dataset fills in (${c0.measured} -> ${c1.measured} measured)`);
  check(c1.points > c0.points, `its registration plot gains points (${c0.points} -> ${c1.points})`);
  await live.close();

  // ---- 3. pause ----
  await page.locator("#pause:not([disabled])").waitFor({ timeout: 10000 });
  await page.click("#pause");
  let paused = false;
  try {
    await page.waitForFunction(() => document.getElementById("run-state").textContent === "paused", null, { timeout: 30000 });
    paused = true;
  } catch (_) { /* reported below */ }
  check(paused, "state shows paused", await text(page, "#run-state"));
  if (paused) {
    await page.locator("#resume:not([disabled])").waitFor({ timeout: 5000 }).catch(() => {});
    check(await page.$eval("#pause", (b) => b.disabled), "Pause disabled while paused");
    check(!(await page.$eval("#resume", (b) => b.disabled)), "Resume enabled while paused");
    const v1 = await page.$eval("#progress", (p) => p.value);
    await sleep(1500);
    const v2 = await page.$eval("#progress", (p) => p.value);
    // Informational: the step under way when Pause was clicked may still be reported.
    console.log(`# progress while paused: ${v1} -> ${v2} over 1.5 s`);
  }
  check(await page.$eval("#error", (e) => e.hidden), "no error shown to the operator", await text(page, "#error-text").catch(() => ""));
  fs.mkdirSync(path.dirname(shot), { recursive: true });
  await page.screenshot({ path: shot, fullPage: true });
  console.log(`# screenshot: ${shot}`);

  // ---- 4. abort (the page asks for a second click) ----
  await page.locator("#abort:not([disabled])").waitFor({ timeout: 10000 });
  await page.click("#abort");
  check((await text(page, "#abort")).toLowerCase().includes("confirm"), "Abort asks for a confirmation");
  await page.click("#abort");
  let aborted = false;
  try {
    await page.waitForFunction(() => document.getElementById("run-state").textContent === "aborted", null, { timeout: 30000 });
    aborted = true;
  } catch (_) { /* reported below */ }
  check(aborted, "state shows aborted", await text(page, "#run-state"));

  // ---- 5. a plan file (plan_text) with the simulator's "flaky" faults: warnings listed ----
  const demo = fs.readFileSync(path.join(repo, "rig-configs/plans/demo.toml"), "utf8");
  const flaky = demo.replace(/^name = .*$/m, 'name = "demo-flaky"').replace(/^fault_scenario = .*$/m, 'fault_scenario = "flaky"');
  check(flaky.includes('fault_scenario = "flaky"'), "flaky variant of demo.toml made");
  await page.setInputFiles("#plan-file", { name: "demo-flaky.toml", mimeType: "text/plain", buffer: Buffer.from(flaky) });
  await page.locator("#plan-file-clear:not([hidden])").waitFor({ timeout: 5000 });
  await page.click("#dry-run");
  await page.waitForFunction(() => /^(valid|invalid)/.test(document.getElementById("plan-info").textContent), null, { timeout: 30000 });
  const info = await text(page, "#plan-info");
  check(info.startsWith("valid"), `dry run of the plan file: ${info}`);
  await page.locator("#start:not([disabled])").waitFor({ timeout: 20000 });
  await page.click("#start");
  await page.waitForFunction(() => document.getElementById("run-plan").textContent === "demo-flaky", null, { timeout: 20000 });
  let warned = false;
  try {
    await page.locator("#warnings li:not(.empty)").first().waitFor({ timeout: TIMEOUT_MS });
    warned = true;
  } catch (_) { /* reported below */ }
  check(warned, "a warning of the flaky run is listed", await text(page, "#warnings"));
  if (warned) console.log(`# first warning: ${(await text(page, "#warnings li:not(.empty)")).split("\n")[0]}`);
  await page.screenshot({ path: shot.replace(/\.png$/, "-warnings.png"), fullPage: true });
  await page.locator("#abort:not([disabled])").waitFor({ timeout: 10000 });
  await page.click("#abort");
  await page.click("#abort");
  let aborted2 = false;
  try {
    await page.waitForFunction(() => document.getElementById("run-state").textContent === "aborted", null, { timeout: 30000 });
    aborted2 = true;
  } catch (_) { /* reported below */ }
  check(aborted2, "flaky run aborted", await text(page, "#run-state"));
} catch (e) {
  check(false, "browser test ran to the end", e.stack || String(e));
  if (page) await page.screenshot({ path: shot.replace(/\.png$/, "-failure.png"), fullPage: true }).catch(() => {});
} finally {
  check(pageErrors.length === 0, "no script errors on the page", pageErrors.join("; "));
  check(external.length === 0, "no request left the daemon", external.join(", "));
  await context.close();
  fs.rmSync(profile, { recursive: true, force: true });
}
console.log(`${passes} passed, ${failures} failed`);
process.exit(failures ? 1 : 0);
