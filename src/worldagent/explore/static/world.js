// worldagent explore: the World view (latent sliders, plays, their legends, the animation). Loaded after plots.js and
// before explorer.js, whose `state`, `$`, `api` and `status` it uses when called.
"use strict";

const CLIENT = Math.random().toString(36).slice(2, 12);  // this page: the server drops its plays that a newer one overtook
const TRAILS = ["#1f5fe0", "#ff3b1f", "#ffd400", "#e01fd2", "#00d8ff", "#ff8c00", "#ffffff", "#8a2be2"];  // no grey or green: roads, grass, floors
const LONG_EPISODE = 400, RECENT_TRAIL = 60;  // steps
// ms a slider rests before its world is drawn and replayed: a drag makes a few requests, not one per pixel. Quick
// moves then cost at most the play already running plus the latest one: the server skips the plays in between.
const SLIDER_REST = 60;

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

function newWorld() {
  // the world on screen changes: every play of the previous one is abandoned, and its numbers and status leave the screen
  state.generation++;
  status("");
  if (playing) playing.abort();
  playing = null;
  cancelAnimationFrame(animation);
  state.players = [null, null];
  showMetrics(0, null);
  showMetrics(1, null);
  $("frame").textContent = "0";
  $("frames").textContent = "0";
  $("play-legend").innerHTML = "";
  $("episode-pick").innerHTML = '<option value="all">all episodes</option>';
  clearCanvas(0);
  clearCanvas(1);
}

let sliderTimer = null;
function onSlider(event) {
  const d = Number(event.target.dataset.dim);
  state.z = state.z ? state.z.slice() : new Array(envInfo().latent_dim).fill(0);
  state.z[d] = Number(event.target.value);
  event.target.nextElementSibling.textContent = state.z[d].toFixed(2);
  if (state.world !== null) $("world-info").innerHTML = `<tr><td>moved from world ${state.world}</td><td></td></tr>`;
  state.world = null;  // the world is now G(z), not the stored one
  newWorld();
  clearTimeout(sliderTimer);
  sliderTimer = setTimeout(redrawLatent, SLIDER_REST);
}

function redrawLatent() {
  newWorld();
  setPicture(`/api/${state.env}/decode.png?z=${zParam(state.z)}`);
  $("world-title").textContent = `G(z) of ${state.env}`;
  updateExport();
  if (state.played) play();  // and replay on the new world: an older play still running is dropped, one still waiting is skipped
}

function setPicture(src) {
  for (const [i, id] of ["world-img", "world-img-2"].entries()) {
    const img = $(id);
    img.dataset.loaded = "0";
    img.onload = () => { if (img.getAttribute("src") === src) { img.dataset.loaded = "1"; img.dataset.src = src; } };
    img.onerror = () => { if (img.getAttribute("src") === src) status(`picture failed: ${src}`, true); };
    img.src = src;
    clearCanvas(i);
  }
}

async function openWorld(index) {
  show("world");
  newWorld();
  state.world = index;
  const generation = state.generation;
  const info = await api(`/api/${state.env}/world/${index}`);
  if (generation !== state.generation) return;  // another world was opened meanwhile
  state.z = info.latent.slice();
  state.baseZ = info.latent.slice();
  setSliders(state.z);
  setPicture(`/api/${state.env}/world/${index}.png`);
  $("world-title").textContent = `world ${index} (${info.campaign}, generation ${info.generation}, slot ${info.slot})`;
  $("world-info").innerHTML = `<tr><th>stored world ${index}</th><th>mean of ${info.episodes} episodes</th></tr>` +
    Object.entries(info.metrics).map(([k, v]) => `<tr><td>${esc(k)}</td><td>${fmt(v)}</td></tr>`).join("") +
    `<tr><td>log p(z)</td><td>${fmt(info.log_prior)}</td></tr>`;
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
  $("permalink").href = location.origin + location.pathname + location.hash;  // no token: the cookie carries it here, never a shared link
}

async function playStatus(agents, episodes) {
  // what the wait is for: a first play of an agent compiles it (up to a minute on a busy CPU)
  try {
    const ready = await api(`/api/${state.env}/ready?agents=${encodeURIComponent(agents.join(","))}&episodes=${episodes}`);
    if (ready.cold.length) {
      const warming = ready.warming ? `; the warm-up is compiling ${ready.warming} now` : "";
      return `compiling ${ready.cold.join(" and ")} (first play only${warming}) ...`;
    }
  } catch (_) { /* the play itself will say what is wrong */ }
  return `playing ${agents.join(" and ")} ...`;
}

let playing = null;  // the AbortController of the play in flight
async function play() {
  const agents = [$("agent").value, $("agent2").value], chosen = agents.filter(Boolean);
  const seq = ++state.playSeq, generation = state.generation;
  if (playing) playing.abort();
  const controller = playing = new AbortController();
  const body = { ...source(), episodes: Number($("episodes").value), seed: Number($("seed").value), size: 384, client: CLIENT, seq };
  const current = () => seq === state.playSeq && generation === state.generation;
  const say = (text, isError = false) => { if (current() && state.view === "world") status(text, isError); };  // a superseded play says nothing
  state.stats.plays++;
  let answered = false;
  say(`playing ${chosen.join(" and ")} ...`);
  playStatus(chosen, body.episodes).then((text) => { if (!answered) say(text); });
  try {
    const results = await Promise.all(agents.map((agent) => agent ? api(`/api/${state.env}/play`, {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ ...body, agent }), signal: controller.signal,
    }) : null));
    answered = true;
    if (!current()) { state.stats.dropped++; return; }  // an answer for a world or play no longer on screen
    state.players = results;
    state.played = true;
    state.stats.shown++;
    results.forEach((r, i) => showMetrics(i, r));
    results.forEach((r, i) => { if (r && r.still) $(i === 0 ? "world-img" : "world-img-2").src = r.still; });  // no animation: the env's own picture
    const longest = Math.max(...results.filter(Boolean).flatMap((r) => r.episodes.map((e) => e.steps)));
    $("frames").textContent = String(longest);
    episodePicker(results);
    playLegend(results);
    animate(longest);
    say(`played ${body.episodes} episode(s) of ${chosen.join(" and ")}`);
  } catch (error) {
    if (error.name === "AbortError" || error.status === 409 || !current()) { state.stats.dropped++; return; }  // superseded
    say(error.message, true);
  }
}

function showMetrics(i, result) {
  const table = $(`metrics-${i + 1}`);
  if (!result) { table.innerHTML = ""; return; }
  table.innerHTML = `<tr><th>${esc(result.agent)}</th><th>mean of ${result.episodes.length} episodes</th></tr>` +
    Object.entries(result.means).map(([k, v]) => `<tr><td>${esc(k)}</td><td>${fmt(v)}</td></tr>`).join("");
}

// -- legends of the World view ------------------------------------------------------------------

function swatch(colour) { return `<span class="sw" style="background:${esc(colour)}"></span>`; }
function markSymbol(style) {
  const shape = { dot: "●", square: "■", ring: "○", cross: "✕" }[style.shape] || "●";
  return `<span class="sym" style="color:${esc(style.colour)};text-shadow:0 0 1px #000">${shape}</span>`;
}

function agentColour(a) {
  // agent a's colour: the one the env's own pictures (and so the report's figures) give it, else the page's trail colours
  const own = (envInfo().key || {}).agent_colours || [];
  return own.length ? own[a % own.length] : TRAILS[a % TRAILS.length];
}

function worldLegend() {
  // what the env's picture and animation mean (EnvSpec.pictures: legend, mark_styles, agents, outcomes)
  const key = envInfo().key || { colours: {}, marks: {}, agents: [], outcomes: {} };
  const rows = [];
  const colours = Object.entries(key.colours);
  if (colours.length) rows.push("<h4>the world</h4>", ...colours.map(([c, what]) => `<div class="row">${swatch(c)}${esc(what)}</div>`));
  const marks = Object.values(key.marks);
  if (marks.length) rows.push("<h4>during a play</h4>", ...marks.map((s) => `<div class="row">${markSymbol(s)}${esc(s.label)}</div>`));
  const outcomes = Object.values(key.outcomes);
  if (outcomes.length) rows.push(...(marks.length ? [] : ["<h4>during a play</h4>"]), ...outcomes.map((s) => `<div class="row">${markSymbol(s)}${esc(s.label)}</div>`));
  if (key.agents.length > 1) {
    rows.push("<h4>agents (trail and dot colours)</h4>", ...key.agents.map((name, a) => `<div class="row">${swatch(agentColour(a))}${esc(name)}</div>`));
    rows.push('<div class="row">each agent keeps its colour in every episode; "show" picks one episode</div>');
  } else {
    rows.push(`<div class="row">${esc(key.agents[0] || "the agent")}: one colour per episode (listed after a play); a dot is where it is at this step, a line where it went</div>`);
  }
  $("world-legend").innerHTML = rows.join("");
}

function outcomesOf(result, episode) {
  // the outcome marks (Pictures.outcomes) this episode ended with, e.g. a crash
  return Object.entries(result.outcomes || {}).filter(([name]) => {
    const v = episode.metrics[name];
    return Array.isArray(v) ? v.some((x) => x) : Boolean(v);
  });
}

function playLegend(results) {
  // per played agent: its episodes' colours (one agent: one colour per episode) and how they ended
  const key = envInfo().key || { agents: [] };
  const parts = results.map((r, i) => {
    if (!r) return "";
    const panel = i === 0 ? "left" : "right";
    const ended = r.episodes.map((e) => outcomesOf(r, e).map(([, s]) => s.label.split(":")[0]));
    const count = ended.filter((o) => o.length).length;
    const rows = (key.agents.length > 1 || (r.episodes[0] && r.episodes[0].path && r.episodes[0].path[0].length > 1)) ? [] :
      r.episodes.map((e, k) => `<div class="row">${swatch(TRAILS[k % TRAILS.length])}episode ${k + 1}: ${e.steps} steps${ended[k].length ? ` · ${esc(ended[k].join(", "))}` : ""}</div>`);
    const summary = Object.keys(r.outcomes || {}).length ? ` · ${count} of ${r.episodes.length} ended with ${esc(Object.values(r.outcomes).map((s) => s.label.split(":")[0]).join(" or "))}` : "";
    return `<h4>${esc(r.agent)} (${panel}): ${r.episodes.length} episodes${summary}</h4>` + rows.join("");
  });
  $("play-legend").innerHTML = parts.join("");
}

function episodePicker(results) {
  const count = Math.max(...results.filter(Boolean).map((r) => r.episodes.length));
  $("episode-pick").innerHTML = `<option value="all">all ${count} episodes</option>` + Array.from({ length: count }, (_, k) => `<option value="${k}">episode ${k + 1}</option>`).join("");
}

function shownEpisodes(result) {
  const pick = $("episode-pick").value;
  return result.episodes.map((episode, e) => [episode, e]).filter(([, e]) => pick === "all" || Number(pick) === e);
}

// -- the animation ------------------------------------------------------------------------

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
  canvas.dataset.outcomes = "0";
}

function trail(ctx, episode, a, first, last, scale) {
  ctx.beginPath();
  for (let t = first; t <= last; t++) {
    const [x, y] = episode.path[t][a];
    const joined = t > first && episode.present[t][a] && episode.present[t - 1][a];  // an agent off the map (tagged out) breaks its trail
    if (joined) ctx.lineTo(x * scale, y * scale); else ctx.moveTo(x * scale, y * scale);
  }
}

function drawFrame(i, result, frame) {
  const canvas = $(i === 0 ? "world-canvas" : "world-canvas-2"), ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  canvas.dataset.frame = String(frame);
  if (!result || !result.episodes.length || result.episodes[0].path === null) return;
  const scale = canvas.width / result.size, shown = shownEpisodes(result);
  canvas.dataset.marks = String(result.marks ? drawMarks(ctx, result, shown, frame, scale) : 0);
  let outcomes = 0;
  for (const [episode, e] of shown) {
    const last = Math.min(frame, episode.path.length - 1), agents = episode.path[0].length;
    for (let a = 0; a < agents; a++) {
      const colour = agents > 1 ? agentColour(a) : TRAILS[e % TRAILS.length];
      const first = episode.path.length > LONG_EPISODE ? Math.max(0, last - RECENT_TRAIL) : 0;  // long episodes keep a recent trail only
      trail(ctx, episode, a, first, last, scale);
      ctx.lineJoin = "round";
      ctx.strokeStyle = "rgba(0, 0, 0, 0.55)"; ctx.lineWidth = 5; ctx.stroke();  // a dark edge: seen on any road or floor
      ctx.strokeStyle = colour; ctx.lineWidth = 2.8; ctx.stroke();
      if (episode.present[last][a]) {
        const [x, y] = episode.path[last][a];
        ctx.fillStyle = colour;
        ctx.beginPath();
        ctx.arc(x * scale, y * scale, 5, 0, 2 * Math.PI);
        ctx.fill();
        ctx.strokeStyle = "#000"; ctx.lineWidth = 1.5;
        ctx.stroke();
      }
    }
    if (frame >= episode.steps) {  // how the episode ended, where it ended
      for (const [, style] of outcomesOf(result, episode)) {
        for (let a = 0; a < agents; a++) {
          const [x, y] = episode.path[episode.path.length - 1][a];
          drawCross(ctx, x * scale, y * scale, Math.max(style.radius * scale, 5), style.colour);
          outcomes++;
        }
      }
    }
  }
  canvas.dataset.outcomes = String(outcomes);
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

function drawMarks(ctx, result, shownEpisodes, frame, scale) {
  // the world's still picture dimmed, then every kind's marks at this frame; a mark in only some of the
  // episodes is fainter. Returns how many marks were drawn.
  ctx.fillStyle = "rgba(0, 0, 0, 0.45)";
  ctx.fillRect(0, 0, ctx.canvas.width, ctx.canvas.height);
  const counts = {};
  shownEpisodes.forEach(([episode]) => {
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
      ctx.globalAlpha = 0.3 + (0.7 * n) / shownEpisodes.length;
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
