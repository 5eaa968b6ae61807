// motionweb page: catalog, clip player, segment search, registered matches, graph and warps.
// Plain JS and canvas; every request goes to this service's JSON API (flows/app/api.py).
// Motion spaces: the sampled parameter cloud, a target to drag, the synthesized motion played.
"use strict";

const $ = (id) => document.getElementById(id);
const COLORS = ["#1565c0", "#c62828", "#2e7d32", "#6a1b9a", "#ef6c00", "#00838f", "#5d4037", "#ad1457", "#546e7a"];
const MAX_COMPARE = 8;

function say(text) { $("message").textContent = text || ""; }

async function api(path, options) {
  const resp = await fetch(path, Object.assign({ credentials: "same-origin" }, options || {}));
  const data = await resp.json();
  if (!resp.ok) throw new Error(data.error || ("HTTP " + resp.status));
  return data;
}

// ------------------------------------------------------------------ 3D stick figure on a canvas
class Figure {
  // pose: {rate, frames, parents, positions: flat F*J*3 metres, y up}
  constructor(canvas, color) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.color = color || COLORS[0];
    this.pose = null;
    this.yaw = 0.6; this.pitch = 0.25; this.dist = 4.0;
    this.frame = 0;
    let drag = null;
    canvas.addEventListener("mousedown", (e) => { drag = [e.clientX, e.clientY]; });
    window.addEventListener("mouseup", () => { drag = null; });
    window.addEventListener("mousemove", (e) => {
      if (!drag) return;
      this.yaw -= (e.clientX - drag[0]) * 0.01;
      this.pitch = Math.max(-0.2, Math.min(1.4, this.pitch + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      this.draw(this.frame);
    });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      this.dist = Math.max(0.8, Math.min(30, this.dist * Math.exp(e.deltaY * 0.001)));
      this.draw(this.frame);
    }, { passive: false });
  }

  setPose(pose) {
    this.pose = pose;
    this.nJ = pose.parents.length;
    // height of the figure sets the initial zoom
    const p = pose.positions; let lo = Infinity, hi = -Infinity;
    for (let i = 1; i < p.length; i += 3) { lo = Math.min(lo, p[i]); hi = Math.max(hi, p[i]); }
    this.height = Math.max(0.3, hi - Math.min(lo, 0));
    this.dist = 2.6 * this.height;
    this.draw(0);
  }

  joint(f, j) {
    const k = (f * this.nJ + j) * 3, p = this.pose.positions;
    return [p[k], p[k + 1], p[k + 2]];
  }

  camera(target) {
    const cp = Math.cos(this.pitch);
    const eye = [target[0] + this.dist * cp * Math.sin(this.yaw), target[1] + this.dist * Math.sin(this.pitch),
      target[2] + this.dist * cp * Math.cos(this.yaw)];
    const f = norm(sub(target, eye)), r = norm(cross(f, [0, 1, 0])), u = cross(r, f);
    const focal = this.canvas.height / (2 * Math.tan(0.5 * 0.8));
    const w = this.canvas.width, h = this.canvas.height;
    return (p) => {
      const d = sub(p, eye), z = dot(d, f);
      if (z < 0.05) return null;
      return [w / 2 + focal * dot(d, r) / z, h / 2 - focal * dot(d, u) / z];
    };
  }

  draw(frame) {
    const ctx = this.ctx, w = this.canvas.width, h = this.canvas.height;
    ctx.fillStyle = "#fafafa"; ctx.fillRect(0, 0, w, h);
    if (!this.pose || !this.pose.frames) return;
    const f = Math.max(0, Math.min(this.pose.frames - 1, frame | 0));
    this.frame = f;
    const root = this.joint(f, 0);
    const target = [root[0], this.height * 0.5, root[2]];
    const proj = this.camera(target);
    // floor grid, 0.5 m cells, following the root
    ctx.strokeStyle = "#ddd"; ctx.lineWidth = 1;
    const gx = Math.round(root[0] / 0.5) * 0.5, gz = Math.round(root[2] / 0.5) * 0.5;
    for (let i = -6; i <= 6; i++) {
      line(ctx, proj([gx + i * 0.5, 0, gz - 3]), proj([gx + i * 0.5, 0, gz + 3]));
      line(ctx, proj([gx - 3, 0, gz + i * 0.5]), proj([gx + 3, 0, gz + i * 0.5]));
    }
    // shadow and bones
    const par = this.pose.parents;
    ctx.strokeStyle = "rgba(0,0,0,0.12)"; ctx.lineWidth = 3;
    for (let j = 1; j < this.nJ; j++) {
      const a = this.joint(f, j), b = this.joint(f, par[j]);
      line(ctx, proj([a[0], 0, a[2]]), proj([b[0], 0, b[2]]));
    }
    ctx.strokeStyle = this.color; ctx.lineWidth = 3; ctx.lineCap = "round";
    for (let j = 1; j < this.nJ; j++) line(ctx, proj(this.joint(f, j)), proj(this.joint(f, par[j])));
    ctx.fillStyle = this.color;
    for (let j = 0; j < this.nJ; j++) {
      const s = proj(this.joint(f, j));
      if (s) { ctx.beginPath(); ctx.arc(s[0], s[1], 2.5, 0, 2 * Math.PI); ctx.fill(); }
    }
  }
}

function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
function norm(a) { const n = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / n, a[1] / n, a[2] / n]; }
function line(ctx, a, b) { if (!a || !b) return; ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke(); }

// ------------------------------------------------------------------ state
const state = {
  clip: null, pose: null, time: 0, playing: false, speed: 1, sel: null,
  result: null, compare: [], compareTime: 0, comparePlaying: true, epsRange: null,
};
const view = new Figure($("view"));

// ------------------------------------------------------------------ catalog
async function loadStatus() {
  const s = await api("/api/status");
  if (!s.generation) { $("status").textContent = s.message; return s; }
  $("status").textContent = `generation ${s.generation} · ${s.clips} clips · ${s.webs} webs · ${s.rate} Hz`;
  const sel = $("f-category");
  const keep = sel.value;
  sel.length = 1;
  for (const c of Object.keys(s.categories).sort()) sel.add(new Option(`${c} (${s.categories[c]})`, c));
  sel.value = keep;
  return s;
}

let catalogTimer = null;
function catalogSoon() { clearTimeout(catalogTimer); catalogTimer = setTimeout(loadCatalog, 200); }

async function loadCatalog() {
  const q = new URLSearchParams();
  if ($("f-category").value) q.set("category", $("f-category").value);
  if ($("f-name").value) q.set("name", $("f-name").value);
  if ($("f-min").value) q.set("min_s", $("f-min").value);
  if ($("f-max").value) q.set("max_s", $("f-max").value);
  const c = await api("/api/catalog?" + q.toString());
  const body = $("catalog").tBodies[0];
  body.textContent = "";
  for (const clip of c.clips) {
    const tr = body.insertRow();
    tr.dataset.id = clip.id;
    for (const v of [clip.path, clip.category, clip.duration.toFixed(2), clip.frames ?? ""]) tr.insertCell().textContent = v;
    tr.addEventListener("click", () => openClip(clip.id).catch((e) => say(e.message)));
  }
  $("catalog-count").textContent = `${c.clips.length} of ${c.total} clips`;
}

// ------------------------------------------------------------------ player
async function openClip(id) {
  say("loading clip…");
  const pose = await api(`/api/clips/${id}/pose?rate=30`);
  showClip(pose, id);
  $("q-pick").value = "";
  $("clip-bvh").href = `/api/clips/${id}/bvh`; $("clip-bvh").classList.remove("hidden");
  $("clip-glb").href = `/api/clips/${id}/glb`; $("clip-glb").classList.remove("hidden");
}

// an uploaded clip (POST /api/uploads) in the player: its segment is then searched as the query
// (the service builds its webs against the index on demand, KG04 §3.3)
async function openUpload(id) {
  say("loading the uploaded clip…");
  const pose = await api(`/api/uploads/${id}/pose?rate=30`);
  showClip(pose, id);
  $("q-pick").value = id;
  $("clip-bvh").classList.add("hidden"); $("clip-glb").classList.add("hidden");
}

// a clip of the user's own: a BVH, or an ASF and its AMC, sent as text (POST /api/uploads), kept
// by the service in memory only (content-addressed: the same file twice is one upload); listed
// as a query of the search panel. unit: a BVH's length unit ("": the config's).
async function uploadClip(files, unit) {
  const byExt = {};
  for (const f of files) byExt[f.name.split(".").pop().toLowerCase()] = f;
  const body = { name: (byExt.bvh || byExt.amc || files[0]).name };
  if (byExt.bvh) body.bvh = await byExt.bvh.text();
  else if (byExt.asf && byExt.amc) { body.asf = await byExt.asf.text(); body.amc = await byExt.amc.text(); }
  else throw new Error("choose a .bvh file, or an .asf and its .amc");
  if (unit) body.unit = unit;
  say("uploading…");
  const up = await api("/api/uploads", {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  });
  say("");
  const pick = $("q-pick");
  if (![...pick.options].some((o) => o.value === up.id)) {
    pick.add(new Option(`${up.name} · ${up.duration.toFixed(2)} s (${up.id})`, up.id));
  }
  return up;
}

function showClip(pose, id) {
  state.clip = { ...pose, id }; state.pose = pose; state.time = 0;
  for (const tr of $("catalog").tBodies[0].rows) tr.classList.toggle("selected", tr.dataset.id === id);
  $("clip-title").textContent = `${pose.path} · ${pose.duration.toFixed(2)} s · ${pose.category}`;
  view.setPose(pose);
  const d = pose.duration;
  state.sel = [Math.min(d * 0.25, Math.max(0, d - 1)), Math.min(d, Math.max(d * 0.25, 0) + Math.min(1.5, d))];
  syncSegmentInputs();
  $("play").disabled = false; $("search").disabled = false;
  state.playing = true; $("play").textContent = "pause";
  drawTimeline();
  say("");
}

function clipDuration() { return state.pose ? (state.pose.frames - 1) / state.pose.rate : 0; }

function syncSegmentInputs() {
  if (!state.sel) return;
  $("seg-start").value = state.sel[0].toFixed(2);
  $("seg-end").value = state.sel[1].toFixed(2);
}

function drawTimeline() {
  const c = $("timeline"), ctx = c.getContext("2d"), w = c.width, h = c.height;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  const d = clipDuration();
  if (!d) return;
  const x = (t) => 8 + (w - 16) * t / d;
  ctx.fillStyle = "#eceff1"; ctx.fillRect(8, 4, w - 16, 20);
  ctx.fillStyle = "#cfd8dc"; ctx.fillRect(8, 30, w - 16, 20);
  if (state.sel) {
    ctx.fillStyle = "rgba(21,101,192,0.35)";
    ctx.fillRect(x(state.sel[0]), 30, x(state.sel[1]) - x(state.sel[0]), 20);
  }
  ctx.fillStyle = "#555"; ctx.font = "10px sans-serif";
  for (let t = 0; t <= d + 1e-9; t += d > 20 ? 5 : 1) { ctx.fillRect(x(t), 20, 1, 4); ctx.fillText(t.toFixed(0), x(t) + 2, 19); }
  ctx.fillStyle = "#c62828"; ctx.fillRect(x(state.time) - 1, 2, 2, h - 4);
  ctx.fillStyle = "#37474f"; ctx.fillText("drag to select a segment", 12, 44);
}

function timelineTime(e) {
  const c = $("timeline"), r = c.getBoundingClientRect();
  const px = (e.clientX - r.left) * c.width / r.width;
  return Math.max(0, Math.min(clipDuration(), (px - 8) / (c.width - 16) * clipDuration()));
}

function setupTimeline() {
  const c = $("timeline");
  let mode = null, anchor = 0;
  c.addEventListener("mousedown", (e) => {
    if (!state.pose) return;
    const r = c.getBoundingClientRect(), y = (e.clientY - r.top) * c.height / r.height;
    const t = timelineTime(e);
    if (y < 27) { mode = "scrub"; state.time = t; } else { mode = "select"; anchor = t; state.sel = [t, t]; }
    drawTimeline();
  });
  window.addEventListener("mousemove", (e) => {
    if (!mode) return;
    const t = timelineTime(e);
    if (mode === "scrub") state.time = t; else state.sel = [Math.min(anchor, t), Math.max(anchor, t)];
    syncSegmentInputs(); drawTimeline();
  });
  window.addEventListener("mouseup", () => { mode = null; });
  for (const id of ["seg-start", "seg-end"]) {
    $(id).addEventListener("change", () => {
      state.sel = [parseFloat($("seg-start").value) || 0, parseFloat($("seg-end").value) || 0];
      drawTimeline();
    });
  }
}

// ------------------------------------------------------------------ search and results
function epsLabel() {
  const v = parseFloat($("eps").value);
  $("eps-value").textContent = $("eps-mode").value === "quantile" ? v.toFixed(2) : v.toPrecision(3);
}

function setEpsMode() {
  const s = $("eps");
  if ($("eps-mode").value === "quantile") { s.min = 0.05; s.max = 0.99; s.step = 0.01; s.value = 0.8; }
  else {
    const top = state.result && state.result.epsilon !== null ? Math.max(state.result.epsilon * 2, 1e-3) : 1.0;
    s.min = 0; s.max = top; s.step = top / 200; s.value = state.result && state.result.epsilon !== null ? state.result.epsilon : top / 2;
  }
  epsLabel();
}

async function runSearch() {
  if (!state.clip || !state.sel) return;
  const body = { clip: state.clip.id, start: +state.sel[0].toFixed(3), end: +state.sel[1].toFixed(3),
    tiers: parseInt($("tiers").value, 10) || 1, all_categories: $("all-cats").checked };
  body[$("eps-mode").value] = parseFloat($("eps").value);
  say("searching…");
  const t0 = performance.now();
  const res = await api("/api/search", { method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body) });
  state.result = res;
  const eps = res.epsilon === null ? "none" : res.epsilon.toPrecision(4);
  $("result-info").textContent = `· ${res.matches.length} matches · ε = ${eps} · ` +
    `${(performance.now() - t0).toFixed(0)} ms` + (res.message ? ` · ${res.message}` : "");
  showRows(res);
  drawGraph(res);
  say("registering…");
  const reg = await api(`/api/results/${res.result}/registration`);
  drawWarps(reg, res);
  await loadCompare(res);
  say("");
}

function showRows(res) {
  const body = $("results").tBodies[0];
  body.textContent = "";
  for (const r of [res.query, ...res.matches]) {
    const tr = body.insertRow();
    const cells = [r.rank, r.clip, r.category, `${r.start_s.toFixed(2)}–${r.end_s.toFixed(2)}`, r.cost.toPrecision(3),
      r.tier, r.distance.toPrecision(3)];
    for (const v of cells) tr.insertCell().textContent = v;
    const dl = tr.insertCell();
    for (const [label, reg, fmt] of [["seg", false, "bvh"], ["reg", true, "bvh"], ["seg.glb", false, "glb"],
      ["reg.glb", true, "glb"]]) {
      const a = document.createElement("a");
      a.href = `/api/results/${res.result}/nodes/${r.rank}/${fmt}?registered=${reg}`;
      a.textContent = label; a.download = ""; a.title = reg ? "registered to the query's timing" : "the matched segment";
      a.addEventListener("click", (e) => e.stopPropagation());
      dl.append(a, " ");
    }
    tr.style.color = COLORS[r.rank % COLORS.length];
    tr.addEventListener("click", () => (r.id.startsWith("up-") ? openUpload : openClip)(r.id).then(() => {
      state.sel = [r.start_s, r.end_s]; state.time = r.start_s; syncSegmentInputs(); drawTimeline();
    }).catch((e) => say(e.message)));
  }
}

async function loadCompare(res) {
  const box = $("compare");
  box.textContent = "";
  state.compare = [];
  const ranks = [res.query, ...res.matches].slice(0, MAX_COMPARE + 1).map((r) => r.rank);
  const poses = await Promise.all(ranks.map((k) => api(`/api/results/${res.result}/nodes/${k}/pose?registered=true`)));
  poses.forEach((pose, i) => {
    const fig = document.createElement("figure");
    const c = document.createElement("canvas");
    c.width = 200; c.height = 180;
    const cap = document.createElement("figcaption");
    cap.textContent = `${pose.rank}: ${pose.path}`;
    cap.style.maxWidth = "200px";
    fig.append(c, cap);
    box.append(fig);
    const f = new Figure(c, COLORS[pose.rank % COLORS.length]);
    f.setPose(pose);
    state.compare.push(f);
  });
  state.compareTime = 0;
}

function drawGraph(res) {
  const c = $("graph"), ctx = c.getContext("2d"), w = c.width, h = c.height;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  const nodes = res.graph.nodes;
  const maxD = Math.max(1e-9, ...nodes.map((n) => n.distance)), maxT = Math.max(1, ...nodes.map((n) => n.tier));
  const pos = nodes.map((n, i) => [20 + (w - 40) * n.distance / maxD,
    h - 20 - (h - 40) * (n.tier + (n.tier ? 0.25 * Math.sin(i * 2.3) : 0)) / (maxT + 0.5)]);
  ctx.strokeStyle = "#ccc"; ctx.lineWidth = 1;
  for (const e of res.graph.edges) line(ctx, pos[e.u], pos[e.v]);
  nodes.forEach((n, i) => {
    ctx.fillStyle = COLORS[i % COLORS.length];
    ctx.beginPath(); ctx.arc(pos[i][0], pos[i][1], i ? 4 : 6, 0, 2 * Math.PI); ctx.fill();
  });
  ctx.fillStyle = "#555"; ctx.font = "10px sans-serif";
  ctx.fillText(`distance 0 … ${maxD.toPrecision(3)}`, 20, h - 5);
}

function drawWarps(reg, res) {
  const c = $("warps"), ctx = c.getContext("2d"), w = c.width, h = c.height;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  const n = reg.nodes[0].frames.length;
  let top = 1e-9;
  for (const nd of reg.nodes) top = Math.max(top, (nd.end - nd.start) / reg.rate);
  const X = (i) => 30 + (w - 40) * i / Math.max(1, n - 1), Y = (s) => h - 20 - (h - 30) * s / top;
  ctx.strokeStyle = "#999"; line(ctx, [30, h - 20], [w - 10, h - 20]); line(ctx, [30, 10], [30, h - 20]);
  for (const nd of reg.nodes) {
    ctx.strokeStyle = COLORS[nd.rank % COLORS.length]; ctx.lineWidth = nd.rank ? 1.2 : 2.5;
    ctx.beginPath();
    nd.frames.forEach((f, i) => { const p = [X(i), Y((f - nd.start) / reg.rate)]; if (i) ctx.lineTo(p[0], p[1]); else ctx.moveTo(p[0], p[1]); });
    ctx.stroke();
  }
  ctx.fillStyle = "#555"; ctx.font = "10px sans-serif";
  ctx.fillText("query frame u →", w - 100, h - 6); ctx.fillText(`${top.toFixed(2)} s`, 2, 14);
}

// ------------------------------------------------------------------ animation
let last = performance.now();
function tick(now) {
  const dt = Math.min(0.1, (now - last) / 1000);
  last = now;
  if (state.pose) {
    if (state.playing) {
      state.time += dt * state.speed;
      if (state.time > clipDuration()) state.time = 0;
    }
    view.draw(Math.round(state.time * state.pose.rate));
    $("time").textContent = `${state.time.toFixed(2)} s`;
    drawTimeline();
  }
  if (state.compare.length) {
    if (state.comparePlaying) state.compareTime += dt * state.speed;
    for (const f of state.compare) {
      const n = f.pose.frames;
      f.draw(Math.floor(state.compareTime * f.pose.rate) % n);
    }
  }
  requestAnimationFrame(tick);
}

// ------------------------------------------------------------------ GLB (glTF 2.0 binary) loader
// Plays a GLB in the player without any 3-D library: the GLB's JSON and BIN chunks, the skin's
// joints (their parents from the nodes' children), every node's translation and rotation as its
// LINEAR samplers give them at the first sampler's key times (nlerp between keys), composed along
// the node hierarchy into world positions (metres, y up): the pose the player draws. Scale and
// morph targets are ignored; what store/gltf.py writes (and any GLB with a skin and an animation)
// plays.
const GLB_ARRAYS = { 5121: Uint8Array, 5123: Uint16Array, 5125: Uint32Array, 5126: Float32Array };
const GLB_WIDTH = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4, MAT4: 16 };

function qmul(a, b) {  // x, y, z, w (glTF's order)
  return [a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1], a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
    a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3], a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2]];
}
function qrot(q, v) {
  const u = [q[0], q[1], q[2]], t = cross(u, v).map((x) => 2 * x), c = cross(u, t);
  return [v[0] + q[3] * t[0] + c[0], v[1] + q[3] * t[1] + c[1], v[2] + q[3] * t[2] + c[2]];
}

function glbPose(buf, name) {
  const dv = new DataView(buf);
  if (buf.byteLength < 20 || dv.getUint32(0, true) !== 0x46546c67) throw new Error(`${name}: not a GLB file`);
  let off = 12, json = null, bin = -1;
  while (off + 8 <= buf.byteLength) {
    const len = dv.getUint32(off, true), type = dv.getUint32(off + 4, true);
    if (type === 0x4e4f534a) json = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, off + 8, len)));
    else if (type === 0x004e4942) bin = off + 8;
    off += 8 + len;
  }
  if (!json || bin < 0 || !json.skins || !json.animations) throw new Error(`${name}: a GLB with a skin and an animation is needed`);
  const read = (k) => {
    const a = json.accessors[k], v = json.bufferViews[a.bufferView], Arr = GLB_ARRAYS[a.componentType];
    const start = bin + (v.byteOffset || 0) + (a.byteOffset || 0), n = a.count * GLB_WIDTH[a.type];
    return { width: GLB_WIDTH[a.type], data: new Arr(buf.slice(start, start + n * Arr.BYTES_PER_ELEMENT)) };
  };
  const nodes = json.nodes, anim = json.animations[0];
  const parent = nodes.map(() => -1);
  nodes.forEach((nd, i) => (nd.children || []).forEach((c) => { parent[c] = i; }));
  const order = [], seen = new Set();
  const visit = (i) => { if (seen.has(i)) return; if (parent[i] >= 0) visit(parent[i]); seen.add(i); order.push(i); };
  nodes.forEach((_, i) => visit(i));
  const times = read(anim.samplers[0].input).data, nF = times.length;
  const channels = anim.channels.filter((c) => c.target.path === "translation" || c.target.path === "rotation").map((c) => {
    const s = anim.samplers[c.sampler];
    return { node: c.target.node, path: c.target.path, input: read(s.input).data, output: read(s.output) };
  });
  const sample = (ch, t) => {  // LINEAR: lerp, nlerp for rotations along the shorter arc
    const x = ch.input, w = ch.output.width, o = ch.output.data;
    let i = 0;
    while (i < x.length - 2 && x[i + 1] <= t) i++;
    const s = x.length > 1 ? Math.max(0, Math.min(1, (t - x[i]) / ((x[i + 1] - x[i]) || 1))) : 0;
    const a = Array.from(o.subarray(i * w, i * w + w));
    if (x.length < 2) return a;
    const b = Array.from(o.subarray((i + 1) * w, (i + 1) * w + w));
    const sign = w === 4 && dot4(a, b) < 0 ? -1 : 1;
    const v = a.map((ai, k) => (1 - s) * ai + s * sign * b[k]);
    if (w !== 4) return v;
    const n = Math.hypot(...v) || 1;
    return v.map((c) => c / n);
  };
  const joints = json.skins[0].joints, nJ = joints.length, jointOf = new Map(joints.map((n, j) => [n, j]));
  const positions = new Float64Array(nF * nJ * 3);
  for (let f = 0; f < nF; f++) {
    const T = nodes.map((nd) => (nd.translation || [0, 0, 0]).slice()), R = nodes.map((nd) => (nd.rotation || [0, 0, 0, 1]).slice());
    for (const ch of channels) (ch.path === "translation" ? T : R)[ch.node] = sample(ch, times[f]);
    const wp = [], wq = [];
    for (const i of order) {
      const p = parent[i];
      wq[i] = p < 0 ? R[i] : qmul(wq[p], R[i]);
      const t = p < 0 ? T[i] : qrot(wq[p], T[i]);
      wp[i] = p < 0 ? t : [wp[p][0] + t[0], wp[p][1] + t[1], wp[p][2] + t[2]];
    }
    joints.forEach((n, j) => positions.set(wp[n], (f * nJ + j) * 3));
  }
  const parents = joints.map((n) => {
    let p = parent[n];
    while (p >= 0 && !jointOf.has(p)) p = parent[p];
    return p >= 0 ? jointOf.get(p) : -1;
  });
  const duration = nF > 1 ? times[nF - 1] - times[0] : 0;
  return { path: name, category: "GLB", duration, frames: nF, rate: nF > 1 ? (nF - 1) / duration : 30,
    parents, joints: joints.map((n) => nodes[n].name || `node ${n}`), positions: Array.from(positions) };
}
function dot4(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]; }

function playGlb(buf, name) {
  const pose = glbPose(buf, name);
  state.clip = pose; state.pose = pose; state.time = 0; state.glb = pose;
  $("clip-title").textContent = `${name} · ${pose.duration.toFixed(2)} s · GLB`;
  view.setPose(pose);
  $("play").disabled = false; $("search").disabled = true;
  state.playing = true; $("play").textContent = "pause";
  drawTimeline();
  say("");
  return pose;
}

// a GLB from this service (or any URL) in the player
async function openGlbUrl(url) {
  const resp = await fetch(url, { credentials: "same-origin" });
  if (!resp.ok) throw new Error(`${url}: HTTP ${resp.status}`);
  const named = /filename="([^"]+)"/.exec(resp.headers.get("content-disposition") || "");
  return playGlb(await resp.arrayBuffer(), named ? named[1] : url);
}

// ------------------------------------------------------------------ wiring
function setup() {
  setupTimeline();
  $("play").addEventListener("click", () => { state.playing = !state.playing; $("play").textContent = state.playing ? "pause" : "play"; });
  $("speed").addEventListener("change", () => { state.speed = parseFloat($("speed").value); });
  $("play-all").addEventListener("click", () => {
    state.comparePlaying = !state.comparePlaying; $("play-all").textContent = state.comparePlaying ? "pause" : "play";
  });
  $("eps").addEventListener("input", epsLabel);
  $("eps-mode").addEventListener("change", setEpsMode);
  $("search").addEventListener("click", () => runSearch().catch((e) => say(e.message)));
  $("q-upload").addEventListener("change", (e) => uploadClip([...e.target.files], $("q-upload-unit").value)
    .then((up) => openUpload(up.id)).catch((err) => say(err.message)));
  $("q-pick").addEventListener("change", () => { if ($("q-pick").value) openUpload($("q-pick").value).catch((e) => say(e.message)); });
  $("open-glb").addEventListener("change", (e) => {
    const file = e.target.files[0];
    if (file) file.arrayBuffer().then((b) => playGlb(b, file.name)).catch((err) => say(err.message));
  });
  for (const id of ["f-category", "f-name", "f-min", "f-max"]) $(id).addEventListener("input", catalogSoon);
  setupSpaces();
  epsLabel();
  loadStatus().then(loadCatalog).then(loadSpaces).catch((e) => say(e.message));
  // a newly committed generation (or a new space) shows up between requests; refresh now and then
  setInterval(() => { loadStatus().catch(() => {}); loadSpaces().catch(() => {}); }, 10000);
  requestAnimationFrame(tick);
}

// ------------------------------------------------------------------ motion spaces (KG04 §4)
// The sampled parameter cloud on a canvas, seen from above: x to the right, z up the canvas
// (for a 3-D position parameter the height y is a slider beside it; 1-D parameters lie on a
// line). Dragging the target asks the service for the motion that hits it (requests debounced,
// one in flight, the latest target wins) and plays that motion in the player.
const space = { info: null, target: null, result: null, busy: false, pending: false, timer: null, view: null };

async function loadSpaces() {
  const res = await api("/api/spaces");
  const sel = $("space");
  const keep = sel.value;
  sel.length = 0;
  for (const s of res.spaces) sel.add(new Option(`${s.id.slice(0, 12)} · ${s.param} · ${s.examples} examples`, s.id));
  if (!res.spaces.length) $("space-info").textContent = "no motion spaces yet: motionweb parameterize CONFIG …";
  if (keep && res.spaces.some((s) => s.id === keep)) sel.value = keep;
  if (res.spaces.length && (!space.info || space.info.id !== sel.value)) await openSpace(sel.value);
}

async function openSpace(id, synthesize) {
  const info = await api(`/api/spaces/${id}`);
  space.info = info; space.result = null;
  const all = info.samples.concat(info.example_params);
  const xs = all.map((p) => p[0]), zs = all.map((p) => (info.dim === 3 ? p[2] : info.dim === 2 ? p[1] : 0));
  const pad = (lo, hi) => { const m = Math.max(0.05, 0.15 * (hi - lo)); return [lo - m, hi + m]; };
  let [x0, x1] = pad(Math.min(...xs), Math.max(...xs)), [z0, z1] = pad(Math.min(...zs), Math.max(...zs));
  // equal scale on both axes (a top view); 1-D: a line across the middle
  const c = $("cloud"), span = Math.max((x1 - x0) / c.width, (z1 - z0) / c.height);
  const cx = (x0 + x1) / 2, cz = (z0 + z1) / 2;
  space.view = { cx, cz, s: span };
  const h = $("space-height");
  $("space-height-box").classList.toggle("hidden", info.dim !== 3);
  if (info.dim === 3) {
    h.min = info.lo[1]; h.max = info.hi[1]; h.step = Math.max(1e-4, (info.hi[1] - info.lo[1]) / 100);
    h.value = median(info.samples.map((p) => p[1]));
    $("space-height-value").textContent = parseFloat(h.value).toFixed(3);
  }
  const mid = info.samples[0] || info.example_params[0];
  space.target = mid.slice();
  if (info.dim === 3) space.target[1] = parseFloat(h.value);
  $("space-info").textContent = `${info.param} · ${info.names.length} examples · ${info.samples_total} samples` +
    (info.dim === 3 ? " · seen from above (x →, z ↑); height y on the slider" : info.dim === 2 ? " · x →, z ↑" : "");
  $("space-result").textContent = "drag the target on the cloud: its motion plays in the player";
  drawCloud();
  if (synthesize) synthesizeSoon(0);
}

function median(v) { const s = v.slice().sort((a, b) => a - b); return s.length ? s[s.length >> 1] : 0; }

function toCanvas(p) {
  const c = $("cloud"), v = space.view, d = space.info.dim;
  const z = d === 3 ? p[2] : d === 2 ? p[1] : v.cz;
  return [c.width / 2 + (p[0] - v.cx) / v.s, c.height / 2 - (z - v.cz) / v.s];
}

function fromCanvas(px, py) {
  const c = $("cloud"), v = space.view, d = space.info.dim;
  const x = v.cx + (px - c.width / 2) * v.s, z = v.cz - (py - c.height / 2) * v.s;
  if (d === 3) return [x, parseFloat($("space-height").value), z];
  if (d === 2) return [x, z];
  return [x];
}

function drawCloud() {
  const c = $("cloud"), ctx = c.getContext("2d"), w = c.width, h = c.height;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  if (!space.info) return;
  ctx.fillStyle = "rgba(96,125,139,0.45)";
  for (const p of space.info.samples) { const q = toCanvas(p); ctx.fillRect(q[0] - 1, q[1] - 1, 2, 2); }
  ctx.fillStyle = "#c62828"; ctx.font = "10px sans-serif";
  space.info.example_params.forEach((p, i) => {
    const q = toCanvas(p); ctx.fillRect(q[0] - 4, q[1] - 4, 8, 8); ctx.fillText(String(i), q[0] + 5, q[1] - 5);
  });
  const r = space.result;
  if (r && r.achieved) {
    const a = toCanvas(r.achieved), t = toCanvas(space.target);
    ctx.strokeStyle = "#2e7d32"; ctx.setLineDash([3, 3]); line(ctx, t, a); ctx.setLineDash([]);
    ctx.fillStyle = "#2e7d32"; ctx.beginPath(); ctx.arc(a[0], a[1], 4, 0, 2 * Math.PI); ctx.fill();
  }
  if (space.target) {
    const t = toCanvas(space.target);
    ctx.strokeStyle = "#1565c0"; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.arc(t[0], t[1], 7, 0, 2 * Math.PI); ctx.stroke();
    line(ctx, [t[0] - 11, t[1]], [t[0] + 11, t[1]]); line(ctx, [t[0], t[1] - 11], [t[0], t[1] + 11]);
    ctx.lineWidth = 1;
  }
  ctx.fillStyle = "#555";
  ctx.fillText("■ examples  · samples  ⊕ target  ● achieved", 6, h - 6);
}

function synthesizeSoon(delay) {
  clearTimeout(space.timer);
  space.timer = setTimeout(synthesizeNow, delay === undefined ? 90 : delay);
}

async function synthesizeNow() {
  if (!space.info || !space.target) return;
  if (space.busy) { space.pending = true; return; }
  space.busy = true;
  const id = space.info.id, target = space.target.slice();
  try {
    const t0 = performance.now();
    const r = await api(`/api/spaces/${id}/synthesize`, { method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ target: target.map((v) => +v.toFixed(4)) }) });
    if (!space.info || space.info.id !== id) return;
    space.result = r;
    const fmt = (v) => v.map((x) => x.toFixed(3)).join(", ");
    $("space-result").textContent = `target (${fmt(target)}) → achieved (${fmt(r.achieved)}) · ` +
      `${(100 * r.error).toFixed(1)} cm off · ${r.frames} frames · ${(performance.now() - t0).toFixed(0)} ms` +
      (r.outside ? ` · outside the sampled region: projected, ${(100 * r.error).toFixed(1)} cm from the target` : "");
    $("space-result").classList.toggle("outside", r.outside);
    showSynthesized(r);
    drawCloud();
    say("");
  } catch (e) {
    say(e.message);
  } finally {
    space.busy = false;
    if (space.pending) { space.pending = false; synthesizeSoon(0); }
  }
}

function showSynthesized(r) {
  const pose = r.pose;
  const keep = state.pose && state.pose.synthesized;
  state.clip = null; state.sel = null; state.pose = Object.assign(pose, { synthesized: true });
  if (!keep) {  // the first synthesized motion: the camera frames it and it plays
    state.time = 0; view.setPose(pose); state.playing = true; $("play").textContent = "pause";
  } else { view.pose = pose; view.nJ = pose.parents.length; }
  if (state.time > clipDuration()) state.time = 0;
  $("play").disabled = false;
  $("search").disabled = true; $("clip-bvh").classList.add("hidden"); $("clip-glb").classList.add("hidden");
  $("clip-title").textContent = `synthesized from space ${r.space.slice(0, 12)} · ${(r.frames / r.fps).toFixed(2)} s`;
}

function setupSpaces() {
  const c = $("cloud");
  let dragging = false;
  const move = (e) => {
    if (!space.info) return;
    const r = c.getBoundingClientRect();
    space.target = fromCanvas((e.clientX - r.left) * c.width / r.width, (e.clientY - r.top) * c.height / r.height);
    drawCloud(); synthesizeSoon();
  };
  c.addEventListener("pointerdown", (e) => { dragging = true; c.setPointerCapture(e.pointerId); move(e); });
  c.addEventListener("pointermove", (e) => { if (dragging) move(e); });
  c.addEventListener("pointerup", () => { dragging = false; });
  $("space").addEventListener("change", () => openSpace($("space").value, true).catch((e) => say(e.message)));
  $("space-height").addEventListener("input", () => {
    if (!space.target || space.info.dim !== 3) return;
    space.target[1] = parseFloat($("space-height").value);
    $("space-height-value").textContent = space.target[1].toFixed(3);
    drawCloud(); synthesizeSoon();
  });
}

setup();
