// worldagent explore: the page over one run. Plain JS, no dependencies, no build step.
// State lives in the URL hash (#view=world&env=racing&w=12 or &z=...&agent=run), so a link reopens a view.
"use strict";

const $ = (id) => document.getElementById(id);
const state = { run: null, env: null, map: null, metric: null, world: null, z: null, baseZ: null, players: [null, null], atlas: null, diff: null };
const VIRIDIS = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
const TRAILS = ["#1f5fe0", "#e0421f", "#1fa84a", "#c51fe0", "#e0a01f", "#1fc7e0", "#7a4b1f", "#555555"];
const MAP_PAD = 24;
const LONG_EPISODE = 400, RECENT_TRAIL = 60;  // steps

// -- plumbing -----------------------------------------------------------------------------

function status(text, isError = false) {
  const el = $("status");
  el.textContent = text;
  el.className = isError ? "error" : "";
}

async function api(path, options) {
  const response = await fetch(path, options);
  if (!response.ok) {
    let message = `${response.status}`;
    try { message = (await response.json()).error; } catch (_) { /* not JSON */ }
    throw new Error(message);
  }
  return response.json();
}

function envInfo() { return state.run.envs.find((e) => e.name === state.env); }
function fmt(v) { return v === null || v === undefined ? "n/a" : Math.abs(v) >= 1000 || Number.isInteger(v) ? String(Math.round(v * 100) / 100) : Number(v).toPrecision(3); }
function colour(t) {
  if (!Number.isFinite(t)) return "#bbb";
  const x = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1), i = Math.min(Math.floor(x), VIRIDIS.length - 2), f = x - i;
  const c = VIRIDIS[i].map((v, k) => Math.round(v + f * (VIRIDIS[i + 1][k] - v)));
  return `rgb(${c[0]},${c[1]},${c[2]})`;
}
function zParam(z) { return z.map((v) => v.toFixed(3)).join(","); }

function readHash() { return Object.fromEntries(new URLSearchParams(location.hash.slice(1))); }
function writeHash(params) {
  const clean = Object.fromEntries(Object.entries(params).filter(([, v]) => v !== null && v !== undefined && v !== ""));
  history.replaceState(null, "", "#" + new URLSearchParams(clean).toString());
}

// -- views --------------------------------------------------------------------------------

function show(view) {
  for (const button of document.querySelectorAll("#tabs button")) button.classList.toggle("active", button.dataset.view === view);
  for (const section of document.querySelectorAll(".view")) section.hidden = section.id !== `view-${view}`;
  state.view = view;
  if (view === "map" && state.map) drawMap();
  if (view === "atlas") loadAtlas();
  if (view === "failures") loadFailures();
  if (view === "diff") loadDiff();
  if (view !== "world") writeHash({ view, env: state.env, metric: state.metric });
}

async function selectEnv(name) {
  state.env = name;
  $("env").value = name;
  const info = envInfo();
  $("map-metric").innerHTML = info.metrics.map((m) => `<option>${m}</option>`).join("");
  state.metric = info.metrics.includes(state.metric) ? state.metric : info.main;
  $("map-metric").value = state.metric;
  for (const id of ["agent", "agent2"]) {
    const keep = id === "agent2" ? '<option value="">none</option>' : "";
    $(id).innerHTML = keep + info.agents.map((a) => `<option>${a}</option>`).join("");
  }
  $("event").placeholder = info.failure || "e.g. return < 0";
  $("diff-event").placeholder = info.failure || "e.g. return < 0";
  $("diff-tab").hidden = !info.diffs.length;
  $("diff-campaign").innerHTML = info.diffs.map((d) => `<option>${d}</option>`).join("");
  buildSliders(info.latent_dim);
  state.atlas = null;
  status(`loading the map of ${name} ...`);
  state.map = await api(`/api/${name}/map`);
  drawMap();
  status(`${name}: ${info.worlds} stored worlds`);
}

// -- map ----------------------------------------------------------------------------------

function mapScale() {
  const canvas = $("map-canvas"), xs = state.map.x, ys = state.map.y;
  const lo = [Math.min(...xs), Math.min(...ys)], hi = [Math.max(...xs), Math.max(...ys)];
  const span = Math.max(hi[0] - lo[0], hi[1] - lo[1], 1e-9), size = canvas.width - 2 * MAP_PAD;
  return (x, y) => [MAP_PAD + ((x - lo[0]) / span) * size, canvas.height - MAP_PAD - ((y - lo[1]) / span) * size];
}

function drawMap() {
  const canvas = $("map-canvas"), ctx = canvas.getContext("2d"), map = state.map;
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const n = map.x.length;
  canvas.dataset.points = String(n);
  if (!n) { ctx.fillText("no stored worlds", 20, 20); return; }
  const values = map.metrics[state.metric] || [];
  const finite = values.filter(Number.isFinite), lo = Math.min(...finite), hi = Math.max(...finite);
  const place = mapScale();
  state.screen = [];
  for (let i = 0; i < n; i++) {
    const [px, py] = place(map.x[i], map.y[i]);
    state.screen.push([px, py]);
    ctx.fillStyle = colour(hi > lo ? (values[i] - lo) / (hi - lo) : 0.5);
    ctx.beginPath();
    ctx.arc(px, py, 3, 0, 2 * Math.PI);
    ctx.fill();
  }
  $("map-legend").innerHTML = `${fmt(lo)} <i></i> ${fmt(hi)}`;
  canvas.dataset.metric = state.metric;
  drawMarker(ctx, place);
}

function drawMarker(ctx, place) {
  // the world open in the World view (a stored one, or G(z) as the sliders left it), on the same projection
  if (!state.z || state.z.length !== state.map.centre.length) { $("map-canvas").dataset.marker = ""; return; }
  const centred = state.z.map((v, d) => v - state.map.centre[d]);
  const [x, y] = state.map.axes.map((axis) => axis.reduce((sum, a, d) => sum + a * centred[d], 0));
  const [px, py] = place(x, y);
  ctx.strokeStyle = "#d62728";
  ctx.lineWidth = 2.5;
  ctx.beginPath();
  ctx.arc(px, py, 9, 0, 2 * Math.PI);
  ctx.stroke();
  $("map-canvas").dataset.marker = `${px.toFixed(1)},${py.toFixed(1)}`;
}

function nearestPoint(event) {
  const rect = $("map-canvas").getBoundingClientRect(), x = event.clientX - rect.left, y = event.clientY - rect.top;
  let best = -1, bestDistance = 64;  // within 8 px
  (state.screen || []).forEach(([px, py], i) => {
    const d = (px - x) ** 2 + (py - y) ** 2;
    if (d < bestDistance) { best = i; bestDistance = d; }
  });
  return best;
}

function hoverMap(event) {
  const i = nearestPoint(event), box = $("map-hover");
  if (i < 0) { box.hidden = true; return; }
  const [px, py] = state.screen[i], value = (state.map.metrics[state.metric] || [])[i];
  $("map-hover-img").src = `/api/${state.env}/world/${i}.png?size=160`;
  $("map-hover-text").textContent = `world ${i} · ${state.map.campaigns[state.map.campaign[i]]} · ${state.metric} ${fmt(value)}`;
  box.style.left = `${px + 12}px`;
  box.style.top = `${py + 12}px`;
  box.hidden = false;
}

// -- world --------------------------------------------------------------------------------

function buildSliders(dim) {
  $("sliders").innerHTML = Array.from({ length: dim }, (_, d) =>
    `<label>z${d} <input type="range" min="-4" max="4" step="0.05" value="0" data-dim="${d}"> <output>0.00</output></label>`).join("");
  for (const input of $("sliders").querySelectorAll("input")) input.addEventListener("input", onSlider);
}

function setSliders(z) {
  for (const input of $("sliders").querySelectorAll("input")) {
    const v = z[Number(input.dataset.dim)];
    input.value = String(v);
    input.nextElementSibling.textContent = v.toFixed(2);
  }
}

let sliderTimer = null;
function onSlider(event) {
  const d = Number(event.target.dataset.dim);
  state.z = state.z ? state.z.slice() : new Array(envInfo().latent_dim).fill(0);
  state.z[d] = Number(event.target.value);
  event.target.nextElementSibling.textContent = state.z[d].toFixed(2);
  if (state.world !== null) $("world-info").innerHTML = `<tr><td>moved from world ${state.world}</td><td></td></tr>`;
  state.world = null;  // the world is now G(z), not the stored one
  clearTimeout(sliderTimer);
  sliderTimer = setTimeout(() => { redrawLatent(); }, 60);
}

function redrawLatent() {
  setPicture(`/api/${state.env}/decode.png?z=${zParam(state.z)}`);
  $("world-title").textContent = `G(z) of ${state.env}`;
  updateExport();
  if (state.players.some((p) => p)) play();  // and replay on the new world
}

function setPicture(src) {
  for (const [i, id] of ["world-img", "world-img-2"].entries()) {
    const img = $(id);
    img.dataset.loaded = "0";
    img.onload = () => { img.dataset.loaded = "1"; img.dataset.src = src; };
    img.onerror = () => status(`picture failed: ${src}`, true);
    img.src = src;
    clearCanvas(i);
  }
}

async function openWorld(index) {
  show("world");
  state.world = index;
  const info = await api(`/api/${state.env}/world/${index}`);
  state.z = info.latent.slice();
  state.baseZ = info.latent.slice();
  setSliders(state.z);
  setPicture(`/api/${state.env}/world/${index}.png`);
  $("world-title").textContent = `world ${index} (${info.campaign}, generation ${info.generation}, slot ${info.slot})`;
  $("world-info").innerHTML = "<tr><th>stored</th><th>mean</th></tr>" +
    Object.entries(info.metrics).map(([k, v]) => `<tr><td>${k}</td><td>${fmt(v)}</td></tr>`).join("") +
    `<tr><td>log p(z)</td><td>${fmt(info.log_prior)}</td></tr><tr><td>episodes</td><td>${info.episodes}</td></tr>`;
  updateExport();
}

function openLatent(z) {
  show("world");
  state.world = null;
  state.z = z.slice();
  state.baseZ = z.slice();
  setSliders(z);
  $("world-info").innerHTML = "";
  redrawLatent();
}

function source() { return state.world !== null ? { world: state.world } : { z: state.z }; }
function sourceQuery() { return state.world !== null ? `world=${state.world}` : `z=${zParam(state.z)}`; }

function updateExport() {
  $("export-npz").href = `/api/${state.env}/export.npz?${sourceQuery()}`;
  $("export-json").href = `/api/${state.env}/export.json?${sourceQuery()}`;
  const params = { view: "world", env: state.env, agent: $("agent").value, agent2: $("agent2").value };
  if (state.world !== null) params.w = state.world; else params.z = zParam(state.z);
  writeHash(params);
  $("permalink").href = location.href;
}

async function play() {
  const agents = [$("agent").value, $("agent2").value];
  const body = { ...source(), episodes: Number($("episodes").value), seed: Number($("seed").value), size: 384 };
  status("playing ...");
  try {
    const results = await Promise.all(agents.map((agent) => agent ? api(`/api/${state.env}/play`, {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ ...body, agent }),
    }) : null));
    state.players = results;
    results.forEach((r, i) => showMetrics(i, r));
    results.forEach((r, i) => { if (r && r.still) $(i === 0 ? "world-img" : "world-img-2").src = r.still; });  // no animation: the env's own picture
    const longest = Math.max(...results.filter(Boolean).flatMap((r) => r.episodes.map((e) => e.steps)));
    $("frames").textContent = String(longest);
    animate(longest);
    status(`played ${body.episodes} episode(s)`);
  } catch (error) {
    status(error.message, true);
  }
}

function showMetrics(i, result) {
  const table = $(`metrics-${i + 1}`);
  if (!result) { table.innerHTML = ""; return; }
  table.innerHTML = `<tr><th>${result.agent}</th><th>mean of ${result.episodes.length}</th></tr>` +
    Object.entries(result.means).map(([k, v]) => `<tr><td>${k}</td><td>${fmt(v)}</td></tr>`).join("");
}

let animation = null;
function animate(longest) {
  cancelAnimationFrame(animation);
  const start = performance.now(), stepsPerSecond = Math.max(60, longest / 6);  // long episodes play in about 6 s
  const tick = (now) => {
    // a frame's timestamp may precede the click's performance.now(): never a negative step
    const frame = Math.min(longest, Math.max(0, Math.floor(((now - start) / 1000) * stepsPerSecond)));
    state.players.forEach((r, i) => drawFrame(i, r, frame));
    $("frame").textContent = String(frame);
    if (frame < longest) animation = requestAnimationFrame(tick);
  };
  animation = requestAnimationFrame(tick);
}

function clearCanvas(i) {
  const canvas = $(i === 0 ? "world-canvas" : "world-canvas-2");
  canvas.width = 384; canvas.height = 384;
  canvas.getContext("2d").clearRect(0, 0, 384, 384);
  canvas.dataset.frame = "0";
  canvas.dataset.marks = "0";
}

function drawFrame(i, result, frame) {
  const canvas = $(i === 0 ? "world-canvas" : "world-canvas-2"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  canvas.dataset.frame = String(frame);
  if (!result || !result.episodes.length || result.episodes[0].path === null) return;
  const scale = canvas.width / result.size;
  canvas.dataset.marks = String(result.marks ? drawMarks(ctx, result, frame, scale) : 0);
  result.episodes.forEach((episode, e) => {
    const last = Math.min(frame, episode.path.length - 1), agents = episode.path[0].length;
    for (let a = 0; a < agents; a++) {
      ctx.strokeStyle = TRAILS[(agents > 1 ? a : e) % TRAILS.length];
      ctx.globalAlpha = 0.8;
      ctx.lineWidth = 2.5;
      ctx.beginPath();
      // long episodes keep a recent trail only; an agent off the map (tagged out) breaks its trail
      const first = episode.path.length > LONG_EPISODE ? Math.max(0, last - RECENT_TRAIL) : 0;
      for (let t = first; t <= last; t++) {
        const [x, y] = episode.path[t][a];
        const joined = t > first && episode.present[t][a] && episode.present[t - 1][a];
        if (joined) ctx.lineTo(x * scale, y * scale); else ctx.moveTo(x * scale, y * scale);
      }
      ctx.stroke();
      ctx.globalAlpha = 1;
      if (episode.present[last][a]) {
        const [x, y] = episode.path[last][a];
        ctx.fillStyle = TRAILS[(agents > 1 ? a : e) % TRAILS.length];
        ctx.beginPath();
        ctx.arc(x * scale, y * scale, 5, 0, 2 * Math.PI);
        ctx.fill();
        ctx.strokeStyle = "#fff";
        ctx.stroke();
      }
    }
  });
}

// Marks (Pictures.marks): what the env shows besides the agents (harvest: apples, beams, tagged-out agents).
// Each episode carries, per kind, the steps where marks appear or vanish: [step, appeared [[x, y]], vanished [[x, y]]].
function marksAt(episode, frame) {
  // the marks there at `frame`, as {kind: Map("x,y" -> count)}: replayed on from the last frame asked, or from the start
  let cursor = episode.markCursor;
  if (!cursor || frame < cursor.frame) cursor = episode.markCursor = { frame: -1, next: {}, shown: {} };
  for (const [kind, changes] of Object.entries(episode.marks || {})) {
    const shown = cursor.shown[kind] || (cursor.shown[kind] = new Map());
    let k = cursor.next[kind] || 0;
    for (; k < changes.length && changes[k][0] <= frame; k++) {
      const [, appeared, vanished] = changes[k];
      for (const xy of vanished) {
        const key = xy.join(","), left = (shown.get(key) || 0) - 1;
        if (left > 0) shown.set(key, left); else shown.delete(key);
      }
      for (const xy of appeared) { const key = xy.join(","); shown.set(key, (shown.get(key) || 0) + 1); }
    }
    cursor.next[kind] = k;
  }
  cursor.frame = frame;
  return cursor.shown;
}

function drawMarks(ctx, result, frame, scale) {
  // the world's still picture dimmed, then every kind's marks at this frame; a mark in only some of the
  // episodes is fainter. Returns how many marks were drawn.
  ctx.fillStyle = "rgba(0, 0, 0, 0.45)";
  ctx.fillRect(0, 0, ctx.canvas.width, ctx.canvas.height);
  const counts = {};
  result.episodes.forEach((episode) => {
    for (const [kind, shown] of Object.entries(marksAt(episode, Math.min(frame, episode.steps)))) {
      const total = counts[kind] || (counts[kind] = new Map());
      shown.forEach((n, key) => total.set(key, (total.get(key) || 0) + Math.min(n, 1)));
    }
  });
  let drawn = 0;
  for (const [kind, style] of Object.entries(result.marks)) {
    const r = style.radius * scale;
    ctx.fillStyle = ctx.strokeStyle = style.colour;
    ctx.lineWidth = 2;
    (counts[kind] || new Map()).forEach((n, key) => {
      const [x, y] = key.split(",").map((v) => Number(v) * scale);
      ctx.globalAlpha = 0.3 + (0.7 * n) / result.episodes.length;
      ctx.beginPath();
      if (style.shape === "square") ctx.fillRect(x - r, y - r, 2 * r, 2 * r);
      else if (style.shape === "ring") { ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.stroke(); }
      else { ctx.arc(x, y, r, 0, 2 * Math.PI); ctx.fill(); }
      drawn++;
    });
  }
  ctx.globalAlpha = 1;
  return drawn;
}

async function saveWorld() {
  try {
    const saved = await api(`/api/${state.env}/save`, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(source()) });
    status(`saved ${saved.saved}`);
  } catch (error) { status(error.message, true); }
}

// -- atlas --------------------------------------------------------------------------------

async function loadAtlas() {
  const info = envInfo(), canvas = $("atlas-canvas"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!info.atlases.length) { $("atlas-title").textContent = `${state.env} has no atlas in its store`; canvas.dataset.cells = "0"; return; }
  try {
    state.atlas = state.atlas || await api(`/api/${state.env}/atlas`);
  } catch (error) { status(error.message, true); return; }
  const atlas = state.atlas, [cols, rows] = atlas.size, w = canvas.width / cols, h = canvas.height / rows;
  const scores = atlas.cells.map((c) => c.score), lo = Math.min(...scores), hi = Math.max(...scores);
  for (const cell of atlas.cells) {
    ctx.fillStyle = colour(hi > lo ? (cell.score - lo) / (hi - lo) : 0.5);
    ctx.fillRect(cell.x * w, canvas.height - (cell.y + 1) * h, w - 1, h - 1);
  }
  canvas.dataset.cells = String(atlas.cells.length);
  $("atlas-title").textContent = `${atlas.name}: ${atlas.metric} (${atlas.maximize ? "best" : "worst"} world per cell, ${fmt(lo)} to ${fmt(hi)}); x: ${atlas.descriptors[0]}, y: ${atlas.descriptors[1] || "-"}`;
}

function atlasCellAt(event) {
  const atlas = state.atlas, canvas = $("atlas-canvas"), rect = canvas.getBoundingClientRect();
  if (!atlas) return null;
  const [cols, rows] = atlas.size;
  const x = Math.floor(((event.clientX - rect.left) / rect.width) * cols), y = rows - 1 - Math.floor(((event.clientY - rect.top) / rect.height) * rows);
  return atlas.cells.find((c) => c.x === x && c.y === y) || null;
}

// -- failures -----------------------------------------------------------------------------

async function loadFailures() {
  const event = $("event").value.trim(), by = $("rank-by").value;
  const query = new URLSearchParams({ by, limit: "20", ...(event ? { event } : {}) });
  const table = $("failures-table");
  try {
    const found = await api(`/api/${state.env}/failures?${query}`);
    $("failures-summary").textContent = `${found.failing} of ${found.worlds} stored evaluations fail (${found.event}): ${found.distinct} distinct worlds, ranked by ${found.by}`;
    const metricNames = found.rows.length ? Object.keys(found.rows[0].metrics) : [];
    table.innerHTML = `<tr><th>#</th><th>failing world</th><th>log p(z)</th><th>severity</th><th>times evaluated</th>${metricNames.map((m) => `<th>${m}</th>`).join("")}<th>nearest passing world</th><th>latent distance</th></tr>` +
      found.rows.map((row, k) => `<tr><td class="num">${k + 1}</td>` +
        `<td><img loading="lazy" data-world="${row.index}" src="/api/${state.env}/world/${row.index}.png?size=72" alt="world ${row.index}"> ${row.index}</td>` +
        `<td class="num">${fmt(row.log_prior)}</td><td class="num">${fmt(row.severity)}</td><td class="num">${row.evaluations}</td>` +
        metricNames.map((m) => `<td class="num">${fmt(row.metrics[m])}</td>`).join("") +
        (row.nearest_passing === null ? "<td>none</td><td></td>" :
          `<td><img loading="lazy" data-world="${row.nearest_passing}" src="/api/${state.env}/world/${row.nearest_passing}.png?size=72" alt="world ${row.nearest_passing}"> ${row.nearest_passing}</td><td class="num">${fmt(row.distance)}</td>`) +
        "</tr>").join("");
  } catch (error) {
    status(error.message, true);
    table.innerHTML = "";
  }
}

// -- diff: two agents' regressed worlds -----------------------------------------------------

async function loadDiff() {
  const event = $("diff-event").value.trim(), campaign = $("diff-campaign").value;
  const query = new URLSearchParams({ limit: "20", ...(campaign ? { campaign } : {}), ...(event ? { event } : {}) });
  const table = $("diff-table");
  try {
    const found = await api(`/api/${state.env}/diff?${query}`);
    state.diff = found;
    $("diff-summary").textContent = `${found.campaign}: ${found.regressed} of ${found.worlds} worlds regressed (${found.event}), ${found.improved} improved`;
    const names = found.rows.length ? Object.keys(found.rows[0].a) : [];
    const picture = (i) => `<img loading="lazy" data-world="${i}" src="/api/${state.env}/world/${i}.png?size=72" alt="world ${i}"> ${i}`;
    table.innerHTML = `<tr><th>#</th><th>regressed world</th><th>log p(z)</th>${names.map((m) => `<th>${m} A → B</th>`).join("")}<th>nearest world where B passes</th><th>latent distance</th></tr>` +
      found.rows.map((row, k) => `<tr><td class="num">${k + 1}</td><td>${picture(row.index)}</td><td class="num">${fmt(row.log_prior)}</td>` +
        names.map((m) => `<td class="num">${fmt(row.a[m])} → ${fmt(row.b[m])}</td>`).join("") +
        (row.nearest_passing === null ? "<td>none</td><td></td>" : `<td>${picture(row.nearest_passing)}</td><td class="num">${fmt(row.distance)}</td>`) +
        "</tr>").join("");
  } catch (error) {
    status(error.message, true);
    table.innerHTML = "";
  }
}

async function openDiff(index) {
  // the World view with the diff's A and B as its two agents, played at once
  const [a, b] = (state.diff && state.diff.agents) || [];
  if (a) $("agent").value = a;
  if (b) $("agent2").value = b;
  await openWorld(index);
  if (a || b) play();
}

// -- start --------------------------------------------------------------------------------

async function start() {
  try {
    state.run = await api("/api/run");
  } catch (error) { status(error.message, true); return; }
  const hash = readHash();
  $("env").innerHTML = state.run.envs.map((e) => `<option>${e.name}</option>`).join("");
  state.metric = hash.metric || null;
  await selectEnv(state.run.envs.some((e) => e.name === hash.env) ? hash.env : state.run.envs[0].name);
  for (const [id, key] of [["agent", "agent"], ["agent2", "agent2"]]) if (hash[key]) $(id).value = hash[key];
  if (hash.view === "world" && hash.w !== undefined) await openWorld(Number(hash.w));
  else if (hash.view === "world" && hash.z) openLatent(hash.z.split(",").map(Number));
  else show(hash.view && hash.view !== "world" ? hash.view : "map");
  document.body.dataset.ready = "1";
}

$("env").addEventListener("change", (e) => selectEnv(e.target.value).then(() => show(state.view || "map")));
$("map-metric").addEventListener("change", (e) => { state.metric = e.target.value; drawMap(); writeHash({ view: "map", env: state.env, metric: state.metric }); });
$("map-canvas").addEventListener("mousemove", hoverMap);
$("map-canvas").addEventListener("mouseleave", () => { $("map-hover").hidden = true; });
$("map-canvas").addEventListener("click", (e) => { const i = nearestPoint(e); if (i >= 0) openWorld(i); });
$("atlas-canvas").addEventListener("click", (e) => { const cell = atlasCellAt(e); if (cell) openWorld(cell.world); });
$("failures-table").addEventListener("click", (e) => { if (e.target.dataset.world) openWorld(Number(e.target.dataset.world)); });
$("failures-go").addEventListener("click", loadFailures);
$("diff-table").addEventListener("click", (e) => { if (e.target.dataset.world) openDiff(Number(e.target.dataset.world)); });
$("diff-go").addEventListener("click", loadDiff);
$("diff-campaign").addEventListener("change", loadDiff);
$("rank-by").addEventListener("change", loadFailures);
$("play").addEventListener("click", play);
$("save").addEventListener("click", saveWorld);
$("agent").addEventListener("change", updateExport);
$("agent2").addEventListener("change", updateExport);
$("reset-z").addEventListener("click", () => { if (state.baseZ) { setSliders(state.baseZ); state.z = state.baseZ.slice(); redrawLatent(); } });
for (const button of document.querySelectorAll("#tabs button")) button.addEventListener("click", () => show(button.dataset.view));
window.explorer = { state, openWorld, openLatent, play, drawFrame, openDiff };  // for scripts and the browser tests
start();
