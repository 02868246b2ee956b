// End-of-mission report: utility over time per drone (plain JS, no libraries).
"use strict";

const $ = (id) => document.getElementById(id);
function esc(s) { return String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]); }

// Axis ticks at 1, 2, 2.5 or 5 times a power of ten from 0 to at least `max`, about `n`
// steps: every label is its gridline's exact value (a 0..6 axis in quarters was labelled
// 0 2 3 5 6, rounding 1.5 and 4.5 away).
function niceTicks(max, n) {
  if (!(max > 0)) max = 1;  // nothing to scale (all zero): a 0..1 axis
  const raw = max / n, mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => s >= raw * (1 - 1e-9));
  const top = Math.ceil(max / step - 1e-9);
  return Array.from({ length: top + 1 }, (_, i) => Number((i * step).toPrecision(12)));
}

function draw(series) {
  const canvas = $("r-chart");
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height, pad = 44;
  ctx.clearRect(0, 0, w, h);
  const drones = Object.entries(series.drones);
  const tMax = Math.max(series.bin_s, ...series.t);  // one bin: an axis one bin wide
  const most = Math.max(0, ...drones.flatMap(([, d]) => d.utility));
  const yTicks = niceTicks(most, 4);
  const uMax = yTicks[yTicks.length - 1];
  ctx.strokeStyle = "#30363d"; ctx.fillStyle = "#8b949e"; ctx.font = "12px sans-serif";
  for (const u of yTicks) {
    const y = h - pad - (h - 2 * pad) * u / uMax;
    ctx.beginPath(); ctx.moveTo(pad, y); ctx.lineTo(w - 10, y); ctx.stroke();
    ctx.fillText(String(u), 4, y + 4);
  }
  const xTicks = niceTicks(tMax, 8).filter((t) => t <= tMax);
  for (const t of xTicks) {
    ctx.fillText(String(t), pad + (w - pad - 10) * t / tMax - 4, h - pad + 16);
  }
  ctx.fillText("mission time (s)", w - 110, h - 8);
  // what the axes say and the numbers they were drawn for (tests read them)
  Object.assign(canvas.dataset, { yTicks: yTicks.join(" "), xTicks: xTicks.join(" "),
                                  most: String(most), tMax: String(tMax) });
  for (const [drone, d] of drones) {
    ctx.strokeStyle = d.color; ctx.lineWidth = 2; ctx.beginPath();
    d.utility.forEach((u, i) => {
      const x = pad + (w - pad - 10) * series.t[i] / tMax;
      const y = h - pad - (h - 2 * pad) * u / uMax;
      if (i === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
    });
    ctx.stroke();
    ctx.fillStyle = d.color;  // dots too: a one-bin mission still shows its points
    d.utility.forEach((u, i) => {
      const x = pad + (w - pad - 10) * series.t[i] / tMax;
      const y = h - pad - (h - 2 * pad) * u / uMax;
      ctx.beginPath(); ctx.arc(x, y, 3, 0, 2 * Math.PI); ctx.fill();
    });
  }
  $("r-legend").innerHTML = drones.map(([drone, d]) =>
    `<span class="lg" data-drone="${esc(drone)}" data-color="${esc(d.color)}"><i style="background:${esc(d.color)}"></i>${esc(drone)} total ${esc(d.total_text ?? d.total.toFixed(1))}</span>`).join(" ");
  $("r-empty").classList.toggle("hidden", drones.length > 0);
}

// What the report counts, said on the page: every run of the mission (start to end), and
// how many stored images fell outside them (before the first start, between runs).
function covers(series) {
  const t = (x) => new Date(x * 1000).toLocaleTimeString();
  const runs = (series.runs || []).map(([a, b]) => t(a) + "–" + (b == null ? "now" : t(b)));
  let text = runs.length ? (runs.length === 1 ? "run " : runs.length + " runs: ") + runs.join(", ")
    : series.t_start ? "from " + t(series.t_start) + " (no start command)" : "";
  text += ` · ${series.images || 0} image(s)`;
  if (series.images_outside) text += `, ${series.images_outside} stored outside the runs not counted`;
  return text;
}

async function load() {
  const key = localStorage.getItem("gs-key") || "";  // the dashboard's page key (app.js)
  const res = await fetch("/api/report", { headers: { "X-GS-Key": key }, credentials: "same-origin" });
  if (!res.ok) { $("r-empty").textContent = "not logged in: open the dashboard's login link first"; $("r-empty").classList.remove("hidden"); return; }
  const series = await res.json();
  $("r-mission").textContent = series.mission;
  $("r-bin").textContent = series.bin_s;
  $("r-times").textContent = covers(series);
  draw(series);
  $("r-png").src = "/api/report.png?t=" + Date.now() + "&key=" + encodeURIComponent(key);
  document.body.dataset.loaded = "1";
}
load();
