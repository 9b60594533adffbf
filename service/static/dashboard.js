// Script of /dashboard (served from the project: the page's CSP allows 'self' only).
"use strict";
const W = 760, H = 360, M = {l: 60, r: 15, t: 15, b: 35};
let rows = [], after = -1, timer = null, jobId = null;
const TOKEN_KEY = "cmrt-api-token";

// The API token (only needed when the service sets CMRT_API_TOKEN and closes reads): kept in
// this tab's sessionStorage, sent as a bearer header, never put in a URL.
function headers() {
  const t = sessionStorage.getItem(TOKEN_KEY);
  return t ? {Authorization: "Bearer " + t} : {};
}

async function getJson(url) {
  const r = await fetch(url, {headers: headers()});
  const body = await r.json();
  if (!r.ok) throw new Error(r.status + " " + (body.detail || ""));
  return body;
}
const NS = "http://www.w3.org/2000/svg";

function el(name, attrs, text) {
  const e = document.createElementNS(NS, name);
  for (const k in attrs) e.setAttribute(k, attrs[k]);
  if (text !== undefined) e.textContent = text;
  return e;
}

function draw() {
  const svg = document.getElementById("plot");
  while (svg.firstChild) svg.removeChild(svg.firstChild);
  if (!rows.length) return;
  const xs = rows.map(r => r.iteration);
  const ys = rows.flatMap(r => [r.best, r.median]).filter(v => Number.isFinite(v));
  const x0 = Math.min(...xs), x1 = Math.max(...xs, x0 + 1);
  let y0 = Math.min(...ys), y1 = Math.max(...ys);
  if (y1 - y0 < 1e-12) { y0 -= 0.5; y1 += 0.5; }
  const X = x => M.l + (x - x0) / (x1 - x0) * (W - M.l - M.r);
  const Y = y => H - M.b - (y - y0) / (y1 - y0) * (H - M.t - M.b);
  svg.appendChild(el("line", {x1: M.l, y1: H - M.b, x2: W - M.r, y2: H - M.b, class: "axis"}));
  svg.appendChild(el("line", {x1: M.l, y1: M.t, x2: M.l, y2: H - M.b, class: "axis"}));
  for (let i = 0; i <= 4; i++) {
    const v = y0 + (y1 - y0) * i / 4;
    svg.appendChild(el("text", {x: 4, y: Y(v) + 4, class: "lbl"}, v.toPrecision(4)));
  }
  svg.appendChild(el("text", {x: M.l, y: H - 10, class: "lbl"}, "generation " + x0));
  svg.appendChild(el("text", {x: W - M.r - 90, y: H - 10, class: "lbl"}, "generation " + x1));
  for (const [key, cls] of [["best", "best"], ["median", "median"]]) {
    const pts = rows.filter(r => Number.isFinite(r[key])).map(r => X(r.iteration) + "," + Y(r[key]));
    svg.appendChild(el("polyline", {points: pts.join(" "), class: cls}));
  }
}

function fmt(v) { return (v === null || v === undefined) ? "" : Number(v).toPrecision(5); }

async function poll() {
  if (!jobId) return;
  try {
    const job = await getJson("/jobs/" + encodeURIComponent(jobId));
    const page = await getJson("/jobs/" + encodeURIComponent(jobId) + "/generations?after=" + after);
    const tbody = document.querySelector("#tbl tbody");
    for (const g of page.generations || []) {
      rows.push(g); after = Math.max(after, g.iteration);
      const tr = document.createElement("tr");
      for (const v of [g.iteration, g.evaluations, fmt(g.best), fmt(g.median), fmt(g.sigma), fmt(g.best_so_far)]) {
        const td = document.createElement("td"); td.textContent = v; tr.appendChild(td);
      }
      tbody.appendChild(tr);
    }
    document.getElementById("meta").textContent =
      `job ${jobId}: ${job.status || "?"} (${job.name || ""}, family ${job.family || ""})` +
      (job.error ? " error: " + job.error : "") + ` — ${rows.length} generations`;
    draw();
    if (["converged", "stopped", "failed", "cancelled"].includes(job.status)) { clearInterval(timer); timer = null; }
  } catch (e) {
    document.getElementById("meta").textContent = "polling failed: " + e;
  }
}

function watch(id) {
  jobId = id; rows = []; after = -1;
  document.querySelector("#tbl tbody").innerHTML = "";
  if (timer) clearInterval(timer);
  poll(); timer = setInterval(poll, 1000);
}

document.getElementById("go").addEventListener("click",
  () => watch(document.getElementById("job").value.trim()));
document.getElementById("token").addEventListener("change", e => {
  const t = e.target.value.trim();
  if (t) sessionStorage.setItem(TOKEN_KEY, t); else sessionStorage.removeItem(TOKEN_KEY);
  e.target.value = "";
  e.target.placeholder = t ? "(token set)" : "";
});
const q = new URLSearchParams(location.search).get("job");
if (q) { document.getElementById("job").value = q; watch(q); }
