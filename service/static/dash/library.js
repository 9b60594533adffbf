// /dashboard/library: the CMRT library by family and task parameter (GET /cmrts/families,
// then one family's CMRTs with their curves: GET /cmrts?family=F&curves=true, paged), an interpolation preview (GET /cmrts/interpolate) and
// the family's PCA bases (GET /bases?family=).
"use strict";
(() => {
  const {el, clear, fmt, getJson, api, setText} = CMRT;
  const PAGE = 200, MAX_OVERLAY = 40, DEBOUNCE_MS = 150;
  const params = new URLSearchParams(location.search);
  CMRT.header("library");
  document.getElementById("source").textContent =
    "GET /cmrts/families, /cmrts?family=F&curves=true, /cmrts/interpolate?family=F&KEY=V, /bases?family=F";
  let members = [], details = new Map(), keys = [], interpTimer = null;

  // One family at a time: the library may hold thousands of CMRTs in hundreds of families.
  async function loadFamily(family) {
    const out = [];
    for (let offset = 0; ; offset += PAGE) {
      const page = await getJson(api("/cmrts", {family, curves: true, limit: PAGE, offset}));
      out.push(...page.items);
      if (out.length >= page.total || !page.items.length) return out;
    }
  }

  function paramText(tp) {
    return Object.keys(tp).sort().map(k => `${k}=${fmt(tp[k], 4)}`).join(", ");
  }

  // ---- the family's table -----------------------------------------------------------------
  function table() {
    const head = clear(document.querySelector("#cmrts thead tr"));
    for (const h of [...keys, "objective", "without CMRT", "winner", "fell", "job", "id", ""]) {
      head.appendChild(el("th", {}, h));
    }
    const tbody = clear(document.querySelector("#cmrts tbody"));
    const mark = params.get("cmrt");
    for (const r of members) {
      tbody.appendChild(el("tr", {class: r.id === mark ? "marked" : null, "data-id": r.id},
        ...keys.map(k => el("td", {class: "num"}, fmt(r.task_parameters[k], 4))),
        el("td", {class: "num"}, fmt(r.objective, 5)),
        el("td", {class: "num"}, fmt(r.objective_without, 5)),
        el("td", {}, r.winner), el("td", {}, r.fell ? "fell" : ""),
        el("td", {}, r.job_id ? el("a", {href: CMRT.jobPage(r.job_id)}, "job") : ""),
        el("td", {}, el("a", {href: "/cmrts/" + encodeURIComponent(r.id)}, r.id.slice(0, 8))),
        el("td", {}, CMRT.replayLink("/cmrts/" + encodeURIComponent(r.id) + "/replay",
                                     "replay"))));
    }
  }

  // ---- overlaid curves --------------------------------------------------------------------
  function curveSeries(rec, i, extra) {
    return Object.assign({label: paramText(rec.task_parameters) || rec.id.slice(0, 8),
                          stroke: CMRT.COLOURS[i % CMRT.COLOURS.length], width: 1.5,
                          value: (u, v) => fmt(v, 4)}, extra || {});
  }

  function overlay() {
    const shown = members.slice(0, MAX_OVERLAY).map(r => details.get(r.id)).filter(Boolean);
    const box = document.getElementById("overlay");
    if (!shown.length) {
      clear(box).appendChild(el("p", {class: "muted"}, "no CMRT in this family"));
      return;
    }
    const mark = params.get("cmrt");
    CMRT.plot(box, {
      height: 300,
      scales: {x: {time: false}},
      axes: [{label: "time in the clip (s)"}, {label: "dx (m)", size: 70}],
      series: [{label: "t (s)"}, ...shown.map((d, i) =>
        curveSeries(d, i, d.id === mark ? {width: 3.5} : {}))],
    }, uPlot.join(shown.map(d => [d.curve.t, d.curve.dx])));
    setText("overlay-note", members.length > MAX_OVERLAY
      ? `the first ${MAX_OVERLAY} of ${members.length} (by ${keys[0]})` : "");
  }

  // ---- interpolation ----------------------------------------------------------------------
  function interpForm() {
    const along = clear(document.getElementById("along"));
    // the parameters the family varies most come first, so the preview opens on one it varies
    const varied = [...keys].sort((a, b) => values(b).length - values(a).length ||
                                           keys.indexOf(a) - keys.indexOf(b));
    for (const k of varied) along.appendChild(el("option", {value: k}, k));
    along.value = varied[0];
    along.onchange = () => { fixedInputs(); preview(); };
    fixedInputs();
  }

  function values(k) {
    return [...new Set(members.map(r => r.task_parameters[k]).filter(v => v !== undefined))]
      .sort((a, b) => a - b);
  }

  function fixedInputs() {
    const along = document.getElementById("along").value;
    const fixed = clear(document.getElementById("fixed"));
    for (const k of keys.filter(k => k !== along)) {
      const sel = el("select", {"data-key": k, onchange: preview});
      for (const v of values(k)) sel.appendChild(el("option", {value: v}, fmt(v, 6)));
      fixed.appendChild(el("label", {}, k + " ", sel));
    }
    const vs = values(along);
    const at = document.getElementById("at"), range = document.getElementById("at-range");
    if (vs.length) {
      const lo = vs[0], hi = vs[vs.length - 1], pad = (hi - lo) * 0.25 || Math.abs(lo) * 0.25 || 1;
      range.min = lo - pad; range.max = hi + pad;
      range.step = (hi - lo + 2 * pad) / 200;
      at.value = vs.length > 1 ? fmt((vs[0] + vs[1]) / 2, 6) : fmt(lo, 6);
      range.value = at.value;
    }
  }

  function schedule() { clearTimeout(interpTimer); interpTimer = setTimeout(preview, DEBOUNCE_MS); }

  // What the answer is: its source and members, the neighbours' switch check, and once
  // verified its simulated outcome and verdict (never a falling answer shown as good).
  function answerText(out) {
    const parts = [`source: ${out.source} (${out.members.length} member${out.members.length > 1 ? "s" : ""})`];
    if (out.switch) {
      parts.push(out.switch.detected
        ? `strategy switch between the neighbours (${fmt(out.switch.distance, 3)} apart): not averaged`
        : `one strategy (neighbours ${fmt(out.switch.distance, 3)} apart)`);
    }
    if (out.outcome) {
      const o = out.outcome;
      parts.push(`verdict: ${out.verdict.toUpperCase()} — objective ${fmt(o.objective, 4)}, ` +
                 (o.fell ? `falls ${o.fall_direction || ""}` : "stands") +
                 (o.task_success === false ? ", task failed" : o.task_success ? ", task done" : "") +
                 (o.cached ? " (kept by the library)" : " (simulated now)"));
    } else {
      parts.push("not simulated (verify simulates it once)");
    }
    return parts.join("  ·  ") + "  —  " + out.message;
  }

  async function preview(verify) {
    const family = document.getElementById("family").value;
    const along = document.getElementById("along").value;
    const at = document.getElementById("at").value;
    const note = document.getElementById("interp-note");
    if (!family || !along || at === "") return;
    if (values(along).length < 2) {  // the endpoint would answer 422: say why instead
      note.textContent = `interpolation needs two CMRTs of this family with different ${along}`;
      clear(document.getElementById("interp-plot"));
      return;
    }
    const vs = values(along), extrapolate = document.getElementById("extrapolate").checked;
    if (!extrapolate && (+at < vs[0] || +at > vs[vs.length - 1])) {  // the endpoint's 422
      note.textContent = `${along} = ${at} is outside the library's ${fmt(vs[0], 4)} .. ` +
                         `${fmt(vs[vs.length - 1], 4)}: tick "extrapolate" to go beyond`;
      clear(document.getElementById("interp-plot"));
      return;
    }
    const q = {family, [along]: at, along,
               extrapolate: document.getElementById("extrapolate").checked ? "true" : "",
               verify: verify === true ? "true" : ""};
    const said = document.getElementById("interp-answer");
    said.textContent = verify === true ? "simulating the answer…" : "";
    said.dataset.verdict = "";
    for (const sel of document.querySelectorAll("#fixed select")) q[sel.dataset.key] = sel.value;
    const url = api("/cmrts/interpolate", q);
    const box = document.getElementById("interp-plot");
    try {
      const out = await getJson(url);
      const ns = out.neighbours.map(n => details.get(n.id)).filter(Boolean);
      note.textContent = `${along} = ${fmt(out.value, 5)}: ` + (out.exact ? "a stored CMRT"
        : `weight ${fmt(out.weight, 3)} between ` +
          out.neighbours.map(n => `${along} = ${fmt(n[along], 5)}`).join(" and ")) +
        (out.extrapolated ? " (extrapolated)" : "") + `  —  GET ${url}`;
      said.textContent = answerText(out);
      said.dataset.verdict = out.verdict;
      said.className = "small" + (["falls", "fails_task", "failed"].includes(out.verdict) ? " error" : "");
      CMRT.plot(box, {
        height: 280,
        scales: {x: {time: false}, y: {range: CMRT.minSpan(0.1)}},
        axes: [{label: "time in the clip (s)"}, {label: "dx (m)", size: 70}],
        series: [{label: "t (s)"},
          {label: `interpolated, ${along}=${fmt(out.value, 4)}`, stroke: "#d62728", width: 3,
           value: (u, v) => fmt(v, 4)},
          ...ns.map((d, i) => curveSeries(d, i, {dash: [6, 4],
            label: "neighbour " + paramText(d.task_parameters)}))],
      }, uPlot.join([[out.curve.t, out.curve.dx], ...ns.map(d => [d.curve.t, d.curve.dx])]));
    } catch (e) {
      note.textContent = "no preview: " + e.message;
      // the answer line says the request failed instead of "simulating…" forever
      said.textContent = "no answer: " + e.message;
      said.dataset.verdict = "error";
      said.className = "small error";
      clear(box);
    }
  }

  // ---- PCA bases --------------------------------------------------------------------------
  async function bases(family) {
    const box = clear(document.getElementById("bases"));
    const page = await getJson(api("/bases", {family, limit: 20}));
    if (!page.items.length) {
      box.appendChild(el("p", {class: "muted"},
        "no basis for this family yet (POST /bases {\"family\": ..., \"k\": 3} builds one)"));
      return;
    }
    const byId = new Map(members.map(r => [r.id, r]));
    for (const b of page.items) {
      let cum = 0;
      const rows = b.variance_explained.slice(0, Math.max(b.k, 1) + 2).map((v, i) => {
        cum += v;
        const bar = el("span", {class: "bar" + (i < b.k ? " used" : "")});
        bar.style.width = Math.round(v * 200) + "px";  // CSSOM, allowed by the page's CSP
        return el("tr", {},
          el("td", {class: "num"}, "PC" + (i + 1) + (i < b.k ? "" : " (unused)")),
          el("td", {class: "num"}, (100 * v).toFixed(1) + " %"),
          el("td", {class: "num"}, (100 * cum).toFixed(1) + " %"), el("td", {}, bar));
      });
      const mem = el("ul", {class: "members"}, ...b.members.map(id => {
        const r = byId.get(id);
        return el("li", {}, el("a", {href: "/cmrts/" + encodeURIComponent(id)},
                               r ? paramText(r.task_parameters) : id));
      }));
      box.appendChild(el("div", {class: "basis", "data-id": b.id},
        el("h3", {}, `basis ${b.id.slice(0, 8)}: k = ${b.k}, ${b.members.length} members`),
        el("table", {class: "grid"},
          el("thead", {}, el("tr", {}, el("th", {}, "component"), el("th", {}, "variance"),
                              el("th", {}, "cumulative"), el("th", {}, ""))),
          el("tbody", {}, ...rows)),
        el("p", {class: "small"}, "members (library CMRTs): "), mem));
    }
  }

  // ---- family selection -------------------------------------------------------------------
  async function showFamily(family) {
    members = await loadFamily(family);
    for (const d of members) details.set(d.id, d);
    keys = [...new Set(members.flatMap(r => Object.keys(r.task_parameters)))].sort();
    const k0 = keys[0];
    members.sort((a, b) => (a.task_parameters[k0] ?? 0) - (b.task_parameters[k0] ?? 0));
    history.replaceState(null, "", api("/dashboard/library",
                                       {family, cmrt: params.get("cmrt") || ""}));
    table();
    overlay();
    interpForm();
    await preview();
    await bases(family);
    document.body.setAttribute("data-state", "loaded");
  }

  async function main() {
    try {
      const lib = (await getJson(api("/cmrts/families", {}))).items;
      const fams = lib.map(f => f.family);
      const count = lib.reduce((n, f) => n + f.count, 0);
      setText("lib-count", `${count} CMRTs in ${fams.length} families`);
      const sel = document.getElementById("family");
      for (const f of fams) sel.appendChild(el("option", {value: f}, f));
      if (!fams.length) {
        document.body.setAttribute("data-state", "loaded");
        return;
      }
      sel.value = fams.includes(params.get("family")) ? params.get("family") : fams[0];
      sel.addEventListener("change", () => { params.delete("cmrt"); run(sel.value); });
      document.getElementById("at").addEventListener("input", () => {
        document.getElementById("at-range").value = document.getElementById("at").value;
        schedule();
      });
      document.getElementById("at-range").addEventListener("input", () => {
        document.getElementById("at").value = fmt(Number(document.getElementById("at-range").value), 4);
        schedule();
      });
      document.getElementById("extrapolate").addEventListener("change", preview);
      document.getElementById("verify").addEventListener("click", () => preview(true));
      document.getElementById("interp").addEventListener("submit", ev => { ev.preventDefault(); preview(); });
      await run(sel.value);
    } catch (e) {
      CMRT.showError("error", e);
    }
  }

  async function run(family) {
    try { await showFamily(family); } catch (e) { CMRT.showError("error", e); }
  }
  main();
})();
