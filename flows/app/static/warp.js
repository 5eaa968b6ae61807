// motionweb page: the guided time warp panel (HDP07), over the service's warp sessions
// (flows/app/sessions.py). A session keeps the clip, its reference (or itself) and the local
// scores of its triples; every edit (the duration, a keytime added or dragged on the warp curve)
// asks for the warped motion, played here beside the original (or the reference it is warped
// toward) on one clock, as the retime panel plays the retimed beside the original, with the warp
// curve (a red mark: the frame playing now), each flight shaded on it with its ratio.
// Plain JS and canvas; uses $, api, say, Figure, COLORS and state of app.js, rtAxes and
// rtPolyline of retime.js.
"use strict";

const gw = { session: null, result: null, keytimes: [], duration: null, busy: false, pending: false, timer: null,
  drag: null, time: 0, last: performance.now(), view: null, original: null, axes: null };

async function gwOpen() {
  if (!state.clip) { say("open a clip in the player first"); return; }
  const body = { clip: state.clip.id };
  if ($("gw-ref").value.trim()) body.reference = $("gw-ref").value.trim();
  $("gw-info").textContent = "opening…";
  const s = await api("/api/warp/sessions", {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  });
  gw.session = s; gw.keytimes = [];
  // beside the warped motion: the reference it follows (HDP07 §3), else the original clip
  gw.original.setPose(s.reference_pose || s.original);
  $("gw-original-cap").textContent = s.reference_pose ? `reference: ${s.reference.path}` : `original: ${s.path}`;
  gw.time = 0;
  gw.duration = Math.round(0.7 * s.duration * 100) / 100;
  $("gw-duration").value = gw.duration.toFixed(2);
  $("gw-info").textContent = `${s.path} toward ${s.reference ? s.reference.path : "itself"}`;
  await gwEditNow();
}

function gwEditSoon(delay) {
  clearTimeout(gw.timer);
  gw.timer = setTimeout(() => gwEditNow().catch((e) => say(e.message)), delay ?? 60);
}

async function gwEditNow() {
  if (!gw.session) return;
  if (gw.busy) { gw.pending = true; return; }
  gw.busy = true; gw.pending = false;
  try {
    const body = { duration: gw.duration, fast: $("gw-fast").checked,
      keytimes: gw.keytimes.slice().sort((a, b) => a[1] - b[1]) };
    const r = await api(`/api/warp/sessions/${gw.session.session}/edit`, {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
    });
    gw.result = r;
    gw.view.setPose(r.pose);
    $("gw-bvh").href = `/api/warp/sessions/${gw.session.session}/bvh`; $("gw-bvh").classList.remove("hidden");
    $("gw-flights").textContent = `${r.input_s.toFixed(2)} s → ${r.output_s.toFixed(2)} s, cost ${r.cost.toPrecision(4)}`
      + (r.flights.length ? " · flights " + r.flights.map((f) => `${f.source_s.toFixed(2)} → ${f.output_s.toFixed(2)} s (×${f.ratio.toFixed(2)})`).join(", ") : " · no flight")
      + ` · edit ${(r.edit_s * 1000).toFixed(0)} ms`;
    gwCurve();
    say("");
  } catch (e) {
    say(e.message);
  } finally {
    gw.busy = false;
    if (gw.pending) gwEditSoon(0);
  }
}

function gwCurve() {
  const r = gw.result;
  if (!r) return;
  const t = r.times_s.map((_, i) => i / r.fps);
  const a = rtAxes($("gw-curve"), 0, r.output_s, 0, r.input_s);
  gw.axes = a;
  const ctx = a.ctx;
  ctx.setLineDash([4, 3]); ctx.strokeStyle = "#9e9e9e"; ctx.lineWidth = 1.5;
  rtPolyline(ctx, t, r.linear_s, a.X, a.Y);
  ctx.setLineDash([]); ctx.strokeStyle = "#1565c0"; ctx.lineWidth = 2;
  rtPolyline(ctx, t, r.times_s, a.X, a.Y);
  ctx.fillStyle = "#000";
  for (const [s, o] of gw.keytimes) { ctx.beginPath(); ctx.arc(a.X(o), a.Y(s), 5, 0, 2 * Math.PI); ctx.fill(); }
  // each flight of the input (no foot down): its input span shaded, with the ratio the warp gave it
  ctx.font = "10px sans-serif";
  for (const f of r.flights) {
    if (f.start_s === undefined) continue;
    const y0 = a.Y(f.start_s), y1 = a.Y(f.start_s + f.source_s);
    ctx.fillStyle = "rgba(255,152,0,0.18)"; ctx.fillRect(a.X(0), y1, a.X(r.output_s) - a.X(0), y0 - y1);
    ctx.fillStyle = "#e65100"; ctx.fillText(`×${f.ratio.toFixed(2)}`, a.X(r.output_s) - 34, y1 + 10);
  }
  // the frame playing now
  const k = Math.min(r.times_s.length - 1, Math.round(gw.time * r.fps));
  ctx.fillStyle = "#c62828"; ctx.beginPath(); ctx.arc(a.X(k / r.fps), a.Y(r.times_s[k]), 3, 0, 2 * Math.PI); ctx.fill();
}

function gwSetup() {
  gw.view = new Figure($("gw-view"), COLORS[2]);
  gw.original = new Figure($("gw-original"), COLORS[5]);
  const c = $("gw-curve");
  const at = (e) => {
    const b = c.getBoundingClientRect(), px = (e.clientX - b.left) * c.width / b.width, py = (e.clientY - b.top) * c.height / b.height;
    const r = gw.result, p = 28, w = c.width, h = c.height;
    return [r.input_s * (h - p - py) / (h - p - 12), r.output_s * (px - p) / (w - p - 6), px, py];
  };
  const near = (px, py) => gw.keytimes.findIndex(([s, o]) => Math.hypot(gw.axes.X(o) - px, gw.axes.Y(s) - py) < 8);
  c.addEventListener("pointerdown", (e) => {
    if (!gw.result) return;
    const [, , px, py] = at(e), k = near(px, py);
    if (k >= 0) { gw.drag = k; c.setPointerCapture(e.pointerId); }
  });
  c.addEventListener("pointermove", (e) => {
    if (gw.drag == null) return;
    const [s, o] = at(e), r = gw.result;
    gw.keytimes[gw.drag] = [Math.max(0.05, Math.min(r.input_s - 0.05, s)), Math.max(0.05, Math.min(gw.duration - 0.05, o))];
    gwCurve();
    gwEditSoon(80);
  });
  c.addEventListener("pointerup", () => { if (gw.drag != null) { gw.drag = null; gwEditSoon(0); } });
  c.addEventListener("dblclick", (e) => {
    if (!gw.result) return;
    const [s, o, px, py] = at(e), k = near(px, py);
    if (k >= 0) gw.keytimes.splice(k, 1);
    else if (s > 0.05 && s < gw.result.input_s - 0.05 && o > 0.05 && o < gw.duration - 0.05) {
      gw.keytimes.push([Math.round(s * 1000) / 1000, Math.round(o * 1000) / 1000]);
    }
    gwCurve();
    gwEditSoon(0);
  });
  $("gw-open").addEventListener("click", () => gwOpen().catch((e) => { say(e.message); $("gw-info").textContent = ""; }));
  $("gw-duration").addEventListener("change", () => {
    const d = parseFloat($("gw-duration").value);
    if (!(d > 0)) { say("duration: a positive number of seconds"); return; }
    gw.duration = d;
    gw.keytimes = gw.keytimes.filter(([, o]) => o < d - 0.05);
    gwEditSoon(0);
  });
  $("gw-fast").addEventListener("change", () => gwEditSoon(0));
  const tick = (now) => {
    const dt = Math.min(0.1, (now - gw.last) / 1000);
    gw.last = now;
    if (gw.result && gw.view.pose) {
      // one clock for both, over the longer of the two (as the retime panel's)
      const o = gw.original.pose, span = Math.max(gw.result.output_s, o ? (o.frames - 1) / o.rate : 0, 0.1);
      gw.time = (gw.time + dt) % span;
      gw.view.draw(Math.min(gw.view.pose.frames - 1, Math.round(gw.time * gw.view.pose.rate)));
      if (o) gw.original.draw(Math.min(o.frames - 1, Math.round(gw.time * o.rate)));
      if (gw.drag == null) gwCurve();
    }
    requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);
}

gwSetup();
