// Plots of a dataset, shared by the operator page (/ui/plots.js) and the self-contained
// report file (`btfrig dataset report`, which inlines this script, uPlot and the data).
// Coverage is a matrix of (light, view) cells drawn on a canvas (one rectangle per pair:
// nothing a chart library adds); the per-capture series are uPlot charts (vendored, see
// ui/vendor/README.md).
"use strict";
const BtfPlots = (() => {
  const STATE_COLORS = { measured: "#2a9d4b", pending: "#d0d0d0" };
  const REASON_COLORS = ["#e76f51", "#457b9d", "#f4a261", "#8d5fd3", "#e9c46a", "#264653"];

  function reasonColor(reasons, r) {
    const i = reasons.indexOf(r);
    return REASON_COLORS[i % REASON_COLORS.length];
  }

  // The coverage matrix: one cell per pair, lights across, views down. The element carries
  // the counts it shows (data-measured, data-pending, data-skipped as JSON) for tests.
  function coverage(el, cov) {
    el.textContent = "";
    const nl = cov.light.length, nv = cov.view.length;
    const cell = Math.max(3, Math.min(14, Math.floor(640 / Math.max(nl, 1))));
    const cv = document.createElement("canvas");
    cv.className = "coverage-matrix";
    cv.width = nl * cell + 1;
    cv.height = nv * cell + 1;
    cv.title = "columns: lights, rows: views";
    const g = cv.getContext("2d");
    const reasons = Object.keys(cov.skipped);
    const counts = { measured: 0, pending: 0, skipped: {} };
    for (const p of cov.pairs) {
      let color;
      if (p.state === "skipped") {
        color = reasonColor(reasons, p.reason);
        counts.skipped[p.reason] = (counts.skipped[p.reason] || 0) + 1;
      } else {
        color = STATE_COLORS[p.state] || "#000";
        counts[p.state] = (counts[p.state] || 0) + 1;
      }
      g.fillStyle = color;
      g.fillRect(p.light * cell + 1, p.view * cell + 1, cell - 1, cell - 1);
    }
    const legend = document.createElement("div");
    legend.className = "legend";
    const item = (color, label, n) => {
      const s = document.createElement("span");
      const w = document.createElement("i");
      w.className = "swatch";
      w.style.background = color;
      s.append(w, `${label}: ${n}`);
      legend.append(s);
    };
    item(STATE_COLORS.measured, "measured", counts.measured);
    for (const r of reasons) item(reasonColor(reasons, r), `skipped, ${r}`, counts.skipped[r] || 0);
    if (counts.pending) item(STATE_COLORS.pending, "pending", counts.pending);
    const axes = document.createElement("div");
    axes.className = "muted";
    axes.textContent = `${nl} lights (columns) x ${nv} views (rows); ${cov.note}`;
    el.append(cv, legend, axes);
    el.dataset.measured = String(counts.measured);
    el.dataset.pending = String(counts.pending);
    el.dataset.skipped = JSON.stringify(counts.skipped);
    return counts;
  }

  // One uPlot chart of per-capture series (x: capture number in journal order). `series`:
  // [{label, values}], values may hold null. The element carries the point count. `xaxis`
  // (optional): {label, values} for another x than the capture number.
  function series(el, title, ylabel, rows, series, xaxis) {
    el.textContent = "";
    const x = xaxis ? xaxis.values : rows.map((_, i) => i + 1);
    const colors = ["#1d3557", "#e63946", "#2a9d8f", "#f4a261", "#8d5fd3", "#6c757d"];
    const shown = series.filter((s) => s.values.some((v) => v !== null && v !== undefined));
    el.dataset.points = String(rows.length);
    el.dataset.series = JSON.stringify(shown.map((s) => s.label));
    if (!rows.length || !shown.length) {
      el.textContent = `${title}: no values in this dataset`;
      return null;
    }
    if (typeof uPlot === "undefined") {
      el.textContent = `${title}: the plotting library did not load`;
      return null;
    }
    const opts = {
      title,
      width: Math.min(900, Math.max(420, el.clientWidth || 720)),
      height: 220,
      scales: { x: { time: false } },
      axes: [{ label: xaxis ? xaxis.label : "capture (journal order)" }, { label: ylabel }],
      series: [{ label: xaxis ? xaxis.label : "capture" }].concat(
        shown.map((s, i) => ({ label: s.label, stroke: colors[i % colors.length], width: 1.5,
          points: { show: true, size: 4 } }))),
    };
    return new uPlot(opts, [x].concat(shown.map((s) => s.values.map((v) => (v === undefined ? null : v)))), el);
  }

  function summary(table, data) {
    const r = data.report || {};
    const rows = [
      ["dataset", data.name],
      ["status", r.status ?? "no report yet"],
      ["captures", `${data.coverage.measured} measured, ${Object.values(data.coverage.skipped).reduce((a, b) => a + b, 0)} skipped, ${data.coverage.pending} pending`],
      ["rig time", r.hardware_s != null ? `${r.hardware_s.toFixed(1)} s` : "–"],
      ["wall time", r.wall_s != null ? `${r.wall_s.toFixed(1)} s` : "–"],
      ["texture error", r.texture_rel_rmse != null ? `${r.texture_rel_rmse.toFixed(4)} (relative RMSE against the simulator's truth)` : "–"],
    ];
    table.textContent = "";
    for (const [k, v] of rows) {
      const tr = document.createElement("tr");
      const th = document.createElement("th");
      th.textContent = k;
      const td = document.createElement("td");
      td.textContent = v;
      tr.append(th, td);
      table.append(tr);
    }
  }

  // The report page: every plot of `data` (look::ReportData) into its element.
  function report(doc, data) {
    summary(doc.getElementById("summary"), data);
    coverage(doc.getElementById("coverage"), data.coverage);
    const rows = data.captures;
    series(doc.getElementById("registration"), "Registration", "pixels / texels", rows, [
      { label: "marker RMS reprojection (px)", values: rows.map((c) => c.rms_px) },
      { label: "texel position sigma (texel)", values: rows.map((c) => c.texel_sigma) },
    ]);
    series(doc.getElementById("exposure"), "Exposure", "seconds", rows, [
      { label: "base exposure (s)", values: rows.map((c) => (c.exposures_s ? c.exposures_s[0] : null)) },
      { label: "bracket exposures", values: rows.map((c) => (c.exposures_s ? c.exposures_s.length : null)) },
    ]);
    const stages = [...new Set(rows.flatMap((c) => Object.keys(c.stage_s)))].sort();
    series(doc.getElementById("stages"), "Stage times", "seconds", rows,
      stages.map((s) => ({ label: s, values: rows.map((c) => (c.stage_s[s] ?? null)) })).concat(
        [{ label: "wall (start to commit)", values: rows.map((c) => c.wall_s) }]));
    multiplexGain(doc.getElementById("multiplex-gain"), data.report);
    const me = data.model_errors;
    if (me.Ok) modelErrors(doc.getElementById("compression"), me.Ok[0], me.Ok[1]);
    else doc.getElementById("compression").textContent = `no compression error: ${me.Err}`;
  }

  // The model's relative RMSE per capture (look::capture_errors), in capture order.
  function modelErrors(el, label, errors) {
    return series(el, `Compression error per capture (${label})`, "relative RMSE", errors, [
      { label: `${label}: relative RMSE against the measured texture`, values: errors.map((e) => e.rel_rmse) },
    ]);
  }

  // A dome's or camera array's multiplex gain per view group (report.json's
  // multiplex_gain_per_group, in the order the groups were committed), with the run's
  // predicted gain and the gain measured on its first group against the simulator's truth.
  function multiplexGain(el, report) {
    const groups = (report && report.multiplex_gain_per_group) || [];
    const title = "Multiplex gain per view group";
    if (!groups.length) {
      el.textContent = "";
      el.dataset.points = "0";
      el.textContent = `${title}: none (not a multiplexed dome or camera-array run, or no report yet)`;
      return null;
    }
    const x = { label: "view group (commit order)", values: groups.map((_, i) => i + 1) };
    const measured = report.multiplex_gain_measured;
    return series(el, title, "SNR gain over single light", groups, [
      { label: "predicted after the group's faults", values: groups.map((g) => g.gain) },
      { label: "predicted (run)", values: groups.map(() => report.multiplex_gain_predicted ?? null) },
      { label: "measured, first group (truth)", values: groups.map((_, i) => (i === 0 ? measured ?? null : null)) },
    ], x);
  }

  return { coverage, series, report, modelErrors, multiplexGain };
})();
