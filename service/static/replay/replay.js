// The replay player: draws a cmrt-replay/1 document (docs/replay.md) on canvases, one view per
// clip on one timeline, with uPlot plots synced to the playhead. Vanilla JS; it reads the
// document from <script id="replay-data" type="application/json"> and needs no network.
// User text (spec names, labels) is only ever set with textContent.
(function () {
  "use strict";
  const doc = JSON.parse(document.getElementById("replay-data").textContent);
  const root = document.getElementById("replay");
  const clips = doc.clips;
  const rate = doc.rate;
  const nFrames = Math.max.apply(null, clips.map(function (c) { return c.frames; }));
  const SPEEDS = [0.1, 0.25, 0.5, 1, 2];
  // Colours of the clips in the plots (clip 0: no anticipation, clip 1: with the CMRT).
  const CLIP_COLOURS = ["#d9480f", "#1864ab", "#2b8a3e", "#862e9c"];
  const bodyIndex = {};
  doc.bodies.forEach(function (n, i) { bodyIndex[n] = i; });

  function el(tag, attrs, text) {
    const e = document.createElement(tag);
    Object.keys(attrs || {}).forEach(function (k) { e.setAttribute(k, attrs[k]); });
    if (text !== undefined) e.textContent = text;
    return e;
  }
  function fmt(v, d) { return v === null || v === undefined ? "-" : Number(v).toFixed(d); }

  // The clip's motion files (BVH and CSV, written by the service's sim.export and carried in
  // the document) as downloads: object URLs of the text, no network.
  function downloads(c, k) {
    const stem = doc.spec.name.replace(/[^A-Za-z0-9_.-]/g, "_") +
      (c.cmrt && c.cmrt.source !== "none" ? "_cmrt" : "_flat");
    const box = el("span", { class: "downloads" }, " motion at " + c.motion.fps + " fps: ");
    [["bvh", "text/plain"], ["csv", "text/csv"]].forEach(function (f, j) {
      const url = URL.createObjectURL(new Blob([c.motion[f[0]]], { type: f[1] }));
      if (j) box.appendChild(document.createTextNode(", "));
      box.appendChild(el("a", { href: url, download: stem + "." + f[0],
                                class: "download-" + f[0], "data-clip": String(k) },
                         f[0].toUpperCase()));
    });
    return box;
  }

  // ---- layout --------------------------------------------------------------------------
  const title = doc.spec.name + " (" + doc.spec.task_type + ", family " + doc.spec.family + ")";
  document.title = "Replay: " + doc.spec.name;
  root.appendChild(el("h1", {}, "Replay: " + title));
  const bar = el("div", { class: "controls" });
  const playBtn = el("button", { id: "play", type: "button" }, "Play");
  const scrub = el("input", { id: "scrub", type: "range", min: "0", max: String(nFrames - 1),
                              step: "1", value: "0", "aria-label": "time" });
  const speed = el("select", { id: "speed", "aria-label": "speed" });
  SPEEDS.forEach(function (s) {
    const o = el("option", { value: String(s) }, s + "x");
    if (s === 1) o.selected = true;
    speed.appendChild(o);
  });
  const loopLbl = el("label", {});
  const loop = el("input", { id: "loop", type: "checkbox" });
  loop.checked = true;
  loopLbl.appendChild(loop);
  loopLbl.appendChild(document.createTextNode(" loop"));
  const clock = el("span", { id: "clock", class: "clock" }, "");
  [playBtn, scrub, speed, loopLbl, clock].forEach(function (e) { bar.appendChild(e); });
  root.appendChild(bar);

  const views = el("div", { class: "views" });
  root.appendChild(views);
  const clipViews = clips.map(function (c, k) {
    const box = el("figure", { class: "view" });
    const cap = el("figcaption", {});
    const o = c.outcome;
    cap.appendChild(el("strong", {}, c.label));
    const what = o.fell ? "fell at " + fmt(o.fall_time, 2) + " s (" + (o.fall_direction || "?") +
      ", " + (o.fall_reason || "") + ")" : "no fall";
    let line = " objective " + fmt(o.objective, 3) + ", " + what;
    if (o.task_success !== null && o.task_success !== undefined) {
      line += ", task " + (o.task_success ? "succeeded" : "failed");
    }
    cap.appendChild(document.createTextNode(line));
    if (c.motion) cap.appendChild(downloads(c, k));
    cap.querySelector("strong").style.color = CLIP_COLOURS[k % CLIP_COLOURS.length];
    const canvas = el("canvas", { class: "stage", "data-clip": String(k) });
    box.appendChild(canvas);
    box.appendChild(cap);
    views.appendChild(box);
    return { canvas: canvas, clip: c, status: cap };
  });
  const legend = el("div", { class: "legend" },
    "CM: circle, its ground projection: dashed line and tick; CM reference: vertical line; " +
    "CoP: triangle on the ground; support: thick bar; task window: shaded on the plots.");
  root.appendChild(legend);
  const plotsBox = el("div", { class: "plots" });
  root.appendChild(plotsBox);

  // ---- world -> canvas -----------------------------------------------------------------
  function bounds() {
    let x0 = Infinity, x1 = -Infinity, y1 = doc.character.height;
    clips.forEach(function (c) {
      c.poses.forEach(function (row) {
        for (let j = 0; j < row.length; j += 3) {
          x0 = Math.min(x0, row[j]); x1 = Math.max(x1, row[j]); y1 = Math.max(y1, row[j + 1]);
        }
      });
      c.cm_ref.forEach(function (r) { x0 = Math.min(x0, r[0]); x1 = Math.max(x1, r[0]); });
    });
    doc.props.forEach(function (p) {
      if (p.hanging) { y1 = Math.max(y1, p.hanging.anchor[1]); }
    });
    const pad = 0.45;
    return { x0: x0 - pad, x1: x1 + pad, y0: -0.12, y1: y1 + 0.25 };
  }
  const B = bounds();
  const ASPECT = (B.y1 - B.y0) / (B.x1 - B.x0);

  function sizeCanvases() {
    const n = clipViews.length, gap = 12, frame = 12;  // .views gap, figure padding + border
    const w = Math.max(260, Math.min(620, Math.floor(((views.clientWidth || 900) -
      gap * (n - 1)) / n) - frame));
    const h = Math.round(Math.min(520, Math.max(260, w * ASPECT)));
    const dpr = window.devicePixelRatio || 1;
    clipViews.forEach(function (v) {
      v.canvas.width = Math.round(w * dpr); v.canvas.height = Math.round(h * dpr);
      v.canvas.style.width = w + "px"; v.canvas.style.height = h + "px";
      v.scale = Math.min(w / (B.x1 - B.x0), h / (B.y1 - B.y0)) * dpr;
      v.ox = (v.canvas.width - v.scale * (B.x1 - B.x0)) / 2 - v.scale * B.x0;
      v.oy = v.canvas.height - (v.canvas.height - v.scale * (B.y1 - B.y0)) / 2 + v.scale * B.y0;
    });
  }

  function capsule(ctx, ax, ay, ra, bx, by, rb, minW) {
    // The convex hull of two discs (a tapered capsule), or a line when both radii are 0.
    const dx = bx - ax, dy = by - ay, d = Math.hypot(dx, dy);
    if (ra <= 0 && rb <= 0) {
      ctx.save(); ctx.lineWidth = minW; ctx.beginPath(); ctx.moveTo(ax, ay); ctx.lineTo(bx, by);
      ctx.stroke(); ctx.restore(); return;
    }
    ctx.beginPath();
    if (d < 1e-9 || Math.abs(ra - rb) >= d) {
      const r = Math.max(ra, rb);
      ctx.arc(d < 1e-9 || ra > rb ? ax : bx, d < 1e-9 || ra > rb ? ay : by, r, 0, 2 * Math.PI);
    } else {
      const phi = Math.atan2(dy, dx), alpha = Math.acos((ra - rb) / d);
      ctx.arc(ax, ay, ra, phi + alpha, phi - alpha + 2 * Math.PI);
      ctx.arc(bx, by, rb, phi - alpha, phi + alpha);
      ctx.closePath();
    }
    ctx.fill(); ctx.stroke();
  }

  function drawProp(ctx, p, pose, px) {
    ctx.save();
    ctx.translate(pose[0], pose[1]); ctx.rotate(pose[2]);
    ctx.fillStyle = "rgba(230, 160, 40, 0.8)"; ctx.strokeStyle = "#7a4a00"; ctx.lineWidth = px;
    if (p.shape === "box") {
      ctx.fillRect(-p.size[0] / 2, -p.size[1] / 2, p.size[0], p.size[1]);
      ctx.strokeRect(-p.size[0] / 2, -p.size[1] / 2, p.size[0], p.size[1]);
    } else if (p.shape === "sphere") {
      ctx.beginPath(); ctx.arc(0, 0, p.size[0], 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
    } else {
      const r = p.size[0], h = p.size[1] / 2;
      capsule(ctx, 0, -h, r, 0, h, r, px);
    }
    ctx.restore();
  }

  function drawView(v, i) {
    const c = v.clip, k = Math.min(i, c.frames - 1), ctx = v.canvas.getContext("2d");
    const W = v.canvas.width, H = v.canvas.height, s = v.scale, px = 1 / s;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#ffffff"; ctx.fillRect(0, 0, W, H);
    ctx.setTransform(s, 0, 0, -s, v.ox, v.oy);  // world metres, y up
    // Ground.
    ctx.fillStyle = "#e9ecef"; ctx.fillRect(B.x0 - 1, B.y0 - 1, B.x1 - B.x0 + 2, 1);
    ctx.strokeStyle = "#495057"; ctx.lineWidth = 1.5 * px;
    ctx.beginPath(); ctx.moveTo(B.x0 - 1, 0); ctx.lineTo(B.x1 + 1, 0); ctx.stroke();
    // Metre ticks on the ground.
    ctx.lineWidth = px;
    for (let x = Math.ceil(B.x0 * 10) / 10; x <= B.x1; x += 0.1) {
      const major = Math.abs(x - Math.round(x)) < 1e-6;
      ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, major ? -0.05 : -0.02); ctx.stroke();
    }
    // Support interval.
    const sup = c.support[k];
    ctx.strokeStyle = "#2b8a3e"; ctx.lineWidth = 6 * px;
    ctx.beginPath(); ctx.moveTo(sup[0], -3 * px); ctx.lineTo(sup[1], -3 * px); ctx.stroke();
    const row = c.poses[k];
    // Props: chains and rods first, then the bodies.
    doc.props.forEach(function (p) {
      const j = bodyIndex[p.name];
      if (p.hanging) {
        ctx.strokeStyle = "#868e96"; ctx.lineWidth = 1.5 * px; ctx.beginPath();
        ctx.moveTo(p.hanging.anchor[0], p.hanging.anchor[1]);
        p.hanging.links.forEach(function (ln) {
          const q = bodyIndex[ln]; ctx.lineTo(row[3 * q], row[3 * q + 1]);
        });
        ctx.lineTo(row[3 * j], row[3 * j + 1]); ctx.stroke();
      }
      drawProp(ctx, p, [row[3 * j], row[3 * j + 1], row[3 * j + 2]], px);
    });
    // The character, to scale: each body's shapes in its local frame.
    doc.character.segments.forEach(function (seg, b) {
      ctx.save();
      ctx.translate(row[3 * b], row[3 * b + 1]); ctx.rotate(row[3 * b + 2]);
      ctx.lineWidth = px;
      seg.shapes.forEach(function (sh) {
        const hand = sh.geom !== undefined;
        ctx.fillStyle = hand ? "rgba(73, 80, 87, 0.35)" : "rgba(173, 181, 189, 0.85)";
        ctx.strokeStyle = "#343a40";
        if (sh.kind === "capsule") {
          capsule(ctx, sh.a[0], sh.a[1], sh.ra, sh.b[0], sh.b[1], sh.rb, 2 * px);
        } else if (sh.kind === "circle") {
          ctx.beginPath(); ctx.arc(sh.c[0], sh.c[1], Math.max(sh.r, 2 * px), 0, 2 * Math.PI);
          ctx.fill(); ctx.stroke();
        } else if (sh.kind === "polygon") {
          ctx.fillStyle = "rgba(134, 142, 150, 0.9)";
          ctx.beginPath(); ctx.moveTo(sh.points[0][0], sh.points[0][1]);
          sh.points.slice(1).forEach(function (q) { ctx.lineTo(q[0], q[1]); });
          ctx.closePath(); ctx.fill(); ctx.stroke();
        }
      });
      ctx.restore();
    });
    // CM reference: a vertical line (the paper's figures).
    const ref = c.cm_ref[k], cm = c.cm[k];
    ctx.strokeStyle = "#c92a2a"; ctx.lineWidth = 2 * px;
    ctx.beginPath(); ctx.moveTo(ref[0], 0); ctx.lineTo(ref[0], B.y1 - 0.05); ctx.stroke();
    // CM and its ground projection.
    ctx.strokeStyle = "#1c7ed6"; ctx.lineWidth = 1.5 * px; ctx.setLineDash([6 * px, 4 * px]);
    ctx.beginPath(); ctx.moveTo(cm[0], cm[1]); ctx.lineTo(cm[0], 0); ctx.stroke();
    ctx.setLineDash([]);
    ctx.beginPath(); ctx.moveTo(cm[0], 0.04); ctx.lineTo(cm[0], -0.04); ctx.lineWidth = 3 * px;
    ctx.stroke();
    ctx.fillStyle = "#ffffff"; ctx.lineWidth = 2 * px;
    ctx.beginPath(); ctx.arc(cm[0], cm[1], 7 * px, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
    ctx.fillStyle = "#1c7ed6";
    ctx.beginPath(); ctx.moveTo(cm[0], cm[1]); ctx.arc(cm[0], cm[1], 7 * px, 0, Math.PI / 2);
    ctx.closePath(); ctx.fill();
    ctx.beginPath(); ctx.moveTo(cm[0], cm[1]);
    ctx.arc(cm[0], cm[1], 7 * px, Math.PI, 1.5 * Math.PI); ctx.closePath(); ctx.fill();
    // CP.
    const cp = c.cp[k];
    if (cp !== null) {
      ctx.fillStyle = "#f08c00";
      ctx.beginPath(); ctx.moveTo(cp, 0); ctx.lineTo(cp - 6 * px, -11 * px);
      ctx.lineTo(cp + 6 * px, -11 * px); ctx.closePath(); ctx.fill();
    }
    // Text: time and fall state (screen coordinates).
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    const dpr = window.devicePixelRatio || 1;
    ctx.fillStyle = "#212529"; ctx.font = (13 * dpr) + "px sans-serif";
    const t = c.t[k];
    let txt = "t = " + t.toFixed(2) + " s";
    const o = c.outcome;
    if (o.fell && o.fall_time !== null && t >= o.fall_time) {
      txt += "  FELL (" + (o.fall_direction || "") + ")"; ctx.fillStyle = "#c92a2a";
    }
    if (i >= c.frames) txt += "  (clip ended)";
    ctx.fillText(txt, 8 * dpr, 18 * dpr);
  }

  // ---- plots (uPlot), one cursor line at the playhead ----------------------------------
  let current = 0;
  const plots = [];
  const times = [];
  for (let i = 0; i < nFrames; i++) times.push(i / rate);
  function column(c, key) {  // metres in the document, millimetres on the plots
    const out = c.plots[key].map(function (v) { return v === null ? null : v * 1000; });
    while (out.length < nFrames) out.push(null);
    return out;
  }
  function range(u, lo, hi) {  // a flat series still gets a readable +-10 mm axis
    if (lo === null || hi === null || hi - lo < 1) {
      const m = lo === null ? 0 : (lo + hi) / 2; return [m - 10, m + 10];
    }
    const pad = 0.08 * (hi - lo); return [lo - pad, hi + pad];
  }
  const clipDef = doc.spec.clip;
  function playheadPlugin() {
    return {
      hooks: {
        drawClear: [function (u) {
          const ctx = u.ctx, l = u.valToPos(clipDef.task_start, "x", true),
            r = u.valToPos(clipDef.task_end, "x", true);
          ctx.save(); ctx.fillStyle = "rgba(250, 176, 5, 0.12)";
          ctx.fillRect(l, u.bbox.top, r - l, u.bbox.height); ctx.restore();
        }],
        draw: [function (u) {
          const x = u.valToPos(current / rate, "x", true), ctx = u.ctx;
          ctx.save(); ctx.setLineDash([]); ctx.strokeStyle = "#000000"; ctx.lineWidth = 1.5 * (window.devicePixelRatio || 1);
          ctx.beginPath(); ctx.moveTo(x, u.bbox.top); ctx.lineTo(x, u.bbox.top + u.bbox.height);
          ctx.stroke(); ctx.restore();
        }],
      },
    };
  }
  function addPlot(name, unit, series, data) {
    const box = el("div", { class: "plot", "data-plot": name });
    plotsBox.appendChild(box);
    const width = Math.max(300, Math.min(1200, (root.clientWidth || 960) - 20));
    const opts = {
      title: name, width: width, height: 190, plugins: [playheadPlugin()],
      legend: { live: false },
      scales: { x: { time: false }, y: { range: range } },
      axes: [{ label: "t (s)" }, { label: unit, size: 60 }],
      series: [{ label: "t" }].concat(series),
      cursor: { drag: { x: false, y: false } },
    };
    const u = new uPlot(opts, [times].concat(data), box);
    u.over.addEventListener("click", function (ev) {
      const t = u.posToVal(ev.offsetX, "x");
      seek(Math.round(t * rate));
    });
    plots.push(u);
  }
  function colour(k) { return CLIP_COLOURS[k % CLIP_COLOURS.length]; }
  addPlot("CoP error e(t) = CoP - support centre", "mm", clips.map(function (c, k) {
    return { label: c.label, stroke: colour(k), width: 1.5 };
  }), clips.map(function (c) { return column(c, "error"); }));
  addPlot("CMRT displacement", "mm", clips.map(function (c, k) {
    return { label: c.label + " dx", stroke: colour(k), width: 1.5 };
  }), clips.map(function (c) { return column(c, "cmrt_dx"); }));
  const cmSeries = [], cmData = [];
  clips.forEach(function (c, k) {
    cmSeries.push({ label: c.label + " CM x", stroke: colour(k), width: 1.5 });
    cmSeries.push({ label: c.label + " reference x", stroke: colour(k), width: 1, dash: [6, 4] });
    cmData.push(column(c, "cm_x")); cmData.push(column(c, "cm_ref_x"));
  });
  addPlot("CM x against the CM reference x", "mm", cmSeries, cmData);

  // ---- playback ------------------------------------------------------------------------
  let playing = false, lastMs = null, pos = 0;  // pos: fractional frame
  function render() {
    root.setAttribute("data-frame", String(current));
    root.setAttribute("data-time", (current / rate).toFixed(3));
    root.setAttribute("data-playing", playing ? "true" : "false");
    scrub.value = String(current);
    clock.textContent = "t = " + (current / rate).toFixed(2) + " s / " +
      ((nFrames - 1) / rate).toFixed(2) + " s, frame " + current + " / " + (nFrames - 1) +
      " (" + rate + " frames/s)";
    clipViews.forEach(function (v) { drawView(v, current); });
    plots.forEach(function (u) { u.redraw(false, false); });
  }
  function seek(i) {
    current = Math.max(0, Math.min(nFrames - 1, i)); pos = current; render();
  }
  function tick(ms) {
    if (!playing) return;
    if (lastMs !== null) {
      pos += (ms - lastMs) / 1000 * rate * Number(speed.value);
      if (pos > nFrames - 1) {
        if (loop.checked) { pos = 0; } else { pos = nFrames - 1; setPlaying(false); }
      }
      const next = Math.floor(pos);
      if (next !== current) { current = next; render(); }
    }
    lastMs = ms;
    if (playing) requestAnimationFrame(tick);
  }
  function setPlaying(on) {
    playing = on; lastMs = null; playBtn.textContent = on ? "Pause" : "Play";
    if (on && current >= nFrames - 1) pos = current = 0;
    root.setAttribute("data-playing", on ? "true" : "false");
    if (on) requestAnimationFrame(tick);
  }
  playBtn.addEventListener("click", function () { setPlaying(!playing); });
  scrub.addEventListener("input", function () { seek(Number(scrub.value)); });
  document.addEventListener("keydown", function (ev) {
    if (ev.target && ev.target.tagName === "SELECT") return;
    if (ev.key === " ") { ev.preventDefault(); setPlaying(!playing); }
    if (ev.key === "ArrowRight") seek(current + 1);
    if (ev.key === "ArrowLeft") seek(current - 1);
  });
  window.addEventListener("resize", function () { sizeCanvases(); render(); });
  sizeCanvases();
  const start = new URLSearchParams(window.location.search).get("t");
  seek(start ? Math.round(Number(start) * rate) || 0 : 0);
  root.setAttribute("data-ready", "true");
})();
