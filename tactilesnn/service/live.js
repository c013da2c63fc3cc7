"use strict";
const params = new URLSearchParams(location.search);
let follow = params.get("stream");  // null: the first stream that sends a window
let updates = 0;
const COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b",
                "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939"];

function ctx(id) {
  const c = document.getElementById(id), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  return [c, g];
}

function axes(g, c, xlabel, xmax) {
  g.fillStyle = "#555"; g.font = "11px sans-serif";
  g.fillText("0", 30, c.height - 4);
  g.fillText(xmax.toFixed(0) + " " + xlabel, c.width - 70, c.height - 4);
}

function drawSignal(ev) {
  const [c, g] = ctx("signal"), L = 34, B = 16, W = c.width - L - 6, H = c.height - B - 6;
  let lo = Infinity, hi = -Infinity;
  for (const ch of ev.signal) for (const v of ch) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!(hi > lo)) { hi = lo + 1; }
  ev.signal.forEach((ch, i) => {
    g.strokeStyle = COLORS[i % COLORS.length]; g.lineWidth = 1; g.beginPath();
    ch.forEach((v, j) => {
      const x = L + W * j / Math.max(1, ch.length - 1), y = 6 + H * (1 - (v - lo) / (hi - lo));
      j ? g.lineTo(x, y) : g.moveTo(x, y);
    });
    g.stroke();
  });
  // legend: each drawn channel's name in its colour (inserted as canvas text, never as HTML)
  // (top right, clear of the scale labels on the left)
  g.font = "10px sans-serif";
  const labels = (ev.channels || []).map((name) => String(name).slice(0, 16));
  const more = ev.n_channels > ev.signal.length ?
    `(first ${ev.signal.length} of ${ev.n_channels})` : "";
  const widths = labels.map((l) => g.measureText(l).width + 8);
  let lx = Math.max(L + 60, c.width - 6 - widths.reduce((a, b) => a + b, 0) -
                    (more ? g.measureText(more).width : 0));
  labels.forEach((label, i) => {
    g.fillStyle = COLORS[i % COLORS.length];
    g.fillText(label, lx, 10);
    lx += widths[i];
  });
  if (more) { g.fillStyle = "#555"; g.fillText(more, lx, 10); }
  g.fillStyle = "#555"; g.font = "11px sans-serif";
  g.fillText((hi * ev.signal_scale).toPrecision(3), 0, 12);
  g.fillText((lo * ev.signal_scale).toPrecision(3), 0, H + 6);
  axes(g, c, "ms", ev.duration_ms);
}

function heat(t) {  // 0..1 -> dark purple .. yellow
  const r = Math.round(255 * Math.min(1, 1.6 * t)), gr = Math.round(255 * Math.max(0, 1.5 * t - 0.5));
  const b = Math.round(255 * Math.max(0, 0.55 - Math.abs(t - 0.35)));
  return `rgb(${r},${gr},${b})`;
}

function drawSpec(ev) {
  const [c, g] = ctx("spec"), L = 34, B = 16, W = c.width - L - 6, H = c.height - B - 6;
  const S = ev.spectrogram, nb = S.length, nf = S[0].length;
  let lo = Infinity, hi = -Infinity;
  for (const row of S) for (const v of row) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  lo = Math.max(lo, hi - 3);  // 60 dB of display range
  const cw = W / nf, chh = H / nb;
  for (let b = 0; b < nb; b++) for (let f = 0; f < nf; f++) {
    g.fillStyle = heat(Math.max(0, (S[b][f] - lo) / Math.max(1e-9, hi - lo)));
    g.fillRect(L + f * cw, 6 + H - (b + 1) * chh, Math.ceil(cw), Math.ceil(chh));
  }
  g.fillStyle = "#555"; g.font = "11px sans-serif";
  g.fillText(ev.freqs_hz[nb - 1].toFixed(0), 0, 14); g.fillText("0 Hz", 0, H + 6);
  axes(g, c, "ms", ev.duration_ms);
}

function drawRaster(ev) {
  const [c, g] = ctx("raster"), L = 34, B = 16, W = c.width - L - 6, H = c.height - B - 6;
  const n = Math.max(1, ev.n_afferents);
  g.fillStyle = "#111";
  for (const [a, t] of ev.raster) {
    g.fillRect(L + W * t / ev.duration_ms, 6 + H * (1 - (a + 0.5) / n) - 1, 2, 3);
  }
  g.fillStyle = "#555"; g.font = "11px sans-serif";
  g.fillText(String(n), 0, 14); g.fillText("0", 0, H + 6);
  g.fillText(ev.raster.length + " spikes", L + 4, 14);
  axes(g, c, "ms", ev.duration_ms);
}

function drawScores(ev) {
  const [c, g] = ctx("scores"), B = 30, H = c.height - B - 8;
  const s = ev.scores, n = s.length, best = s.indexOf(Math.max(...s));
  const lo = Math.min(0, ...s), hi = Math.max(1e-9, ...s), bw = (c.width - 20) / n;
  const zero = 8 + H * hi / (hi - lo);
  s.forEach((v, i) => {
    g.fillStyle = i === best ? "#ff7f0e" : "#1f77b4";
    const y = 8 + H * (hi - Math.max(v, 0)) / (hi - lo), h = H * Math.abs(v) / (hi - lo);
    g.fillRect(10 + i * bw + bw * 0.15, v >= 0 ? y : zero, bw * 0.7, Math.max(1, h));
    g.fillStyle = "#222"; g.font = "12px sans-serif";
    g.fillText(ev.class_names[i] + "  " + v.toFixed(2), 10 + i * bw + bw * 0.15, c.height - 10);
  });
  g.strokeStyle = "#888"; g.beginPath(); g.moveTo(10, zero); g.lineTo(c.width - 10, zero); g.stroke();
}

// Every string in an event (stream id, class names) came from a request or a model: it is
// inserted as text (textContent, canvas fillText), never parsed as HTML.
function el(tag, text, id) {
  const e = document.createElement(tag);
  e.textContent = String(text);
  if (id) e.id = id;
  return e;
}

function showInfo(ev) {
  const info = document.getElementById("info");
  info.replaceChildren(
    "stream ", el("code", ev.stream),
    ` · window ${Number(ev.window_index)} (t = ${Number(ev.t_s).toFixed(2)} s) · class `,
    el("b", ev.class, "cls"), ` · ${updates} updates`);
}

const source = new EventSource("/v1/live");
source.onmessage = (msg) => {
  const ev = JSON.parse(msg.data);
  if (follow === null) follow = ev.stream;
  if (ev.stream !== follow) return;
  updates += 1;
  document.body.dataset.updates = String(updates);
  document.body.dataset.lastClass = ev.class;
  document.getElementById("waiting").textContent = "";
  showInfo(ev);
  drawSignal(ev); drawSpec(ev); drawRaster(ev); drawScores(ev);
};
source.onerror = () => { document.getElementById("waiting").textContent = "connection lost; retrying…"; };
