// worldagent explore: what the plots need to explain themselves (colour scales, colour bars, axes, marker shapes).
// Each campaign's marker (shape, filled or hollow) comes from the server (views.campaign_markers); drawShape draws its shape.
// Plain functions of numbers and elements; explorer.js draws with them. No dependencies.
"use strict";

const VIRIDIS = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
// Diverging around a failure threshold: red on the failing side, blue on the passing side, grey at the threshold.
const DIVERGING = { fail: [178, 24, 43], mid: [205, 205, 205], pass: [33, 102, 172] };

function fmt(v) { return v === null || v === undefined ? "n/a" : Math.abs(v) >= 1000 || Number.isInteger(v) ? String(Math.round(v * 100) / 100) : Number(v).toPrecision(3); }
function esc(text) { return String(text).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]); }
function rgb(c) { return `rgb(${c.map(Math.round).join(",")})`; }
function mix(a, b, f) { return a.map((v, k) => v + f * (b[k] - v)); }

function viridis(t) {
  if (!Number.isFinite(t)) return "#bbb";
  const x = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1), i = Math.min(Math.floor(x), VIRIDIS.length - 2);
  return rgb(mix(VIRIDIS[i], VIRIDIS[i + 1], x - i));
}

function ranks(values) {
  // each finite value's quantile in [0, 1] (ties share their mean rank); NaN for the others
  const order = values.map((v, i) => [v, i]).filter(([v]) => Number.isFinite(v)).sort((a, b) => a[0] - b[0]);
  const out = new Array(values.length).fill(NaN), n = order.length;
  for (let k = 0; k < n;) {
    let j = k;
    while (j + 1 < n && order[j + 1][0] === order[k][0]) j++;
    const t = n > 1 ? (k + j) / 2 / (n - 1) : 0.5;
    for (let m = k; m <= j; m++) out[order[m][1]] = t;
    k = j + 1;
  }
  return out;
}

function quantile(sorted, q) {
  if (!sorted.length) return NaN;
  const x = q * (sorted.length - 1), i = Math.floor(x);
  return i + 1 < sorted.length ? sorted[i] + (x - i) * (sorted[i + 1] - sorted[i]) : sorted[i];
}

function fails(value, threshold) {
  const { op, value: at } = threshold;
  return op === ">" ? value > at : op === ">=" ? value >= at : op === "<" ? value < at : value <= at;
}

// A colour scale over `values`: {kind, colourOf(i), bar: {paint(t), ticks: [{at, text}], note}}.
// quantile: equal numbers of worlds per colour (long tails no longer paint everything alike); linear;
// diverging: red past `threshold` (the env's failure event), blue before it, each side ranked on its own.
function colourScale(values, kind, threshold, reverse = false, unit = "worlds") {
  const finite = values.filter(Number.isFinite).sort((a, b) => a - b);
  const lo = finite[0], hi = finite[finite.length - 1];
  const flip = (t) => (reverse ? 1 - t : t);
  if (kind === "diverging" && threshold) {
    const sides = values.map((v) => (Number.isFinite(v) ? fails(v, threshold) : null));
    const distance = values.map((v) => Math.abs(v - threshold.value));
    const rankOn = (side) => ranks(distance.map((d, i) => (sides[i] === side ? d : NaN)));
    const failRank = rankOn(true), passRank = rankOn(false);
    const colourOf = (i) => sides[i] === null ? "#bbb" : sides[i] ? rgb(mix(DIVERGING.mid, DIVERGING.fail, 0.35 + 0.65 * failRank[i])) : rgb(mix(DIVERGING.mid, DIVERGING.pass, 0.35 + 0.65 * passRank[i]));
    const failHigh = threshold.op[0] === ">";
    const paint = (t) => {  // the bar runs from the lowest value (left) to the highest, the threshold in the middle
      const away = Math.abs(t - 0.5) * 2, high = t > 0.5;
      return rgb(mix(DIVERGING.mid, high === failHigh ? DIVERGING.fail : DIVERGING.pass, 0.35 + 0.65 * away));
    };
    const ticks = [{ at: 0, text: fmt(lo) }, { at: 0.5, text: `${threshold.op} ${fmt(threshold.value)}` }, { at: 1, text: fmt(hi) }];
    const note = `diverging at the failure threshold: red fails (${threshold.op} ${fmt(threshold.value)}), blue passes; darker: farther from it (ranked on each side).`;
    return { kind, colourOf, bar: { paint, ticks, note } };
  }
  if (kind === "linear") {
    const t = (v) => (hi > lo ? (v - lo) / (hi - lo) : 0.5);
    const ticks = [0, 0.5, 1].map((at) => ({ at, text: fmt(lo + at * (hi - lo)) }));
    return { kind, colourOf: (i) => viridis(flip(t(values[i]))), bar: { paint: (x) => viridis(flip(x)), ticks, note: `linear from ${fmt(lo)} to ${fmt(hi)}.` } };
  }
  const rank = ranks(values);
  const ticks = [0, 0.25, 0.5, 0.75, 1].map((at) => ({ at, text: fmt(quantile(finite, at)) }));
  const note = `quantile scale: each colour holds the same share of ${unit} (ticks: the values at 0, 25, 50, 75 and 100%).`;
  return { kind: "quantile", colourOf: (i) => viridis(flip(rank[i])), bar: { paint: (x) => viridis(flip(x)), ticks, note } };
}

function renderColourBar(el, title, bar, extra = "") {
  // a titled gradient with its tick values and a line saying how to read it, as HTML (the text is in the DOM)
  el.innerHTML = `<div class="cb-title">${esc(title)}</div><canvas width="260" height="14"></canvas>` +
    `<div class="cb-ticks">${bar.ticks.map((t) => `<span style="left:${(t.at * 100).toFixed(1)}%">${esc(t.text)}</span>`).join("")}</div>` +
    `<div class="cb-note">${esc(bar.note)}${extra ? ` ${esc(extra)}` : ""}</div>`;
  const ctx = el.querySelector("canvas").getContext("2d");
  for (let x = 0; x < 260; x++) { ctx.fillStyle = bar.paint(x / 259); ctx.fillRect(x, 0, 1, 14); }
}

function niceTicks(lo, hi, count = 5) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / count, power = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * power).find((s) => s >= raw) || 10 * power;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  return out;
}

function renderTicks(el, ticks, vertical) {
  // ticks: [{px, text}] along the canvas's edge (px from its left, or from its top when vertical)
  el.innerHTML = ticks.map((t) => `<span style="${vertical ? "top" : "left"}:${t.px.toFixed(1)}px">${esc(t.text)}</span>`).join("");
  if (vertical) el.style.height = `${el.parentElement.querySelector("canvas").clientHeight}px`;
}

function drawShape(ctx, shape, x, y, r) {
  ctx.beginPath();
  if (shape === "square") ctx.rect(x - r, y - r, 2 * r, 2 * r);
  else if (shape === "triangle" || shape === "down") {
    const s = shape === "down" ? -1 : 1;
    ctx.moveTo(x, y - s * 1.2 * r); ctx.lineTo(x + 1.1 * r, y + s * 0.8 * r); ctx.lineTo(x - 1.1 * r, y + s * 0.8 * r); ctx.closePath();
  } else if (shape === "diamond") { ctx.moveTo(x, y - 1.3 * r); ctx.lineTo(x + 1.3 * r, y); ctx.lineTo(x, y + 1.3 * r); ctx.lineTo(x - 1.3 * r, y); ctx.closePath(); }
  else if (shape === "left" || shape === "right") {
    const s = shape === "left" ? 1 : -1;
    ctx.moveTo(x - s * 1.2 * r, y); ctx.lineTo(x + s * 0.8 * r, y - 1.1 * r); ctx.lineTo(x + s * 0.8 * r, y + 1.1 * r); ctx.closePath();
  } else if (shape === "hexagon") {
    for (let k = 0; k < 6; k++) { const a = (k * Math.PI) / 3; k ? ctx.lineTo(x + 1.15 * r * Math.cos(a), y + 1.15 * r * Math.sin(a)) : ctx.moveTo(x + 1.15 * r, y); }
    ctx.closePath();
  } else if (shape === "cross") {
    const w = 0.45 * r, c = Math.SQRT1_2;
    for (const [dx, dy] of [[c, c], [c, -c]]) {  // two bars at ±45°
      ctx.moveTo(x - 1.3 * r * dx - w * dy, y - 1.3 * r * dy + w * dx); ctx.lineTo(x + 1.3 * r * dx - w * dy, y + 1.3 * r * dy + w * dx);
      ctx.lineTo(x + 1.3 * r * dx + w * dy, y + 1.3 * r * dy - w * dx); ctx.lineTo(x - 1.3 * r * dx + w * dy, y - 1.3 * r * dy - w * dx); ctx.closePath();
    }
  } else if (shape === "plus") { const w = 0.45 * r; ctx.rect(x - 1.2 * r, y - w, 2.4 * r, 2 * w); ctx.rect(x - w, y - 1.2 * r, 2 * w, 2.4 * r); }
  else if (shape === "star") {
    for (let k = 0; k < 10; k++) { const a = -Math.PI / 2 + (k * Math.PI) / 5, d = k % 2 ? 0.55 * r : 1.4 * r; k ? ctx.lineTo(x + d * Math.cos(a), y + d * Math.sin(a)) : ctx.moveTo(x + d * Math.cos(a), y + d * Math.sin(a)); }
    ctx.closePath();
  } else ctx.arc(x, y, r, 0, 2 * Math.PI);
}

function drawMarker(ctx, marker, x, y, r, colour, ring) {
  // a campaign's marker in `colour`: the shape filled, or hollow (its outline in the colour, thick enough to read it);
  // `ring` (a failing world) outlines it, hollow ones from outside so their colour stays seen
  drawShape(ctx, marker.shape, x, y, r);
  if (marker.filled) {
    ctx.fillStyle = colour; ctx.fill();
    if (ring) { ctx.strokeStyle = ring; ctx.lineWidth = 1.6; ctx.stroke(); }
    return;
  }
  if (ring) { ctx.strokeStyle = ring; ctx.lineWidth = 4.2; ctx.stroke(); drawShape(ctx, marker.shape, x, y, r); }
  ctx.strokeStyle = colour; ctx.lineWidth = 1.8; ctx.stroke();
}

function drawCross(ctx, x, y, r, colour) {
  // an outcome mark (a crash): a cross with a dark edge, seen on any background
  for (const [width, style] of [[r * 0.75, "rgba(0,0,0,0.7)"], [r * 0.4, colour]]) {
    ctx.strokeStyle = style; ctx.lineWidth = width; ctx.beginPath();
    ctx.moveTo(x - r, y - r); ctx.lineTo(x + r, y + r); ctx.moveTo(x + r, y - r); ctx.lineTo(x - r, y + r); ctx.stroke();
  }
}

window.plots = { fmt, esc, viridis, ranks, colourScale, renderColourBar, niceTicks, renderTicks, drawShape, drawMarker, drawCross, fails };
