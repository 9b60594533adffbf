// /dashboard: the jobs, newest first, filtered server-side by GET /jobs?status=&family=.
"use strict";
(() => {
  const {el, clear, fmt, elapsed, api, getJson, statusBadge, jobPage} = CMRT;
  const PAGE = 50, REFRESH_MS = 3000;
  const params = new URLSearchParams(location.search);
  if (params.get("job")) {  // the old /dashboard?job=ID links open the job page
    location.replace(jobPage(params.get("job")));
    return;
  }
  CMRT.header("jobs");
  const state = {status: params.get("status") || "", family: params.get("family") || "",
                 offset: Math.max(0, parseInt(params.get("offset") || "0", 10) || 0)};
  const statusSel = document.getElementById("status");
  for (const s of CMRT.STATUSES) statusSel.appendChild(el("option", {value: s}, s));
  statusSel.value = state.status;
  document.getElementById("family").value = state.family;
  const families = new Set();
  let timer = null;

  function row(j) {
    return el("tr", {"data-id": j.id},
      el("td", {}, el("a", {href: jobPage(j.id)}, j.name)),
      el("td", {}, j.family), el("td", {}, j.task),
      el("td", {}, statusBadge(j.status)),
      el("td", {class: "num"}, fmt(j.best_objective, 5)),
      el("td", {class: "num"}, j.evaluations),
      el("td", {class: "num"}, j.iterations),
      el("td", {class: "num"}, elapsed(j.started_at, j.finished_at)),
      el("td", {}, (j.created_at || "").replace("T", " ").slice(0, 19)));
  }

  // GET /health's numeric fingerprints: a fleet with more than one is flagged (docs/service.md)
  async function fleet() {
    try {
      const h = await getJson("/health");
      const box = document.getElementById("fleet");
      const fps = h.fingerprints || {};
      box.hidden = !h.mixed;
      box.textContent = h.mixed ? "Mixed numeric fingerprints: " + Object.entries(fps)
        .map(([who, fp]) => who + " " + fp).join(", ") +
        " (candidates evaluated on different ones may differ in their last bits)" : "";
    } catch (e) { /* a degraded /health is shown by the requests that fail */ }
  }

  async function load() {
    fleet();
    const url = api("/jobs", {status: state.status, family: state.family, limit: PAGE,
                              offset: state.offset});
    document.getElementById("source").textContent = "GET " + url;
    try {
      const page = await getJson(url);
      const tbody = clear(document.querySelector("#jobs tbody"));
      for (const j of page.items) {
        tbody.appendChild(row(j));
        if (!families.has(j.family)) {
          families.add(j.family);
          document.getElementById("families").appendChild(el("option", {value: j.family}));
        }
      }
      if (!page.items.length) {
        tbody.appendChild(el("tr", {}, el("td", {colspan: 9, class: "muted"}, "no jobs")));
      }
      document.getElementById("count").textContent = page.total + " jobs";
      document.getElementById("range").textContent = page.items.length
        ? `${page.offset + 1}-${page.offset + page.items.length} of ${page.total}` : "";
      document.getElementById("prev").disabled = page.offset === 0;
      document.getElementById("next").disabled = page.offset + page.items.length >= page.total;
      document.getElementById("error").hidden = true;
      const live = page.items.some(j => !CMRT.TERMINAL.includes(j.status));
      clearTimeout(timer);
      timer = live ? setTimeout(load, REFRESH_MS) : null;
    } catch (e) {
      CMRT.showError("error", e);
    }
  }

  function go() {
    const q = api("/dashboard", {status: state.status, family: state.family,
                                 offset: state.offset || ""});
    history.replaceState(null, "", q);
    load();
  }

  document.getElementById("filters").addEventListener("submit", ev => {
    ev.preventDefault();
    state.status = statusSel.value;
    state.family = document.getElementById("family").value.trim();
    state.offset = 0;
    go();
  });
  document.getElementById("prev").addEventListener("click", () => {
    state.offset = Math.max(0, state.offset - PAGE); go();
  });
  document.getElementById("next").addEventListener("click", () => {
    state.offset += PAGE; go();
  });
  load();
})();
