// Shared code of the dashboard pages (/dashboard, /dashboard/jobs/{id}, /dashboard/library).
// Served from the project (the pages' CSP allows 'self' only: no inline script, no CDN).
// Every piece of server data reaches the DOM through textContent or setAttribute on
// attributes that cannot run code (never parsed as markup), so a job named <script>...</script>
// is shown as text.
"use strict";

const CMRT = (() => {
  const TOKEN_KEY = "cmrt-api-token";
  const TERMINAL = ["converged", "stopped", "failed", "cancelled"];
  const STATUSES = ["queued", "running", ...TERMINAL];

  // The API token (only needed when the service sets CMRT_API_TOKEN and closes reads): kept
  // in this tab's sessionStorage, sent as a bearer header, never put in a URL.
  function headers(extra) {
    const t = sessionStorage.getItem(TOKEN_KEY);
    return Object.assign(t ? {Authorization: "Bearer " + t} : {}, extra || {});
  }

  class HttpError extends Error {
    constructor(status, detail) { super(status + " " + detail); this.status = status; }
  }

  async function getJson(url, init) {
    const r = await fetch(url, Object.assign({headers: headers()}, init || {}));
    let body = null;
    try { body = await r.json(); } catch (e) { body = null; }
    if (!r.ok) throw new HttpError(r.status, (body && body.detail) || r.statusText);
    return body;
  }

  // el("td", {class: "num"}, "text", child...): an element; strings become text nodes.
  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined || v === false) continue;
      if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
      else e.setAttribute(k, v === true ? "" : String(v));
    }
    for (const c of children) {
      if (c === null || c === undefined) continue;
      e.appendChild(typeof c === "object" ? c : document.createTextNode(String(c)));
    }
    return e;
  }

  function clear(node) { while (node.firstChild) node.removeChild(node.firstChild); return node; }

  function setText(id, text) { document.getElementById(id).textContent = text; }

  function fmt(v, digits) {
    if (v === null || v === undefined || Number.isNaN(v)) return "";
    if (typeof v !== "number") return String(v);
    if (!Number.isFinite(v)) return v > 0 ? "inf" : "-inf";
    return Number(v.toPrecision(digits || 4)).toString();
  }

  // Seconds from `start` to `end` (ISO strings; end missing: now), "" if not started.
  function elapsed(start, end) {
    if (!start) return "";
    const s = ((end ? Date.parse(end) : Date.now()) - Date.parse(start)) / 1000;
    if (!Number.isFinite(s)) return "";
    if (s < 60) return s.toFixed(1) + " s";
    if (s < 3600) return Math.floor(s / 60) + " min " + Math.round(s % 60) + " s";
    return Math.floor(s / 3600) + " h " + Math.round((s % 3600) / 60) + " min";
  }

  function jobPage(id) { return "/dashboard/jobs/" + encodeURIComponent(id); }
  function api(path, query) {
    const q = new URLSearchParams();
    for (const [k, v] of Object.entries(query || {})) {
      if (v !== null && v !== undefined && v !== "") q.set(k, v);
    }
    const s = q.toString();
    return path + (s ? "?" + s : "");
  }

  function statusBadge(status) {
    return el("span", {class: "status st-" + (STATUSES.includes(status) ? status : "other")},
              status);
  }

  // The navigation bar and the token field, at the top of every page.
  function header(current) {
    const nav = document.getElementById("nav");
    const links = [["jobs", "/dashboard", "Jobs"], ["library", "/dashboard/library", "Library"],
                   ["api", "/docs", "API"]];
    nav.appendChild(el("strong", {}, "CMRT"));
    for (const [key, href, text] of links) {
      nav.appendChild(el("a", {href, class: key === current ? "current" : null}, text));
    }
    const input = el("input", {type: "password", size: 16, autocomplete: "off", id: "token",
                               placeholder: sessionStorage.getItem(TOKEN_KEY) ? "(token set)" : ""});
    input.addEventListener("change", () => {
      const t = input.value.trim();
      if (t) sessionStorage.setItem(TOKEN_KEY, t); else sessionStorage.removeItem(TOKEN_KEY);
      input.value = "";
      input.placeholder = t ? "(token set)" : "";
      location.reload();
    });
    nav.appendChild(el("label", {class: "auth"}, "API token ", input));
  }

  function showError(id, err) {
    const box = document.getElementById(id);
    box.textContent = String(err && err.message ? err.message : err);
    box.hidden = false;
  }

  // A uPlot in `container`, as wide as the container. opts: uPlot options without width;
  // `legendLatest: true`: the legend shows the newest point's values while the cursor is off
  // the plot (set just after each draw, whose own legend update would clear it).
  function plot(container, opts, data) {
    clear(container);
    const width = Math.max(320, container.clientWidth || 640);
    const o = Object.assign({width, height: 260}, opts);
    if (o.legendLatest) {
      o.hooks = Object.assign({}, o.hooks);
      o.hooks.draw = [...(o.hooks.draw || []), u => setTimeout(() => {
        const n = u.data[0].length;  // after the draw's own legend update, which clears it
        if (n && !(u.cursor.left >= 0)) u.setLegend({idx: n - 1});
      }, 0)];
    }
    delete o.legendLatest;
    return new uPlot(o, data, container);
  }

  // A y range of at least `span` (units of the data) around the data: a flat curve (a CMRT
  // that stayed at 0) is drawn as a line at 0, not in an arbitrary 0..100 range.
  function minSpan(span) {
    return (u, min, max) => {
      if (min === null || max === null) return [-span, span];
      const pad = Math.max(span - (max - min), 0) / 2 + (max - min) * 0.05;
      return [min - pad, max + pad];
    };
  }

  const COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b",
                   "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"];

  // A link to a replay page (or a job's motion file). A followed link cannot send the token
  // header, so with a token set the click first asks POST /links for a signed, short-lived
  // URL (service.links) and opens that; the token itself never enters a URL.
  function replayLink(path, text, attrs) {
    return el("a", Object.assign({href: path, class: "replay-link"}, attrs || {}, {
      onclick: async (ev) => {
        if (!sessionStorage.getItem(TOKEN_KEY)) return;
        ev.preventDefault();
        try {
          const out = await getJson("/links", {method: "POST", headers: headers(
            {"Content-Type": "application/json"}), body: JSON.stringify({path})});
          location.assign(out.url);
        } catch (e) { showError("error", e); }
      }}), text);
  }

  return {TERMINAL, STATUSES, COLOURS, HttpError, headers, getJson, el, clear, setText, fmt,
          elapsed, jobPage, api, statusBadge, header, showError, plot, minSpan, replayLink};
})();
