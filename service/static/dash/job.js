// /dashboard/jobs/{id}: one job, updated live. Each poll fetches only what is new:
// generations after the last one shown (?after=), evaluation counts from the oldest
// generation that still had pending candidates (?after=), the best curve only when the best
// objective changed. Polling stops once the job is finished.
"use strict";
(() => {
  const {el, clear, fmt, elapsed, getJson, setText} = CMRT;
  const POLL_MS = 1000, EVAL_ROWS = 12;
  const jobId = decodeURIComponent(location.pathname.replace(/^\/dashboard\/jobs\//, ""));
  const base = "/jobs/" + encodeURIComponent(jobId);
  CMRT.header("jobs");
  document.getElementById("source").textContent =
    `GET ${base}, ${base}/generations?after=N, ${base}/evaluations?after=N, ${base}/best`;

  const g = {it: [], best: [], median: [], worst: [], bsf: [], sigma: []};
  let lastGen = -1, evalAfter = -1, bestKey = null, job = null, clip = null;
  const evals = new Map();
  let conv = null, sig = null, bestPlot = null, evalPlot = null, timer = null;

  // ---- summary --------------------------------------------------------------------------
  function summary(j) {
    const dl = clear(document.getElementById("summary"));
    const items = [["family", j.family], ["task", j.task], ["seed", j.seed],
      ["evaluations", j.evaluations], ["generations", j.iterations],
      ["best objective", fmt(j.best_objective, 6)],
      ["elapsed", elapsed(j.started_at, j.finished_at)],
      ["stopping rule", j.stop_rule || (CMRT.TERMINAL.includes(j.status) ? "" : "(running)")],
      ["basis", j.basis_id], ["error", j.error],
      ["fingerprints", (j.fingerprints || []).length > 1
        ? j.fingerprints.join(", ") + " (mixed: evaluated by workers whose bits differ)"
        : (j.fingerprints || []).join(", ")]];
    for (const [k, v] of items) {
      if (v === null || v === undefined || v === "") continue;
      dl.appendChild(el("div", {}, el("dt", {}, k), el("dd", {class: "v-" + k.replace(/ /g, "-")}, v)));
    }
    setText("title", j.name);
    setText("spec", JSON.stringify(j.spec, null, 2));
    document.title = "CMRT job " + j.name;
    clear(document.getElementById("badge")).appendChild(CMRT.statusBadge(j.status));
    const links = clear(document.getElementById("links"));
    links.appendChild(CMRT.replayLink(base + "/replay",
                                      "Replay the best candidate (with and without anticipation)",
                                      {id: "replay-link"}));
    if (j.best_objective !== null && j.best_objective !== undefined) {
      // The best candidate's motion as files (docs/export.md), signed like the replay link.
      links.appendChild(CMRT.replayLink(base + "/motion.bvh", "Motion (BVH)",
                                        {id: "motion-bvh"}));
      links.appendChild(CMRT.replayLink(base + "/motion.csv", "Motion (CSV)",
                                        {id: "motion-csv"}));
    }
    links.appendChild(el("a", {href: base}, "job JSON"));
    if (j.cmrt_id) {
      links.appendChild(el("a", {href: "/dashboard/library?" + new URLSearchParams(
        {family: j.family, cmrt: j.cmrt_id})}, "its library CMRT"));
    }
    if (!CMRT.TERMINAL.includes(j.status) && !j.cancel_requested) {
      links.appendChild(el("button", {type: "button", id: "cancel", onclick: cancel}, "Cancel"));
    }
  }

  async function cancel() {
    try {
      await getJson(base + "/cancel", {method: "POST", headers: CMRT.headers()});
      poll();
    } catch (e) { CMRT.showError("error", e); }
  }

  // ---- convergence ------------------------------------------------------------------------
  function positive() {
    return [g.best, g.median, g.worst].every(a => a.every(v => v > 0));
  }

  function makeConv() {
    const log = document.getElementById("logy").checked && positive();
    const s = (label, stroke, extra) => Object.assign({label, stroke, width: 2,
                                                       value: (u, v) => fmt(v, 5)}, extra);
    conv = CMRT.plot(document.getElementById("conv"), {
      legendLatest: true,
      scales: {x: {time: false}, y: log ? {distr: 3, log: 10} : {}},
      axes: [{label: "generation"}, {label: "objective" + (log ? " (log)" : ""), size: 70}],
      series: [{label: "generation"},
               s("best", "#1f77b4"), s("median", "#ff7f0e"),
               s("worst", "#d62728", {width: 1}), s("best so far", "#2ca02c", {dash: [6, 4]})],
    }, [g.it, g.best, g.median, g.worst, g.bsf]);
    sig = CMRT.plot(document.getElementById("sigma"), {
      legendLatest: true,
      height: 160,
      scales: {x: {time: false}, y: g.sigma.every(v => v > 0) ? {distr: 3, log: 10} : {}},
      axes: [{label: "generation"}, {label: "sigma", size: 70}],
      series: [{label: "generation"}, {label: "sigma", stroke: "#9467bd", width: 2,
                                       value: (u, v) => fmt(v, 4)}],
    }, [g.it, g.sigma]);
  }

  function drawConv() {
    const box = document.getElementById("conv");
    box.setAttribute("data-generations", String(g.it.length));
    setText("gen-count", g.it.length + " generations" +
            (job && !CMRT.TERMINAL.includes(job.status) ? " (live: polling every second)" : ""));
    const logWanted = document.getElementById("logy").checked && positive();
    const logNow = conv && conv.scales.y.distr === 3;
    if (!conv || logWanted !== logNow) makeConv();
    else {
      conv.setData([g.it, g.best, g.median, g.worst, g.bsf]);
      sig.setData([g.it, g.sigma]);
    }
  }

  function addGenerations(list) {
    const tbody = document.querySelector("#gens tbody");
    for (const r of list) {
      g.it.push(r.iteration); g.best.push(r.best); g.median.push(r.median);
      g.worst.push(r.worst); g.bsf.push(r.best_so_far); g.sigma.push(r.sigma);
      lastGen = Math.max(lastGen, r.iteration);
      tbody.appendChild(el("tr", {},
        ...[r.iteration, r.evaluations, fmt(r.best, 5), fmt(r.median, 5), fmt(r.worst, 5),
            fmt(r.sigma, 4), fmt(r.best_so_far, 5), fmt(r.wall_time, 3)]
          .map(v => el("td", {class: "num"}, v))));
    }
  }

  // ---- evaluations ------------------------------------------------------------------------
  function drawEvals() {
    const rows = [...evals.values()].sort((a, b) =>
      (b.generation === -1 ? Infinity : b.generation) - (a.generation === -1 ? Infinity : a.generation));
    const tot = {population: 0, done: 0, pending: 0, failed: 0, attempts: 0, repeated: 0};
    for (const r of rows) for (const k in tot) tot[k] += r[k];
    setText("eval-totals", `${tot.population} evaluations: ${tot.done} done, ${tot.pending} ` +
      `pending, ${tot.failed} failed; ${tot.attempts} attempts, ${tot.repeated} repeated`);
    drawEvalBars();
    const tbody = clear(document.querySelector("#evals tbody"));
    for (const r of rows.slice(0, EVAL_ROWS)) {
      tbody.appendChild(el("tr", {class: r.pending ? "pending" : (r.failed ? "failed" : null)},
        el("td", {class: "num"}, r.generation === -1 ? "final" : r.generation),
        ...["population", "done", "pending", "failed", "attempts", "repeated"]
          .map(k => el("td", {class: "num"}, r[k]))));
    }
    // the next poll starts after the newest generation below which nothing is pending
    let after = -1;
    for (const r of [...evals.values()].filter(r => r.generation >= 0)
      .sort((a, b) => a.generation - b.generation)) {
      if (r.pending) break;
      after = r.generation;
    }
    evalAfter = after;
  }

  // Done / failed / pending per generation as stacked bars (each series is drawn over the
  // previous one, so the totals go first; the legend shows each state's own count).
  function drawEvalBars() {
    const rows = [...evals.values()].filter(r => r.generation >= 0)
      .sort((a, b) => a.generation - b.generation);
    const x = rows.map(r => r.generation);
    const own = {pending: rows.map(r => r.pending), failed: rows.map(r => r.failed),
                 done: rows.map(r => r.done), repeated: rows.map(r => r.repeated)};
    const data = [x, rows.map(r => r.done + r.failed + r.pending),
                  rows.map(r => r.done + r.failed), own.done];
    const bars = uPlot.paths.bars({size: [0.8, 30]});
    const s = (label, key, fill) => ({label, fill, stroke: fill, width: 0, paths: bars,
                                      points: {show: false},
                                      value: (u, v, si, i) => i === null ? "" : own[key][i]});
    const box = document.getElementById("eval-plot");
    if (evalPlot && evalPlot.series.length === 4) {
      evalPlot.setData(data);
    } else {
      evalPlot = CMRT.plot(box, {
        legendLatest: true,
        height: 150,
        scales: {x: {time: false}, y: {range: (u, lo, hi) => [0, Math.max(1, hi || 0)]}},
        axes: [{label: "generation"}, {label: "evaluations", size: 70}],
        series: [{label: "generation"}, s("pending", "pending", "#93c5fd"),
                 s("failed", "failed", "#ef4444"), s("done", "done", "#86c98f")],
      }, data);
    }
  }

  // ---- best curve -------------------------------------------------------------------------
  function drawBest(b) {
    const box = document.getElementById("best");
    if (!b.curve) {
      clear(box).appendChild(el("p", {class: "muted"}, "no generation recorded yet"));
      bestPlot = null;
      return;
    }
    setText("best-note", `objective ${fmt(b.best_objective, 6)} after ${b.iterations} ` +
                         "generations (dx: horizontal displacement of the CM reference)");
    const series = [{label: "t (s)"},
      {label: "dx (m)", stroke: "#1f77b4", width: 2, value: (u, v) => fmt(v, 4)},
      {label: "knots", stroke: "#1f77b4", width: 0, paths: () => null,
       points: {show: true, size: 8, fill: "#1f77b4"}, value: (u, v) => fmt(v, 4)}];
    const parts = [[b.curve.t, b.curve.dx], [b.knot_times, b.values]];
    if (b.curve.dy) {
      series.push({label: "dy (m)", stroke: "#ff7f0e", width: 2, value: (u, v) => fmt(v, 4)});
      parts.push([b.curve.t, b.curve.dy]);
    }
    const data = uPlot.join(parts);
    bestPlot = CMRT.plot(box, {
      scales: {x: {time: false}, y: {range: CMRT.minSpan(0.1)}},
      axes: [{label: "time in the clip (s)"}, {label: "CMRT (m)", size: 70}],
      series,
      hooks: {drawClear: [u => shadeTask(u)]},
    }, data);
  }

  // The task window (preparation .. preparation + duration) shaded, as in the paper's plots.
  function shadeTask(u) {
    if (!clip) return;
    const x0 = u.valToPos(clip.preparation, "x", true);
    const x1 = u.valToPos(clip.preparation + clip.duration, "x", true);
    const {top, height} = u.bbox;
    u.ctx.save();
    u.ctx.fillStyle = "rgba(120, 120, 120, 0.12)";
    u.ctx.fillRect(x0, top, x1 - x0, height);
    u.ctx.restore();
  }

  // ---- polling ----------------------------------------------------------------------------
  async function poll() {
    clearTimeout(timer);
    if (bestKey === null) performance.mark("cmrt-poll");
    try {
      // the four reads at once (the best curve too on the first poll), then the drawing
      const [j, gp, ep, first] = await Promise.all([
        getJson(base), getJson(`${base}/generations?after=${lastGen}`),
        getJson(`${base}/evaluations?after=${evalAfter}`),
        bestKey === null ? getJson(base + "/best") : Promise.resolve(null)]);
      if (bestKey === null) performance.mark("cmrt-fetched");  // the first poll's reads
      job = j;
      clip = job.spec && job.spec.clip ? job.spec.clip : null;
      summary(job);
      if (gp.generations.length || !conv) {
        addGenerations(gp.generations);
        drawConv();
      }
      for (const r of ep.generations) evals.set(r.generation, r);
      drawEvals();
      const key = `${job.best_objective}|${job.cmrt_id}`;
      if (first && first.best_objective === job.best_objective) {
        drawBest(first);
        bestKey = key;
      } else if (key !== bestKey) {
        drawBest(await getJson(base + "/best"));
        bestKey = key;
      }
      document.getElementById("error").hidden = true;
      const done = CMRT.TERMINAL.includes(job.status);
      document.body.setAttribute("data-state", done ? "finished" : "live");
      if (!document.body.hasAttribute("data-rendered-ms")) {  // first full draw, ms since navigation
        document.body.setAttribute("data-rendered-ms", performance.now().toFixed(1));
      }
      if (!done) timer = setTimeout(poll, POLL_MS);
    } catch (e) {
      CMRT.showError("error", e.status === 404 ? `no job ${jobId}` : e);
      if (e.status !== 404) timer = setTimeout(poll, POLL_MS * 3);
    }
  }

  document.getElementById("logy").addEventListener("change", () => { makeConv(); });
  poll();
})();
