// /dashboard/families/{id}: one family (GET /families/{id}?curves=true, polled while it runs):
// progress, the members, every run's convergence overlaid, and once done the checks (Table 2
// rows, interpolation probes, strategy switches) beside the paper's Table 2.
"use strict";
(() => {
  const {el, clear, fmt, getJson, api, setText, statusBadge} = CMRT;
  const POLL_MS = 2000;
  const id = decodeURIComponent(location.pathname.split("/").pop());
  const url = api("/families/" + encodeURIComponent(id), {curves: true});
  CMRT.header("jobs");
  document.getElementById("source").textContent = "GET " + url;

  function fill(tableId, heads, rows) {
    const head = clear(document.querySelector(`#${tableId} thead tr`));
    for (const h of heads) head.appendChild(el("th", {}, h));
    const body = clear(document.querySelector(`#${tableId} tbody`));
    for (const cells of rows) {
      body.appendChild(el("tr", {}, ...cells.map(c => c instanceof Node ? el("td", {}, c)
        : el("td", {class: typeof c === "number" ? "num" : null}, c === null || c === undefined
          ? "-" : (typeof c === "number" ? fmt(c, 4) : String(c))))));
    }
  }

  const pct = v => v === null || v === undefined ? "-" : (100 * v).toFixed(1) + " %";
  const times = v => v === null || v === undefined ? "-" : v.toFixed(2) + "x";

  function render(f) {
    const leaf = f.param.split(".").pop();
    setText("title", `${f.family} along ${f.param}`);
    clear(document.getElementById("summary")).append(statusBadge(f.status),
      ` ${f.strategy}${f.spec.strategy === "continuation" ? " from " + f.spec.from : ""}, ` +
      `${f.values.length} values, leave-out ${f.spec.leave_out.join(", ") || "none"}, ` +
      `k = ${f.spec.k}, seed ${f.spec.seed}` + (f.error ? ` — ${f.error}` : ""));
    const p = f.progress;
    const bar = document.getElementById("progress");
    bar.max = p.runs; bar.value = p.done;
    setText("progress-note", `${p.done} of ${p.runs} runs done, ${p.running} running, ` +
                             `${p.queued} queued, ${p.not_started} waiting for their start`);
    const checks = f.checks;
    const byValue = new Map((checks ? checks.members : []).map(m => [m.value, m]));
    fill("members", [leaf, "objective", "no CMRT", "fell", "task success", "evaluations",
                     "reconstruction error", "distance from the previous", "switch", "run"],
      (f.members || []).map(m => {
        const c = byValue.get(m.value) || {};
        return [m.value, m.objective, m.baseline_objective, m.fell ? "fell" : "",
                m.task_success === null ? "-" : String(m.task_success), m.evaluations,
                c.reconstruction_error, c.distance, c.switch ? "SWITCH from the previous" : "",
                m.run];
      }));
    const runs = f.runs.filter(r => r.curve && r.curve.length);
    if (runs.length) {
      const xs = [...new Set(runs.flatMap(r => r.curve.map(c => c[0])))].sort((a, b) => a - b);
      const data = [xs, ...runs.map(r => {
        const m = new Map(r.curve.map(c => [c[0], c[1]]));
        return xs.map(x => m.has(x) ? m.get(x) : null);
      })];
      CMRT.plot(document.getElementById("curves"), {
        height: 300, scales: {x: {time: false}},
        axes: [{label: "evaluations"}, {label: "best objective so far", size: 70}],
        series: [{label: "evaluations"}, ...runs.map((r, i) => ({
          label: r.id, stroke: CMRT.COLOURS[i % CMRT.COLOURS.length], width: 1.5,
          spanGaps: true, value: (u, v) => fmt(v, 4)}))],
      }, data);
    }
    fill("table2", [leaf, "member", "reference", "reduced", "relative error",
                    "cold evals to conv.", "reduced evals to conv.", "speed-up (conv.)",
                    "speed-up (to full objective)", "reduced start"],
      (checks ? checks.rows : []).map(r => [r.value, r.member_objective, r.reference_objective,
        r.reduced_objective, pct(r.relative_error), r.cold_converged_at,
        r.reduced_converged_at, times(r.speedup_converged), times(r.speedup_to_full),
        r.reduced_start]));
    if (checks) {
      const m = checks.medians;
      setText("table2-note", `worst relative error ${pct(m.worst_relative_error)}; median ` +
        `speed-up to convergence ${times(m.speedup_converged)}, to the full-space objective ` +
        `${times(m.speedup_to_full)}` + (checks.switches.length
          ? `; strategy switches (CMRTs more than ${checks.switch_threshold} apart) just below ` +
            `${checks.switches.join(", ")}` : ""));
    } else {
      setText("table2-note", "computed when every run has finished");
    }
    const paper = f.paper_table2;
    fill("paper", [leaf, "itr reduced", "fv reduced", "itr full", "fv full", "speed-up",
                   "relative error"],
      (paper || []).map(r => [r.value, r.itr_r, r.fv_r, r.itr_u, r.fv_u, times(r.speedup),
                              r.relative_error_pct.toFixed(1) + " %"]));
    setText("paper-note", paper ? "Anticipatory Balance Control (CAVW 2016), Table 2: the domino"
      : "the paper gives Table 2 for the domino's wall mass only");
    fill("probes", [leaf, "between", "interpolated", "member", "difference", "fell",
                    "task success"],
      (checks ? checks.probes : []).map(q => [q.value, `${q.lower} - ${q.upper}`, q.objective,
        q.member_objective, pct(q.excess), q.fell ? "fell" : "",
        q.task_success === null ? "-" : String(q.task_success)]));
    fill("runs", ["run", "kind", leaf, "from", "status", "best", "evaluations", "job"],
      f.runs.map(r => [r.id, r.kind, r.value, r.start || r.warm_from || "flat",
        statusBadge(r.status), r.best_objective, r.evaluations,
        r.job_id ? el("a", {href: CMRT.jobPage(r.job_id)}, r.job_id.slice(0, 8)) : "-"]));
  }

  async function poll() {
    try {
      const f = await getJson(url);
      render(f);
      document.body.setAttribute("data-state", "loaded");
      if (f.status === "running") setTimeout(poll, POLL_MS);
    } catch (e) {
      CMRT.showError("error", e);
      document.body.setAttribute("data-state", "loaded");
    }
  }
  poll();
})();
