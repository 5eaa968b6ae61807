// motionweb page: the Retime panel (MPS06), over the service's retime sessions (flows/app/sessions.py).
// A session prepares the clip's polygons once per physics (gravity, a limb's mass or weight);
// every timing edit (the duration, a keytime dragged on the timeline) asks for the retimed motion,
// played beside the original, with the plots `motionweb retime` draws: p(t) against linear
// timing, the polygon of a chosen output frame with its (p̈, ṗ²), torques against their limits,
// contact phases and flights with their ratios, and the shortest reachable duration.
// Plain JS and canvas; uses $, api, say, Figure, line, COLORS and state of app.js.
"use strict";

const rt = {
  session: null, // the POST /api/retime/sessions answer
  result: null, // the last edit's answer
  keytimes: [], // [[source s, output s], ...]
  duration: null,
  busy: false, pending: false, timer: null, drag: null,
  time: 0, last: performance.now(),
  original: null, retimed: null,
};

function rtPhysics() {
  const g = ["rt-gx", "rt-gy", "rt-gz"].map((id) => parseFloat($(id).value));
  const body = { clip: rt.clipId };
  if (g.some((v) => !Number.isFinite(v))) throw new Error("gravity: three numbers, m/s²");
  if (!(g[0] === 0 && g[2] === 0 && Math.abs(g[1] + 9.81) < 1e-9)) body.gravity = g;
  const joint = $("rt-joint").value, m = parseFloat($("rt-mass").value), w = parseFloat($("rt-weight").value);
  if (joint && Number.isFinite(m) && m !== 1) body.mass = { [joint]: m };
  if (joint && Number.isFinite(w) && w !== 1) body.weight = { [joint]: w };
  return body;
}

// a new session (a clip, or new physics): prepared once, then the current timing replayed on it;
// clipId: an upload's id (else the player's clip)
async function rtOpen(keepTiming, clipId) {
  if (!keepTiming) {
    if (!clipId && !state.clip) { say("open a clip in the player first"); return; }
    rt.clipId = clipId || state.clip.id; rt.keytimes = []; rt.duration = null;
  }
  $("rt-info").textContent = "preparing the polygons…";
  $("rt-apply").disabled = true;
  const t0 = performance.now();
  const s = await api("/api/retime/sessions", {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(rtPhysics()),
  });
  rt.session = s;
  if (!keepTiming) {
    rt.duration = s.duration;
    $("rt-duration").value = s.duration.toFixed(2);
    const sel = $("rt-joint"), keep = sel.value;
    sel.length = 0;
    sel.add(new Option("—", ""));
    for (const j of s.joints.slice(1)) sel.add(new Option(j, j));
    if (s.joints.includes(keep)) sel.value = keep;
    rt.original.setPose(s.original);
  }
  $("rt-info").textContent = `${s.path} · ${s.frames} frames · prepared in ${((performance.now() - t0) / 1000).toFixed(2)} s`
    + ` (${(s.plan_bytes / 1e6).toFixed(1)} MB, ${s.plans} kept)`;
  $("rt-apply").disabled = false;
  await rtEditNow();
}

function rtEditSoon(delay) {
  clearTimeout(rt.timer);
  rt.timer = setTimeout(() => rtEditNow().catch((e) => say(e.message)), delay ?? 60);
}

// one edit in flight; the latest timing wins
async function rtEditNow() {
  if (!rt.session) return;
  if (rt.busy) { rt.pending = true; return; }
  rt.busy = true; rt.pending = false;
  try {
    const body = { duration: rt.duration, keytimes: rt.keytimes.slice().sort((a, b) => a[0] - b[0]) };
    const r = await api(`/api/retime/sessions/${rt.session.session}/edit`, {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
    });
    rtShow(r);
    say("");
  } catch (e) {
    say(e.message);
  } finally {
    rt.busy = false;
    if (rt.pending) rtEditSoon(0);
  }
}

function rtShow(r) {
  rt.result = r;
  rt.retimed.setPose(r.pose);
  rt.retimed.dist = rt.original.dist;
  const sid = rt.session.session;
  $("rt-bvh").href = `/api/retime/sessions/${sid}/bvh`; $("rt-bvh").classList.remove("hidden");
  $("rt-report").href = `/api/retime/sessions/${sid}/report`; $("rt-report").classList.remove("hidden");
  const fr = $("rt-frame");
  fr.max = r.t.length - 1;
  if (+fr.value > r.t.length - 1) fr.value = 0;
  const reach = r.reachable, sfd = r.shortest_feasible_duration;
  $("rt-reach").textContent = `${r.duration_in.toFixed(3)} s → ${r.duration_out.toFixed(3)} s, timing ${r.timing}`
    + ` · ${reach.message} · shortest reachable ${sfd == null ? "none" : sfd.toFixed(3) + " s"}`
    + ` · ${r.infeasible_output_frames.length} frames outside their polygon · edit ${(r.edit_s * 1000).toFixed(0)} ms`;
  $("rt-reach").classList.toggle("unmet", !reach.met);
  rtDrawAll();
}

function rtDrawAll() {
  rtTimeline(); rtTiming(); rtPolygon(); rtTorques(); rtContacts();
}

// ------------------------------------------------------------------ helpers
function rtInterp(x, xs, ys) {
  if (!xs.length) return 0;
  if (x <= xs[0]) return ys[0];
  for (let i = 1; i < xs.length; i++) {
    if (x <= xs[i]) { const u = (x - xs[i - 1]) / ((xs[i] - xs[i - 1]) || 1); return ys[i - 1] + u * (ys[i] - ys[i - 1]); }
  }
  return ys[ys.length - 1];
}

function rtAxes(c, x0, x1, y0, y1, pad) {
  const ctx = c.getContext("2d"), w = c.width, h = c.height, p = pad || 28;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  ctx.strokeStyle = "#999"; ctx.lineWidth = 1;
  ctx.strokeRect(p, 6, w - p - 6, h - p - 6);
  const X = (x) => p + (w - p - 6) * (x - x0) / ((x1 - x0) || 1);
  const Y = (y) => h - p - (h - p - 12) * (y - y0) / ((y1 - y0) || 1);
  ctx.fillStyle = "#555"; ctx.font = "10px sans-serif";
  ctx.fillText(x0.toFixed(1), p, h - p + 12); ctx.fillText(x1.toFixed(1), w - 30, h - p + 12);
  ctx.fillText(y1.toFixed(1), 2, 14); ctx.fillText(y0.toFixed(1), 2, h - p);
  return { ctx, X, Y };
}

function rtPolyline(ctx, xs, ys, X, Y) {
  ctx.beginPath();
  xs.forEach((x, i) => { if (i) ctx.lineTo(X(x), Y(ys[i])); else ctx.moveTo(X(x), Y(ys[i])); });
  ctx.stroke();
}

// ------------------------------------------------------------------ timeline (output time)
function rtTX(t) { const c = $("rt-timeline"); return 8 + (c.width - 16) * t / (rt.duration || 1); }
function rtTimeAt(px) { const c = $("rt-timeline"); return Math.max(0, Math.min(rt.duration, (px - 8) / (c.width - 16) * rt.duration)); }

function rtTimeline() {
  const c = $("rt-timeline"), ctx = c.getContext("2d"), w = c.width, h = c.height;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  const r = rt.result;
  if (!r || !rt.duration) return;
  ctx.fillStyle = "#eceff1"; ctx.fillRect(8, 18, w - 16, 26);
  for (const f of r.flights) { ctx.fillStyle = "rgba(255,193,7,0.45)"; ctx.fillRect(rtTX(f.output[0]), 18, rtTX(f.output[1]) - rtTX(f.output[0]), 26); }
  // the source frames' positions: a tick per source frame where p(t) shows it (longer each second)
  ctx.strokeStyle = "#78909c"; ctx.lineWidth = 1;
  const fps = r.fps, every = Math.max(1, Math.ceil(4 / Math.max(1e-9, rtTX(1 / fps) - rtTX(0))));  // >= 4 px apart
  for (let i = 0; i <= Math.round(r.duration_in * fps); i += every) {
    const s = i / fps, t = rtInterp(s, r.p, r.t), whole = Math.abs(s - Math.round(s)) < 0.5 * every / fps;
    ctx.beginPath(); ctx.moveTo(rtTX(t), whole ? 18 : 36); ctx.lineTo(rtTX(t), 44); ctx.stroke();
    if (whole) { ctx.fillStyle = "#37474f"; ctx.font = "10px sans-serif"; ctx.fillText(`${Math.round(s)}`, rtTX(t) + 2, 28); }
  }
  ctx.fillStyle = "#c62828";
  for (const k of r.infeasible_output_frames) ctx.fillRect(rtTX(r.t[k]) - 1, 46, 2, 5);
  for (const [s, t] of rt.keytimes) {
    const x = rtTX(t);
    ctx.fillStyle = "#1565c0";
    ctx.beginPath(); ctx.moveTo(x, 8); ctx.lineTo(x + 6, 16); ctx.lineTo(x, 24); ctx.lineTo(x - 6, 16); ctx.closePath(); ctx.fill();
    ctx.font = "10px sans-serif"; ctx.fillText(`${s.toFixed(2)}→${t.toFixed(2)}`, x + 7, 12);
  }
  ctx.fillStyle = "#c62828"; ctx.fillRect(rtTX(rt.time % (rt.duration || 1)) - 1, 2, 2, h - 4);
  ctx.fillStyle = "#37474f"; ctx.font = "10px sans-serif";
  ctx.fillText("output time · ticks: source frames · double-click: add/remove a keytime, drag to move", 10, h - 4);
}

function rtKeyAt(px) {
  return rt.keytimes.findIndex(([, t]) => Math.abs(rtTX(t) - px) <= 7);
}

function rtSetupTimeline() {
  const c = $("rt-timeline");
  const px = (e) => (e.clientX - c.getBoundingClientRect().left) * c.width / c.getBoundingClientRect().width;
  c.addEventListener("pointerdown", (e) => {
    const k = rtKeyAt(px(e));
    if (k >= 0) { rt.drag = k; c.setPointerCapture(e.pointerId); }
  });
  c.addEventListener("pointermove", (e) => {
    if (rt.drag == null) return;
    const kt = rt.keytimes.slice().sort((a, b) => a[1] - b[1]), me = rt.keytimes[rt.drag], i = kt.indexOf(me);
    const lo = i > 0 ? kt[i - 1][1] : 0, hi = i < kt.length - 1 ? kt[i + 1][1] : rt.duration;
    me[1] = Math.max(lo + 0.02, Math.min(hi - 0.02, rtTimeAt(px(e))));
    rtTimeline();
    rtEditSoon(80);
  });
  c.addEventListener("pointerup", () => { if (rt.drag != null) { rt.drag = null; rtEditSoon(0); } });
  c.addEventListener("dblclick", (e) => {
    if (!rt.result) return;
    const k = rtKeyAt(px(e));
    if (k >= 0) rt.keytimes.splice(k, 1);
    else {
      const t = rtTimeAt(px(e)), s = rtInterp(t, rt.result.t, rt.result.p);
      if (t <= 0.02 || t >= rt.duration - 0.02 || s <= 0.02 || s >= rt.result.duration_in - 0.02) return;
      rt.keytimes.push([Math.round(s * 1000) / 1000, Math.round(t * 1000) / 1000]);
    }
    rtTimeline();
    rtEditSoon(0);
  });
}

// ------------------------------------------------------------------ plots
function rtTiming() {
  const r = rt.result;
  if (!r) return;
  const tmax = Math.max(r.duration_out, 1e-3);
  const { ctx, X, Y } = rtAxes($("rt-timing"), 0, tmax, 0, r.duration_in);
  for (const f of r.flights) { ctx.fillStyle = "rgba(255,193,7,0.3)"; ctx.fillRect(X(0), Y(f.source[1]), X(tmax) - X(0), Y(f.source[0]) - Y(f.source[1])); }
  ctx.setLineDash([4, 3]); ctx.strokeStyle = "#9e9e9e"; ctx.lineWidth = 1.5;
  rtPolyline(ctx, r.t, r.linear, X, Y);
  ctx.setLineDash([]); ctx.strokeStyle = "#1565c0"; ctx.lineWidth = 2;
  rtPolyline(ctx, r.t, r.p, X, Y);
  ctx.fillStyle = "#c62828";
  for (const k of r.infeasible_output_frames) { ctx.beginPath(); ctx.arc(X(r.t[k]), Y(r.p[k]), 2, 0, 2 * Math.PI); ctx.fill(); }
  ctx.fillStyle = "#1565c0";
  for (const [s, t] of rt.keytimes) { ctx.beginPath(); ctx.arc(X(t), Y(s), 4, 0, 2 * Math.PI); ctx.fill(); }
}

function rtPolygon() {
  const r = rt.result;
  if (!r) return;
  const k = Math.min(+$("rt-frame").value, r.t.length - 1), i = r.source_frame[k], poly = rt.session.polygons[i] || [];
  const xs = poly.map((v) => v[0]).concat([r.pdd[k], 0]), ys = poly.map((v) => v[1]).concat([r.pd2[k], 1]);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(0, ...ys), y1 = Math.max(...ys);
  const mx = 0.1 * ((x1 - x0) || 1), my = 0.1 * ((y1 - y0) || 1);
  const { ctx, X, Y } = rtAxes($("rt-polygon"), x0 - mx, x1 + mx, y0, y1 + my);
  if (poly.length) {
    ctx.beginPath();
    poly.forEach((v, j) => { if (j) ctx.lineTo(X(v[0]), Y(v[1])); else ctx.moveTo(X(v[0]), Y(v[1])); });
    ctx.closePath(); ctx.fillStyle = "rgba(21,101,192,0.25)"; ctx.fill(); ctx.strokeStyle = "#1565c0"; ctx.stroke();
  }
  ctx.strokeStyle = "#000"; ctx.lineWidth = 1;
  line(ctx, [X(0) - 5, Y(1)], [X(0) + 5, Y(1)]); line(ctx, [X(0), Y(1) - 5], [X(0), Y(1) + 5]);
  ctx.fillStyle = r.feasible[k] ? "#2e7d32" : "#c62828";
  ctx.beginPath(); ctx.arc(X(r.pdd[k]), Y(r.pd2[k]), 4, 0, 2 * Math.PI); ctx.fill();
  const c = $("rt-polygon");
  ctx.fillStyle = "#555"; ctx.fillText("p̈ →", c.width - 40, c.height - 4); ctx.fillText("ṗ²", 30, 18);
  $("rt-frame-info").textContent = `${k} (t ${r.t[k].toFixed(2)} s, source frame ${i}${r.feasible[k] ? "" : ", outside"})`;
}

function rtTorques() {
  const r = rt.result;
  if (!r) return;
  const tq = r.torques, ymax = Math.max(1.2, ...tq.max_ratio);
  const { ctx, X, Y } = rtAxes($("rt-torques"), 0, r.duration_out, 0, ymax);
  ctx.strokeStyle = "#c62828"; ctx.setLineDash([4, 3]); line(ctx, [X(0), Y(1)], [X(r.duration_out), Y(1)]); ctx.setLineDash([]);
  tq.joints.forEach((j, n) => {
    ctx.strokeStyle = COLORS[(n + 1) % COLORS.length]; ctx.lineWidth = 1;
    rtPolyline(ctx, r.t, j.ratio, X, Y);
    ctx.fillStyle = ctx.strokeStyle; ctx.fillText(`${j.name} ${j.peak.toFixed(2)}`, 34, 18 + 11 * n);
  });
  ctx.strokeStyle = "#000"; ctx.lineWidth = 1.5;
  rtPolyline(ctx, r.t, tq.max_ratio, X, Y);
}

function rtContacts() {
  const r = rt.result;
  if (!r) return;
  const c = $("rt-contacts"), ctx = c.getContext("2d"), w = c.width, h = c.height;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  const X = (t) => 90 + (w - 100) * t / (r.duration_out || 1), out = (s) => rtInterp(s, r.p, r.t);
  const feet = Object.keys(r.contacts);
  ctx.font = "10px sans-serif";
  feet.forEach((foot, n) => {
    const y = 8 + n * 22;
    ctx.fillStyle = "#37474f"; ctx.fillText(foot, 4, y + 12);
    ctx.fillStyle = COLORS[n % COLORS.length];
    for (const [a, b] of r.contacts[foot]) ctx.fillRect(X(out(a)), y, Math.max(1, X(out(b)) - X(out(a))), 16);
  });
  const y = 12 + feet.length * 22;
  ctx.fillStyle = "#37474f"; ctx.fillText("flights", 4, y + 12);
  for (const f of r.flights) {
    ctx.fillStyle = "rgba(255,193,7,0.8)"; ctx.fillRect(X(f.output[0]), y, Math.max(1, X(f.output[1]) - X(f.output[0])), 16);
    ctx.fillStyle = "#000"; ctx.fillText(`×${f.ratio.toFixed(2)}`, X(f.output[0]), y + 28);
  }
  const ph = Object.entries(r.phase_seconds).map(([k, v]) => `${k} ${v.source.toFixed(2)}→${v.output.toFixed(2)} s`).join(" · ");
  ctx.fillStyle = "#555"; ctx.fillText(ph, 4, h - 4);
}

// ------------------------------------------------------------------ players, wiring
function rtTick(now) {
  const dt = Math.min(0.1, (now - rt.last) / 1000);
  rt.last = now;
  if (rt.result && rt.original.pose) {
    rt.time += dt;
    const span = Math.max(rt.result.duration_out, rt.result.duration_in);
    if (rt.time > span) rt.time = 0;
    rt.retimed.draw(Math.min(rt.retimed.pose.frames - 1, Math.round(rt.time * rt.retimed.pose.rate)));
    rt.original.draw(Math.min(rt.original.pose.frames - 1, Math.round(rt.time * rt.original.pose.rate)));
    if (!rt.drag) rtTimeline();
  }
  requestAnimationFrame(rtTick);
}

// a clip of the user's own (uploadClip of app.js: also listed as a search query), retimed here
async function rtUpload(files) {
  const up = await uploadClip(files, $("rt-upload-unit").value);
  rt.upload = up;
  await rtOpen(false, up.id);
}

function rtSetup() {
  rt.original = new Figure($("rt-original"), COLORS[5]);
  rt.retimed = new Figure($("rt-retimed"), COLORS[1]);
  rtSetupTimeline();
  $("rt-open").addEventListener("click", () => rtOpen(false).catch((e) => { say(e.message); $("rt-info").textContent = ""; }));
  $("rt-apply").addEventListener("click", () => rtOpen(true).catch((e) => { say(e.message); $("rt-apply").disabled = false; }));
  $("rt-upload").addEventListener("change", (e) => rtUpload([...e.target.files]).catch((err) => say(err.message)));
  $("rt-duration").addEventListener("change", () => {
    const d = parseFloat($("rt-duration").value);
    if (!(d > 0)) { say("duration: a positive number of seconds"); return; }
    rt.duration = d;
    rt.keytimes = rt.keytimes.filter(([, t]) => t < d - 0.02);
    rtEditSoon(0);
  });
  $("rt-frame").addEventListener("input", rtPolygon);
  requestAnimationFrame(rtTick);
}

rtSetup();
