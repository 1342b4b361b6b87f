// worldagent explore: the page over one run. Plain JS, no dependencies, no build step; plots.js (scales, colour bars,
// axes) and world.js (the World view: sliders, plays, legends, the animation) load first.
// State lives in the URL hash (#view=world&env=racing&w=12 or &z=...&agent=run), so a link reopens a view.
// Every answer is tied to what asked for it: opening a world (or env) bumps `state.generation`, each play
// `state.playSeq`, each view's load its `ticket`; an answer for an older one is dropped, a superseded play's
// request is aborted here and, if it still waits on the server, skipped there (it carries this page's CLIENT id
// and its seq). The status line belongs to the view on screen and its latest request: a view change restates or
// clears it, a new world clears it, and an answer no longer current writes none.
"use strict";

const $ = (id) => document.getElementById(id);
// plots.js (loaded first) gives fmt, esc, colourScale, renderColourBar, niceTicks, renderTicks, drawShape, drawMarker, drawCross.
const state = {
  run: null, env: null, map: null, metric: null, world: null, z: null, baseZ: null, players: [null, null], atlas: null, diff: null,
  generation: 0, playSeq: 0, played: false, hidden: new Set(), tickets: {}, stats: { plays: 0, shown: 0, dropped: 0 },
};
const FAIL_RING = "#d62728";
const MAP_PAD = 24;

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
    const error = new Error(message);
    error.status = response.status;
    throw error;
  }
  return response.json();
}

function ticket(name) {
  // a number for the latest request of one kind: an answer whose ticket is no longer the latest is stale
  state.tickets[name] = (state.tickets[name] || 0) + 1;
  const mine = state.tickets[name], env = state.env;
  return () => state.tickets[name] === mine && state.env === env;
}

function viewError(view, fresh, error) {
  // a failed load says so in the status line only while it is the latest of its kind and its view is on screen
  if (fresh() && state.view === view) status(error.message, true);
}

function envInfo() { return state.run.envs.find((e) => e.name === state.env); }
function meaning(metric) { return (envInfo().meanings || {})[metric] || ""; }
function campaignWords(id) {
  // a campaign in words (search.names.describe_campaign, from its recorded config), or its id where the store has no record
  const words = (envInfo().campaign_words || {})[id];
  return words && words !== id ? words : "";
}
function campaignHtml(id) { const words = campaignWords(id); return words ? `${esc(words)} <code>${esc(id)}</code>` : `<code>${esc(id)}</code>`; }
function campaignOptions(ids) { return ids.map((d) => `<option value="${esc(d)}">${esc(campaignWords(d) ? `${campaignWords(d)} (${d})` : d)}</option>`).join(""); }
function zParam(z) { return z.map((v) => v.toFixed(3)).join(","); }

function readHash() { return Object.fromEntries(new URLSearchParams(location.hash.slice(1))); }
function writeHash(params) {
  const clean = Object.fromEntries(Object.entries(params).filter(([, v]) => v !== null && v !== undefined && v !== ""));
  history.replaceState(null, "", location.pathname + "#" + new URLSearchParams(clean).toString());  // never the ?token= query
}

// -- views --------------------------------------------------------------------------------

function show(view) {
  if (view === "diff" && !(envInfo().diffs || []).length) view = "map";  // this environment has no diff: its tab is hidden
  for (const button of document.querySelectorAll("#tabs button")) button.classList.toggle("active", button.dataset.view === view);
  for (const section of document.querySelectorAll(".view")) section.hidden = section.id !== `view-${view}`;
  state.view = view;
  status(view === "map" && state.map ? mapStatus() : "");  // no other view's (or an earlier request's) text stays
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
  newWorld();  // nothing of the previous environment's plays stays on screen
  state.world = null; state.z = null; state.baseZ = null; state.played = false;
  $("world-title").textContent = ""; $("world-info").innerHTML = "";
  $("map-metric").innerHTML = info.metrics.map((m) => `<option title="${esc(meaning(m))}">${esc(m)}</option>`).join("");
  state.metric = info.metrics.includes(state.metric) ? state.metric : info.main;
  $("map-metric").value = state.metric;
  metricMeaning();
  for (const id of ["agent", "agent2"]) {
    const keep = id === "agent2" ? '<option value="">none</option>' : "";
    $(id).innerHTML = keep + info.agents.map((a) => `<option>${esc(a)}</option>`).join("");
  }
  $("event").placeholder = info.failure || "e.g. return < 0";
  $("diff-event").placeholder = info.failure || "e.g. return < 0";
  $("diff-tab").hidden = !info.diffs.length;
  $("diff-campaign").innerHTML = campaignOptions(info.diffs);
  clearTables();
  buildSliders(info.latent_dim);
  worldLegend();
  state.atlas = null;
  state.map = null;
  state.hidden = new Set();
  status(`loading the map of ${name} ...`);
  const map = await api(`/api/${name}/map`);
  if (state.env !== name) return;  // another environment was chosen meanwhile
  state.map = map;
  campaignLegend();
  drawMap();
  if (state.view === "map" || !state.view) status(mapStatus());
}

function mapStatus() { return `${state.env}: ${envInfo().worlds} stored evaluations`; }

function clearTables() {
  // another environment: no table or summary of the previous one stays, and its answers still on the way are dropped
  for (const name of ["failures", "diff"]) ticket(name);
  state.diff = null;
  for (const id of ["failures-table", "diff-table"]) $(id).innerHTML = "";
  for (const id of ["failures-summary", "diff-summary"]) $(id).textContent = "";
}

// -- map ----------------------------------------------------------------------------------

function mapScale() {
  // the same scale on both axes (distances in z read alike): data [lo, lo + span] fills the canvas within MAP_PAD
  const canvas = $("map-canvas"), xs = state.map.x, ys = state.map.y;
  const lo = [Math.min(...xs), Math.min(...ys)], hi = [Math.max(...xs), Math.max(...ys)];
  const span = Math.max(hi[0] - lo[0], hi[1] - lo[1], 1e-9), size = canvas.width - 2 * MAP_PAD;
  const place = (x, y) => [MAP_PAD + ((x - lo[0]) / span) * size, canvas.height - MAP_PAD - ((y - lo[1]) / span) * size];
  place.range = [[lo[0] - (MAP_PAD / size) * span, lo[0] + (1 + MAP_PAD / size) * span], [lo[1] - (MAP_PAD / size) * span, lo[1] + (1 + MAP_PAD / size) * span]];
  return place;
}

function mapVisible(i) {
  const map = state.map;
  if (state.hidden.has(map.campaign[i])) return false;
  return !$("map-failing-only").checked || !map.failing || map.failing[i] === 1;
}

function drawMap() {
  const canvas = $("map-canvas"), ctx = canvas.getContext("2d"), map = state.map, info = envInfo();
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const n = map.x.length;
  canvas.dataset.points = String(n);
  if (!n) { ctx.fillText("no stored worlds", 20, 20); return; }
  const values = map.metrics[state.metric] || [];
  const threshold = (info.thresholds || {})[state.metric];
  const kind = $("map-scale").value === "auto" ? (threshold ? "diverging" : "quantile") : $("map-scale").value;
  const scale = colourScale(values, kind, threshold, worseEnd(state.metric) === "low");  // the worse end yellow, as the report
  const place = mapScale();
  drawMapAxes(ctx, place);
  state.screen = new Array(n).fill(null);
  const order = [...Array(n).keys()].sort((a, b) => (map.failing ? map.failing[a] - map.failing[b] : 0));  // failing ones on top
  for (const i of order) {
    if (!mapVisible(i)) continue;
    const [px, py] = place(map.x[i], map.y[i]);
    state.screen[i] = [px, py];
    drawMarker(ctx, map.markers[map.campaign[i]], px, py, 3.2, scale.colourOf(i), map.failing && map.failing[i] ? FAIL_RING : null);
  }
  renderColourBar($("map-colourbar"), `${state.metric}: each world's mean over its episodes`, scale.bar, threshold ? "" : worseNote(state.metric));
  canvas.dataset.metric = state.metric;
  canvas.dataset.scale = scale.kind;
  failingLegend();
  shareLegend();
  drawOpenWorld(ctx, place);
}

function metricMeaning() {
  // what the chosen metric measures (the env spec's Metrics.meanings): the select's tooltip and a line of the map's legend
  const text = meaning(state.metric);
  $("map-metric").title = text ? `${state.metric}: ${text}` : "";
  $("map-meaning").hidden = !text;
  $("map-meaning").innerHTML = text ? `<div class="row"><b>${esc(state.metric)}</b>: ${esc(text)}</div>` : "";
}

function worseEnd(metric) { return (envInfo().worse || {})[metric] || null; }

function worseNote(metric) {
  // which end is the worse one (the failure event's side, or the side a failure atlas searched), painted yellow as the report does
  const worse = worseEnd(metric);
  if (!worse) return "dark purple: lowest, yellow: highest (this run does not say which end is worse).";
  return `yellow: the worse end (${worse === "low" ? "lowest" : "highest"} ${metric}), dark purple: the better end, as in the report's figures.`;
}

function shareLegend() {
  // the world's share of an episode's outcome, from the stored random campaign (nothing without one)
  const el = $("map-share"), share = state.map.share;
  el.hidden = !share;
  el.innerHTML = share ? `<div class="row" title="one-way random-effects ICC (95% interval); docs/noise.md says how to read it">${esc(share.line)}</div>` : "";
}

function drawMapAxes(ctx, place) {
  // light grid lines on the canvas; tick values and axis names as HTML beside it
  const canvas = $("map-canvas"), [xr, yr] = place.range, explained = state.map.explained || [];
  const xs = niceTicks(xr[0], xr[1], 6), ys = niceTicks(yr[0], yr[1], 6);
  ctx.strokeStyle = "#eee"; ctx.lineWidth = 1;
  const toX = (v) => ((v - xr[0]) / (xr[1] - xr[0])) * canvas.width, toY = (v) => canvas.height - ((v - yr[0]) / (yr[1] - yr[0])) * canvas.height;
  for (const v of xs) { ctx.beginPath(); ctx.moveTo(toX(v), 0); ctx.lineTo(toX(v), canvas.height); ctx.stroke(); }
  for (const v of ys) { ctx.beginPath(); ctx.moveTo(0, toY(v)); ctx.lineTo(canvas.width, toY(v)); ctx.stroke(); }
  const shown = canvas.clientWidth / canvas.width || 1;
  renderTicks($("map-xticks"), xs.map((v) => ({ px: toX(v) * shown, text: fmt(v) })), false);
  renderTicks($("map-yticks"), ys.map((v) => ({ px: toY(v) * shown, text: fmt(v) })), true);
  const share = (k) => (Number.isFinite(explained[k]) ? `, ${Math.round(100 * explained[k])}% of their variance` : "");
  $("map-xlabel").textContent = `principal axis 1 of the stored latents z${share(0)}`;
  $("map-ylabel").textContent = `principal axis 2 of z${share(1)}`;
}

function campaignLegend() {
  // one marker per campaign (its shape, filled or hollow: views.campaign_markers); a click on a campaign hides or shows its worlds
  const map = state.map, counts = map.campaigns.map(() => 0);
  map.campaign.forEach((c) => counts[c]++);
  const repeats = map.campaigns.length > map.distinct_markers ?
    `<div class="row">campaigns past the ${map.distinct_markers}th reuse the markers of the first ones: untick campaigns to tell them apart</div>` : "";
  $("map-campaigns").innerHTML = "<h4>campaigns (marker: shape, filled or hollow)</h4>" + map.campaigns.map((name, c) =>
    `<label class="row"><input type="checkbox" data-campaign="${c}" checked><canvas class="mk" width="16" height="16" data-campaign="${c}"></canvas><span>${campaignHtml(name)} (${counts[c]})</span></label>`).join("") + repeats;
  for (const canvas of $("map-campaigns").querySelectorAll("canvas")) {
    drawMarker(canvas.getContext("2d"), map.markers[Number(canvas.dataset.campaign)], 8, 8, 4.5, "#555", null);
  }
  for (const box of $("map-campaigns").querySelectorAll("input")) {
    box.addEventListener("change", () => { const c = Number(box.dataset.campaign); box.checked ? state.hidden.delete(c) : state.hidden.add(c); drawMap(); });
  }
}

function failingLegend() {
  const map = state.map, el = $("map-failing-legend");
  if (!map.failing) { el.innerHTML = `<div class="row">no failure event is defined for these worlds' metrics</div>`; return; }
  const count = map.failing.reduce((a, b) => a + b, 0);
  el.innerHTML = `<div class="row"><span class="sym" style="color:${FAIL_RING}">○</span>red outline: fails ${esc(map.failure)} (${count} of ${map.failing.length} stored evaluations)</div>` +
    `<div class="row"><span class="sym" style="color:${FAIL_RING}">◯</span>large red ring: the world open in the World view</div>`;
}

function drawOpenWorld(ctx, place) {
  // the world open in the World view (a stored one, or G(z) as the sliders left it), on the same projection
  if (!state.z || state.z.length !== state.map.centre.length) { $("map-canvas").dataset.marker = ""; return; }
  const centred = state.z.map((v, d) => v - state.map.centre[d]);
  const [x, y] = state.map.axes.map((axis) => axis.reduce((sum, a, d) => sum + a * centred[d], 0));
  const [px, py] = place(x, y);
  ctx.strokeStyle = FAIL_RING;
  ctx.lineWidth = 2.5;
  ctx.beginPath();
  ctx.arc(px, py, 9, 0, 2 * Math.PI);
  ctx.stroke();
  $("map-canvas").dataset.marker = `${px.toFixed(1)},${py.toFixed(1)}`;
}

function nearestPoint(event) {
  const rect = $("map-canvas").getBoundingClientRect(), x = event.clientX - rect.left, y = event.clientY - rect.top;
  let best = -1, bestDistance = 64;  // within 8 px
  (state.screen || []).forEach((point, i) => {
    if (!point) return;
    const d = (point[0] - x) ** 2 + (point[1] - y) ** 2;
    if (d < bestDistance) { best = i; bestDistance = d; }
  });
  return best;
}

function hoverMap(event) {
  const i = nearestPoint(event), box = $("map-hover"), map = state.map;
  if (i < 0) { box.hidden = true; return; }
  const [px, py] = state.screen[i], value = (map.metrics[state.metric] || [])[i];
  $("map-hover-img").src = `/api/${state.env}/world/${i}.png?size=160`;
  const failing = map.failing ? (map.failing[i] ? ` · fails ${map.failure}` : " · passes") : "";
  $("map-hover-text").textContent = `world ${i} · ${campaignWords(map.campaigns[map.campaign[i]]) || map.campaigns[map.campaign[i]]} · ${state.metric} ${fmt(value)}${failing}`;
  box.style.left = `${px + 12}px`;
  box.style.top = `${py + 12}px`;
  box.hidden = false;
}

// -- atlas --------------------------------------------------------------------------------

function atlasEdges(atlas, d) {
  // the descriptor's value at each cell edge along axis d
  const [lo, hi] = atlas.ranges[d] || [0, 1], cells = atlas.size[d];
  return Array.from({ length: cells + 1 }, (_, k) => lo + (k * (hi - lo)) / cells);
}

async function loadAtlas() {
  const info = envInfo(), canvas = $("atlas-canvas"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!info.atlases.length) { $("atlas-title").textContent = `${state.env} has no atlas in its store`; canvas.dataset.cells = "0"; return; }
  const fresh = ticket("atlas");
  try {
    const atlas = state.atlas || await api(`/api/${state.env}/atlas`);
    if (!fresh()) return;
    state.atlas = atlas;
  } catch (error) { viewError("atlas", fresh, error); return; }
  const atlas = state.atlas, [cols, rows] = atlas.size, w = canvas.width / cols, h = canvas.height / rows;
  const worst = atlas.maximize ? "highest" : "lowest";
  // yellow: the extreme the atlas searched for (its worst worlds), as the report's atlas figure paints it (viridis_r when it
  // minimised); on a quantile scale so a long tail does not flatten the rest
  const scale = colourScale(atlas.cells.map((c) => c.score), "quantile", null, !atlas.maximize, "cells");
  atlas.cells.forEach((cell, k) => {
    ctx.fillStyle = scale.colourOf(k);
    ctx.fillRect(cell.x * w, canvas.height - (cell.y + 1) * h, w - 1, h - 1);
  });
  canvas.dataset.cells = String(atlas.cells.length);
  const every = (n) => (n > 10 ? 2 : 1), shown = canvas.clientWidth / canvas.width || 1;
  renderTicks($("atlas-xticks"), atlasEdges(atlas, 0).map((v, k) => ({ px: k * w * shown, text: k % every(cols) ? "" : fmt(v) })), false);
  renderTicks($("atlas-yticks"), (atlas.descriptors[1] ? atlasEdges(atlas, 1) : []).map((v, k) => ({ px: canvas.clientHeight - k * h * shown, text: k % every(rows) ? "" : fmt(v) })), true);
  $("atlas-xlabel").textContent = `${atlas.descriptors[0]} (descriptor of the world, ${cols} cells)`;
  $("atlas-ylabel").textContent = atlas.descriptors[1] ? `${atlas.descriptors[1]} (${rows} cells)` : "one row";
  renderColourBar($("atlas-colourbar"), `${atlas.metric}: each cell's ${atlas.maximize ? "best" : "worst"} world`, scale.bar,
    `Yellow: the ${worst} ${atlas.metric}, the worst worlds the atlas found (as in the report's atlas figure); empty cells: no world found there.`);
  $("atlas-title").textContent = `${atlas.name}: ${atlas.cells.length} of ${cols * rows} cells filled, ${atlas.metric} from ${fmt(Math.min(...atlas.cells.map((c) => c.score)))} to ${fmt(Math.max(...atlas.cells.map((c) => c.score)))}`;
}

function atlasCellAt(event) {
  const atlas = state.atlas, canvas = $("atlas-canvas"), rect = canvas.getBoundingClientRect();
  if (!atlas) return null;
  const [cols, rows] = atlas.size;
  const x = Math.floor(((event.clientX - rect.left) / rect.width) * cols), y = rows - 1 - Math.floor(((event.clientY - rect.top) / rect.height) * rows);
  return atlas.cells.find((c) => c.x === x && c.y === y) || null;
}

function hoverAtlas(event) {
  const cell = atlasCellAt(event), box = $("atlas-hover"), atlas = state.atlas;
  if (!cell) { box.hidden = true; return; }
  const rect = $("atlas-canvas").getBoundingClientRect(), xs = atlasEdges(atlas, 0), ys = atlas.descriptors[1] ? atlasEdges(atlas, 1) : null;
  $("atlas-hover-img").src = `/api/${state.env}/world/${cell.world}.png?size=160`;
  $("atlas-hover-text").textContent = `${atlas.descriptors[0]} ${fmt(xs[cell.x])}–${fmt(xs[cell.x + 1])}` +
    (ys ? `, ${atlas.descriptors[1]} ${fmt(ys[cell.y])}–${fmt(ys[cell.y + 1])}` : "") + ` · ${atlas.metric} ${fmt(cell.score)} · world ${cell.world}`;
  box.style.left = `${event.clientX - rect.left + 12}px`;
  box.style.top = `${event.clientY - rect.top + 12}px`;
  box.hidden = false;
}

// -- failures -----------------------------------------------------------------------------

async function loadFailures() {
  const event = $("event").value.trim(), by = $("rank-by").value;
  const query = new URLSearchParams({ by, limit: "20", ...(event ? { event } : {}) });
  const table = $("failures-table"), fresh = ticket("failures");
  try {
    const found = await api(`/api/${state.env}/failures?${query}`);
    if (!fresh()) return;
    $("failures-summary").textContent = `${found.failing} of ${found.worlds} stored evaluations fail (${found.event}): ${found.distinct} distinct worlds (repaired worlds, not latents), ranked by ${found.by}`;
    const metricNames = found.rows.length ? Object.keys(found.rows[0].metrics) : [];
    const picture = (i) => `<img loading="lazy" data-world="${i}" src="/api/${state.env}/world/${i}.png?size=72" alt="world ${i}"> ${i}`;
    table.innerHTML = `<tr><th>#</th><th>failing world</th><th title="log N(z; 0, I): higher is likelier under the generator's prior">log p(z)</th>` +
      `<th title="how far its means lie past the event's thresholds, in the metrics' units">severity (past the threshold)</th><th title="failing evaluations of this repaired world (latents that repair to one world count once)">failing evaluations</th>` +
      `<th title="the campaign that stored this evaluation">found by</th>` + metricNames.map((m) => `<th title="${esc(meaning(m))}">${esc(m)}</th>`).join("") + `<th>nearest passing world</th>` + metricNames.map((m) => `<th>${esc(m)} there</th>`).join("") + `<th>latent distance</th></tr>` +
      found.rows.map((row, k) => `<tr><td class="num">${k + 1}</td><td>${picture(row.index)}</td>` +
        `<td class="num">${fmt(row.log_prior)}</td><td class="num">${fmt(row.severity)}</td><td class="num">${row.evaluations}</td><td class="campaign">${campaignHtml(row.campaign)}</td>` +
        metricNames.map((m) => `<td class="num">${fmt(row.metrics[m])}</td>`).join("") +
        (row.nearest_passing === null ? `<td>none</td>${metricNames.map(() => "<td></td>").join("")}<td></td>` :
          `<td>${picture(row.nearest_passing)}</td>` + metricNames.map((m) => `<td class="num">${fmt(row.nearest_metrics[m])}</td>`).join("") + `<td class="num">${fmt(row.distance)}</td>`) +
        "</tr>").join("");
  } catch (error) {
    if (!fresh()) return;
    viewError("failures", fresh, error);
    table.innerHTML = "";
  }
}

// -- diff: two agents' regressed worlds -----------------------------------------------------

async function loadDiff() {
  // the table is the latest request's (campaign, event, env) or empty while it loads: never an earlier request's
  const event = $("diff-event").value.trim(), campaign = $("diff-campaign").value;
  const query = new URLSearchParams({ limit: "20", ...(campaign ? { campaign } : {}), ...(event ? { event } : {}) });
  const table = $("diff-table"), fresh = ticket("diff");
  state.diff = null;
  table.innerHTML = "";
  $("diff-summary").textContent = `loading ${campaign || "the first diff"} ...`;
  try {
    const found = await api(`/api/${state.env}/diff?${query}`);
    if (!fresh()) return;
    state.diff = found;
    if (found.campaigns.join("\n") !== envInfo().diffs.join("\n")) {  // a diff written since the page loaded joins the list
      envInfo().diffs = found.campaigns;
      envInfo().campaign_words = { ...envInfo().campaign_words, ...found.campaign_words };
      $("diff-campaign").innerHTML = campaignOptions(found.campaigns);
      $("diff-campaign").value = found.campaign;
    }
    const pair = found.pair ? ` · A: ${found.pair.A}, B: ${found.pair.B}` : "";
    $("diff-summary").textContent = `${found.campaign}: ${found.regressed} of ${found.worlds} worlds regressed (${found.event}), ${found.improved} improved${pair}`;
    const names = found.rows.length ? Object.keys(found.rows[0].a) : [];
    const picture = (i) => `<img loading="lazy" data-world="${i}" src="/api/${state.env}/world/${i}.png?size=72" alt="world ${i}"> ${i}`;
    table.innerHTML = `<tr><th>#</th><th>regressed world</th><th>log p(z)</th>${names.map((m) => `<th>${m} A → B</th>`).join("")}<th>nearest world where B passes</th><th>latent distance</th></tr>` +
      found.rows.map((row, k) => `<tr><td class="num">${k + 1}</td><td>${picture(row.index)}</td><td class="num">${fmt(row.log_prior)}</td>` +
        names.map((m) => `<td class="num">${fmt(row.a[m])} → ${fmt(row.b[m])}</td>`).join("") +
        (row.nearest_passing === null ? "<td>none</td><td></td>" : `<td>${picture(row.nearest_passing)}</td><td class="num">${fmt(row.distance)}</td>`) +
        "</tr>").join("");
  } catch (error) {
    if (!fresh()) return;
    viewError("diff", fresh, error);
    $("diff-summary").textContent = "";
  }
}

async function openDiff(index) {
  // the World view with the diff's A and B as its two agents, played at once with the episode keys the diff scored
  const [a, b] = (state.diff && state.diff.agents) || [];
  if (a) $("agent").value = a;
  if (b) $("agent2").value = b;
  const rows = (state.diff && state.diff.rows) || [];
  const replay = rows.map((r) => (r.index === index ? r.replay : r.nearest_passing === index ? r.nearest_replay : null)).find((r) => r);
  if (replay && replay.episodes <= Number($("episodes").max)) {  // other counts give other keys: left to the user then
    $("seed").value = replay.seed;
    $("episodes").value = replay.episodes;
  }
  await openWorld(index);
  if (a || b) play();
}

// -- start --------------------------------------------------------------------------------

async function start() {
  if (new URLSearchParams(location.search).has("token")) history.replaceState(null, "", location.pathname + location.hash);  // the cookie holds it now
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
$("map-metric").addEventListener("change", (e) => { state.metric = e.target.value; metricMeaning(); drawMap(); writeHash({ view: "map", env: state.env, metric: state.metric }); });
$("map-scale").addEventListener("change", drawMap);
$("map-failing-only").addEventListener("change", drawMap);
$("map-canvas").addEventListener("mousemove", hoverMap);
$("map-canvas").addEventListener("mouseleave", () => { $("map-hover").hidden = true; });
$("map-canvas").addEventListener("click", (e) => { const i = nearestPoint(e); if (i >= 0) openWorld(i); });
$("atlas-canvas").addEventListener("click", (e) => { const cell = atlasCellAt(e); if (cell) openWorld(cell.world); });
$("atlas-canvas").addEventListener("mousemove", hoverAtlas);
$("atlas-canvas").addEventListener("mouseleave", () => { $("atlas-hover").hidden = true; });
$("failures-table").addEventListener("click", (e) => { if (e.target.dataset.world) openWorld(Number(e.target.dataset.world)); });
$("failures-go").addEventListener("click", loadFailures);
$("diff-table").addEventListener("click", (e) => { if (e.target.dataset.world) openDiff(Number(e.target.dataset.world)); });
$("diff-go").addEventListener("click", loadDiff);
$("diff-campaign").addEventListener("change", loadDiff);
$("rank-by").addEventListener("change", loadFailures);
$("play").addEventListener("click", play);
$("episode-pick").addEventListener("change", () => { const frame = Number($("frame").textContent); state.players.forEach((r, i) => drawFrame(i, r, frame)); });
$("save").addEventListener("click", saveWorld);
$("agent").addEventListener("change", updateExport);
$("agent2").addEventListener("change", updateExport);
$("reset-z").addEventListener("click", () => { if (state.baseZ) { setSliders(state.baseZ); state.z = state.baseZ.slice(); redrawLatent(); } });
window.addEventListener("resize", () => { if (state.view === "map" && state.map) drawMap(); if (state.view === "atlas" && state.atlas) loadAtlas(); });
for (const button of document.querySelectorAll("#tabs button")) button.addEventListener("click", () => show(button.dataset.view));
window.explorer = { state, openWorld, openLatent, play, drawFrame, openDiff };  // for scripts and the browser tests
start();
