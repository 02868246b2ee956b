// Ground-station dashboard: plain JS, no libraries, no network beyond this server.
"use strict";

// 12 colours readable on the dark background, neighbours far apart in hue (uav1, uav2, ...).
const PALETTE = ["#4aa3ff", "#ffa657", "#3fb950", "#f778ba", "#e3b341", "#a371f7",
  "#56d4dd", "#ff7b72", "#b5e853", "#d2a8ff", "#2ec4a6", "#c9b18a"];
const state = {
  drones: new Map(), series: [], alerts: [], drops: {}, mission: null,
  config: {}, ws: null, dirty: new Set(), frame: false, colors: new Map(), imgTimes: new Map(),
  clockOffset: 0,
};
const $ = (id) => document.getElementById(id);

// -- token ---------------------------------------------------------------------------------
// The page never holds the token: the server keeps the session in an HttpOnly cookie, set by
// the one-time login link (/?login=...) or by sending the token once from the token box.
function initToken() {
  localStorage.removeItem("gs-token");  // left by older versions
  $("token-save").onclick = async () => {
    const token = $("token-input").value.trim();
    $("token-input").value = "";
    const res = await fetch("/api/login", { method: "POST", headers: { Authorization: "Bearer " + token } });
    if (res.ok) location.reload(); else toast("token refused");
  };
}
async function api(path, options = {}) {
  const res = await fetch(path, { ...options, credentials: "same-origin" });
  if (res.status === 401) { $("token-box").classList.remove("hidden"); throw new Error("unauthorized: token needed"); }
  const body = await res.json().catch(() => ({}));
  if (!res.ok) throw new Error(body.error || res.statusText);
  return body;
}
function toast(text, ms = 4000) {
  const el = $("toast");
  el.textContent = text;
  el.classList.remove("hidden");
  clearTimeout(toast.timer);
  toast.timer = setTimeout(() => el.classList.add("hidden"), ms);
}

// -- formatting ----------------------------------------------------------------------------
const fmt = {
  num: (v, d = 1) => (v === null || v === undefined ? "–" : Number(v).toFixed(d)),
  pct: (v) => (v === null || v === undefined ? "–" : Math.round(v * 100) + " %"),
  time: (t) => (t ? new Date(t * 1000).toLocaleTimeString() : "–"),
  age: (s) => (s === null || s === undefined ? "–" : s < 1 ? "now" : s < 60 ? s.toFixed(0) + " s ago" : (s / 60).toFixed(1) + " min ago"),
  fix: (f) => (f === null || f === undefined ? "–" : ["no GPS", "no fix", "2D", "3D", "DGPS", "RTK float", "RTK fixed"][f] || String(f)),
};
// A drone's colour follows from its id alone, so it is the same after a reload, whatever order
// the drones were heard in: a trailing number picks the palette slot (uav1..uav12 all differ),
// any other id is hashed (FNV-1a) into it.
function colorIndex(drone) {
  const m = /(\d+)$/.exec(drone);
  if (m) return (Number(m[1].slice(-6)) + PALETTE.length - 1) % PALETTE.length;
  let h = 0x811c9dc5;
  for (const ch of drone) { h ^= ch.codePointAt(0); h = Math.imul(h, 0x01000193) >>> 0; }
  return h % PALETTE.length;
}
function color(drone) {
  if (!state.colors.has(drone)) state.colors.set(drone, PALETTE[colorIndex(String(drone))]);
  return state.colors.get(drone);
}
function esc(s) { return String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]); }
function now() { return Date.now() / 1000 + state.clockOffset; }

// -- live connection -------------------------------------------------------------------------
function connect(delay = 500) {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(`${proto}//${location.host}/ws`);
  state.ws = ws;
  ws.onopen = () => { $("conn").className = "dot on"; delay = 500; };
  ws.onclose = () => {
    $("conn").className = "dot off";
    setTimeout(() => connect(Math.min(delay * 2, 8000)), delay);
  };
  ws.onmessage = (ev) => handle(JSON.parse(ev.data));
}
function handle(msg) {
  if (msg.t) state.clockOffset = msg.t - Date.now() / 1000;
  switch (msg.kind) {
    case "snapshot":
      state.drones.clear();
      for (const d of msg.drones) { state.drones.set(d.drone, d); state.dirty.add(d.drone); }
      state.series = msg.series || [];
      state.alerts = (msg.alerts || []).slice().reverse();
      state.drops = msg.drops || {};
      state.mission = msg.mission;
      state.config = msg.config || {};
      renderAlerts(); renderMission(); renderCharts(); renderDrops(); fillDroneFilter(); renderKey();
      break;
    case "drone":
    case "status":
      state.drones.set(msg.drone.drone, msg.drone);
      state.dirty.add(msg.drone.drone);
      if (msg.mission) { state.mission = msg.mission; renderMission(); }
      break;
    case "alert":
      state.alerts.unshift(msg.alert);
      state.alerts.length = Math.min(state.alerts.length, 200);
      renderAlerts();
      break;
    case "tick":
      state.series.push(msg.point);
      if (state.series.length > 120) state.series.splice(0, state.series.length - 120);
      state.drops = msg.stats.drops || {};
      for (const [drone, p] of Object.entries(msg.point.drones || {})) {
        const d = state.drones.get(drone);
        if (d) { d.age_s = msg.point.t - d.last_heard; d.now = msg.point.t; state.dirty.add(drone); }
      }
      renderCharts(); renderDrops();
      if (msg.mission) { state.mission = msg.mission; renderMission(); }
      break;
    case "mission":
      state.mission = msg.mission;
      renderMission();
      break;
  }
  schedule();
}
function schedule() {
  if (state.frame) return;
  state.frame = true;
  requestAnimationFrame(() => {
    state.frame = false;
    for (const drone of state.dirty) renderTile(state.drones.get(drone));
    state.dirty.clear();
    renderMap();
    renderSummary();
  });
}

// -- tiles -----------------------------------------------------------------------------------
function tileFor(drone) {
  let el = document.querySelector(`.tile[data-drone="${CSS.escape(drone)}"]`);
  if (el) return el;
  const empty = document.querySelector("#tiles .empty");
  if (empty) empty.remove();
  el = document.createElement("article");
  el.className = "tile";
  el.dataset.drone = drone;
  el.innerHTML = `
    <header><b></b><span class="dot"></span></header>
    <div class="imgbox"><img alt=""><span class="util" title="U: utility weight of the latest image (1 = plain); the red border marks high utility for this mission's spec"></span></div>
    <table><tbody>
      <tr><td>fps</td><td class="v-fps"></td><td>latency</td><td class="v-lat"></td></tr>
      <tr><td title="this drone's part of the fleet's goodput over the last 5 s">share</td><td class="v-share"></td><td>battery</td><td class="v-batt"></td></tr>
      <tr><td>mode</td><td class="v-mode"></td><td>armed</td><td class="v-armed"></td></tr>
      <tr><td>GPS</td><td class="v-gps"></td><td>heard</td><td class="v-heard"></td></tr>
      <tr><td>position</td><td class="v-pos" colspan="3"></td></tr>
      <tr><td title="decisions not made by the optimiser (greedy fallback or timeout)">fallback</td><td class="v-fallback"></td><td></td><td></td></tr>
    </tbody></table>`;
  el.querySelector("header b").textContent = drone;
  el.querySelector("header b").style.color = color(drone);
  el.querySelector("header").style.borderBottom = `3px solid ${color(drone)}`;
  el.dataset.color = color(drone);
  const tiles = $("tiles");
  const after = [...tiles.children].find((t) => t.dataset.drone > drone);
  tiles.insertBefore(el, after || null);
  return el;
}
function renderTile(d) {
  if (!d) return;
  const el = tileFor(d.drone);
  const img = d.latest_image;
  el.classList.toggle("high", !!(img && img.high));
  el.classList.toggle("lost", !!d.link_lost);
  el.dataset.images = d.images;
  el.querySelector("header .dot").className = "dot " + (d.link_lost ? "off" : "on");
  if (img) {
    el.dataset.seq = img.seq;
    const util = el.querySelector(".util");
    util.textContent = `U ${fmt.num(img.utility, 2)}${img.object ? " · object" : ""}${img.red !== null ? " · red " + fmt.pct(img.red) : ""}`;
    util.classList.toggle("high", !!img.high);
    const tag = img.seq + ":" + img.t_rcv;
    const last = state.imgTimes.get(d.drone) || { tag: null, at: 0 };
    // At most 5 image reloads per tile per second; the newest wins.
    if (last.tag !== tag && performance.now() - last.at > 200) {
      el.querySelector("img").src = `/api/drones/${encodeURIComponent(d.drone)}/latest.jpg?s=${img.seq}`;
      state.imgTimes.set(d.drone, { tag, at: performance.now() });
    } else if (last.tag !== tag) {
      state.dirty.add(d.drone);
      setTimeout(schedule, 220);
    }
  }
  el.querySelector(".v-fps").textContent = fmt.num(d.fps, 1);
  el.querySelector(".v-lat").textContent = d.latency_s === null ? "–" : fmt.num(d.latency_s * 1000, 0) + " ms";
  el.querySelector(".v-share").innerHTML = `<span class="meter"><i style="width:${Math.round((d.goodput_share || 0) * 100)}%"></i></span>${fmt.pct(d.goodput_share)}`;
  const b = d.battery;
  el.querySelector(".v-batt").innerHTML = b === null ? "–" : `<span class="meter batt${b < 0.25 ? " low" : ""}"><i style="width:${Math.round(b * 100)}%"></i></span>${fmt.pct(b)}`;
  el.querySelector(".v-mode").textContent = (d.mode || "–") + (d.failsafe ? " · FAILSAFE" : "") + (d.autopilot_connected === false ? " · autopilot lost" : "");
  el.querySelector(".v-armed").textContent = d.armed === null ? "–" : d.armed ? "ARMED" : "disarmed";
  el.querySelector(".v-gps").textContent = fmt.fix(d.gps_fix);
  el.querySelector(".v-pos").textContent = d.no_position ? "no position (no fix)" : d.lat_deg === null ? "–" : `${fmt.num(d.lat_deg, 6)}, ${fmt.num(d.lon_deg, 6)}`;
  // Every telemetry value shows its age; past its bound it is marked stale (issue 17).
  const later = (d.now || d.t || 0) - (d.t || 0);
  const stale = new Set(d.stale || []);
  for (const [cls, name] of [[".v-mode", "mode"], [".v-armed", "armed"], [".v-gps", "gps_fix"], [".v-batt", "battery"], [".v-pos", "position"]]) {
    const cell = el.querySelector(cls), age = d.ages ? d.ages[name] : undefined;
    if (age === undefined) { cell.classList.remove("stale"); continue; }
    const now = age + later;
    const old = stale.has(name) || now > ((d.stale_after_s || {})[name] ?? 12);
    cell.classList.toggle("stale", old);
    cell.title = `${name}: ${fmt.age(now)}${old ? " (stale)" : ""}`;
    cell.insertAdjacentHTML("beforeend", ` <small class="age">${now < 1 ? "" : fmt.num(now, 0) + " s"}</small>`);
  }
  el.querySelector(".v-heard").textContent = fmt.age(d.age_s);
  el.querySelector(".v-fallback").textContent = d.fallback_share == null ? "–" : (d.fallback_share * 100).toFixed(1) + " %";
}
function renderSummary() {
  const ds = [...state.drones.values()];
  const lost = ds.filter((d) => d.link_lost).length;
  $("fleet-summary").textContent = `${ds.length} heard${lost ? `, ${lost} lost` : ""}`;
}

// The legend states the utility scale the server derived from the mission spec.
function renderKey() {
  const c = state.config, sc = c.utility_scale;
  $("key-high").textContent = c.high_utility == null ? "never (no image type gains)" : "U " + fmt.num(c.high_utility, 2);
  if (sc) {
    $("key-scale").textContent = `${fmt.num(sc.plain, 0)} plain … ${fmt.num(sc.max, 0)} best (${sc.source})`;
    $("key-high").title = sc.fraction == null ? "set in the ground-station config"
      : `1 + ${sc.fraction} × ${fmt.num(sc.max - sc.plain, 1)}: ${Math.round(sc.fraction * 100)} % of the largest gain`;
  }
}

// -- fleet map -------------------------------------------------------------------------------
function renderMap() {
  const svg = $("map");
  const pts = [...state.drones.values()].filter((d) => d.x_m !== null && d.y_m !== null);
  let html = "";
  const W = 300, pad = 30;
  let span = 20, cx = 0, cy = 0;
  if (pts.length) {
    const xs = pts.map((d) => d.x_m), ys = pts.map((d) => d.y_m);
    const minx = Math.min(...xs), maxx = Math.max(...xs), miny = Math.min(...ys), maxy = Math.max(...ys);
    span = Math.max(20, maxx - minx, maxy - miny) * 1.15;
    cx = (minx + maxx) / 2; cy = (miny + maxy) / 2;
  }
  const scale = (W - 2 * pad) / span;
  const sx = (x) => W / 2 + (x - cx) * scale, sy = (y) => W / 2 - (y - cy) * scale;
  const raw = span / 6, mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((k) => k * mag).find((v) => v >= raw);
  for (let g = Math.ceil((cx - span) / step) * step; g <= cx + span; g += step) {
    html += `<line x1="${sx(g)}" y1="0" x2="${sx(g)}" y2="${W}" stroke="#1f2a35"/>`;
  }
  for (let g = Math.ceil((cy - span) / step) * step; g <= cy + span; g += step) {
    html += `<line x1="0" y1="${sy(g)}" x2="${W}" y2="${sy(g)}" stroke="#1f2a35"/>`;
  }
  html += `<text x="6" y="${W - 8}" fill="#8b98a5" font-size="10">grid ${step} m</text>`;
  html += `<text x="${W - 14}" y="14" fill="#8b98a5" font-size="11">N</text>`;
  for (const d of pts) {
    const x = sx(d.x_m), y = sy(d.y_m), c = color(d.drone);
    if (d.heading_deg !== null && d.heading_deg !== undefined) {
      const a = (d.heading_deg * Math.PI) / 180;
      html += `<line x1="${x}" y1="${y}" x2="${x + 14 * Math.sin(a)}" y2="${y - 14 * Math.cos(a)}" stroke="${c}" stroke-width="2"/>`;
    }
    const hi = d.latest_image && d.latest_image.high;
    html += `<circle cx="${x}" cy="${y}" r="6" fill="${c}" stroke="${hi ? "#ff2d2d" : "#0b1016"}" stroke-width="${hi ? 3 : 1.5}" opacity="${d.link_lost ? 0.4 : 1}"/>`;
    html += `<text x="${x + 9}" y="${y + 4}" fill="${c}" font-size="11">${esc(d.drone)}${d.alt_m !== null ? " " + fmt.num(d.alt_m, 0) + " m" : ""}</text>`;
  }
  if (!pts.length) html += `<text x="${W / 2}" y="${W / 2}" fill="#8b98a5" font-size="12" text-anchor="middle">no positions yet</text>`;
  svg.innerHTML = html;
}

// -- charts ----------------------------------------------------------------------------------
function drawChart(id, lines, { yScale = 1, fixedMax = null } = {}) {
  const cv = $(id);
  const dpr = window.devicePixelRatio || 1;
  const w = cv.clientWidth, h = cv.clientHeight;
  if (cv.width !== w * dpr) { cv.width = w * dpr; cv.height = h * dpr; }
  const g = cv.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, w, h);
  const t1 = now(), t0 = t1 - 120;
  let max = fixedMax || 0;
  for (const l of lines) for (const [, v] of l.points) if (v !== null && v * yScale > max) max = v * yScale;
  if (!fixedMax) max = max > 0 ? max * 1.15 : 1;
  const L = 34, B = 14, T = 8;
  g.strokeStyle = "#2d3a48"; g.fillStyle = "#8b98a5"; g.font = "10px system-ui"; g.lineWidth = 1;
  for (let i = 0; i <= 2; i++) {
    const y = T + (h - B - T) * (1 - i / 2);
    g.beginPath(); g.moveTo(L, y); g.lineTo(w, y); g.stroke();
    const v = (max * i) / 2;
    g.fillText(v >= 100 ? v.toFixed(0) : v >= 1 ? v.toFixed(1) : v >= 0.1 ? v.toFixed(2) : v.toFixed(3), 2, y + 3);
  }
  g.fillText("-2 min", L, h - 2); g.fillText("now", w - 22, h - 2);
  for (const l of lines) {
    g.strokeStyle = l.color; g.lineWidth = 1.6; g.beginPath();
    let started = false;
    for (const [t, v] of l.points) {
      if (v === null || t < t0) { started = false; continue; }
      const x = L + ((t - t0) / 120) * (w - L), y = T + (h - B - T) * (1 - Math.min(1, (v * yScale) / max));
      if (!started) { g.moveTo(x, y); started = true; } else g.lineTo(x, y);
    }
    g.stroke();
  }
  if (!lines.some((l) => l.points.some(([, v]) => v !== null))) {
    g.fillStyle = "#8b98a5"; g.fillText("nothing reported yet", w / 2 - 45, h / 2);
  }
}
function perDrone(key) {
  const drones = new Set();
  for (const p of state.series) for (const d of Object.keys(p.drones || {})) drones.add(d);
  return [...drones].sort().map((d) => ({
    color: color(d),
    points: state.series.map((p) => [p.t, p.drones && p.drones[d] ? p.drones[d][key] : null]),
  }));
}
function renderCharts() {
  const fleet = (key) => ({ color: "#e6edf3", points: state.series.map((p) => [p.t, p[key]]) });
  drawChart("ch-xi", perDrone("xi"), { yScale: 1 / 1000 });
  drawChart("ch-goodput", [fleet("goodput"), ...perDrone("goodput")], { yScale: 1 / 1000 });
  drawChart("ch-latency", perDrone("latency"));
  drawChart("ch-delta", perDrone("delta"));
  drawChart("ch-loss", perDrone("loss"), { fixedMax: 1 });
  $("legend").innerHTML = `<span><i style="background:#e6edf3"></i>fleet</span>` +
    [...state.drones.keys()].sort().map((d) => `<span><i style="background:${color(d)}"></i>${esc(d)}</span>`).join("");
}

// -- alerts, mission ---------------------------------------------------------------------------
function renderAlerts() {
  $("alerts").innerHTML = state.alerts.slice(0, 100).map((a) =>
    `<li class="${esc(a.level)}"><span class="t">${fmt.time(a.t)}</span>${a.drone ? `<b>${esc(a.drone)}</b> ` : ""}${esc(a.text)}</li>`).join("")
    || `<li class="muted">no alerts</li>`;
}
function renderDrops() {
  const entries = Object.entries(state.drops || {});
  $("drops").innerHTML = entries.length
    ? "drops: " + entries.map(([r, n]) => `<span>${esc(r)} ${n}</span>`).join("")
    : `<span class="muted">no datagrams dropped</span>`;
}
// The phase follows the clock (same rule as MissionManager.phase), so the badge turns from
// "scheduled" to "running" when the start time passes, without waiting for a server event.
function missionPhase(m, t) {
  if (!m.t_start) return "idle";
  if (m.t_end && t >= m.t_end && m.t_end >= m.t_start) return "ended";
  return t < m.t_start ? "scheduled" : "running";
}
function renderBadge() {
  const m = state.mission;
  if (!m) return;
  const phase = missionPhase(m, now());
  const badge = $("mission-phase");
  if (badge.textContent !== phase) { badge.textContent = phase; badge.className = "badge " + phase; }
}
// One command: acks, then per drone done / error (with its reason) / no reply.
function commandLine(c, known) {
  const s = c.summary || {};
  const total = s.total || Math.max(c.sent_to.length, known);
  let text = `#${c.command_id} <b>${esc(c.name)}</b> @ ${fmt.time(c.t_exec)} — acked ${c.acked_by.length}/${total}` +
    ` · <span class="${s.done === total && total ? "ok" : ""}">done ${s.done || 0}/${total}</span>`;
  if (s.error) text += ` · <span class="err">error ${s.error}</span>`;
  if (s["no reply"]) text += ` · <span class="err">no reply ${s["no reply"]}</span>`;
  const bad = Object.entries(c.results || {}).filter(([, e]) => e.result === "error" || e.result === "no reply")
    .map(([d, e]) => `<div class="cmd-detail">${esc(d)}: ${esc(e.result)}${e.reason ? " — " + esc(e.reason) : ""}</div>`).join("");
  const counters = Object.entries(c.results || {}).filter(([, e]) => e.info && e.info.counters)
    .map(([d, e]) => `<div class="cmd-detail">${esc(d)}: ${Object.entries(e.info.counters).map(([k, v]) => `${esc(k)} ${esc(v)}`).join(", ")}</div>`).join("");
  return `<div class="cmd" data-command="${c.command_id}">${text}${bad}${counters}</div>`;
}
function renderMission() {
  const m = state.mission;
  if (!m) return;
  $("mission-name").textContent = state.config.mission || "–";
  renderBadge();
  $("mission-times").textContent = (m.t_start ? "start " + fmt.time(m.t_start) : "") + (m.t_end ? " · end " + fmt.time(m.t_end) : "");
  const cmds = (m.commands || []).slice(-5).reverse().map((c) => commandLine(c, m.drones.length)).join("");
  const reports = Object.entries(m.reports || {}).map(([k, v]) => `${esc(k)}: ${v}`).join(", ");
  const params = Object.entries(m.params || {}).map(([k, v]) => `${esc(k)}=${esc(v)}`).join(", ");
  $("mission-info").innerHTML = `<div>drones known: <b>${m.drones.length}</b></div>` +
    `<div>reports: ${reports || "–"}</div><div>params: ${params || "–"}</div>` + (cmds || "<div class='muted'>no commands yet</div>");
}

// -- gallery ------------------------------------------------------------------------------------
function fillDroneFilter() {
  const sel = $("g-drone"), have = new Set([...sel.options].map((o) => o.value));
  for (const d of [...state.drones.keys()].sort()) {
    if (!have.has(d)) { const o = document.createElement("option"); o.value = d; o.textContent = d; sel.appendChild(o); }
  }
}
function whySent(im) {
  const what = im.object ? "object" : im.red != null ? "red " + fmt.pct(im.red) : "plain";
  const version = im.version == null ? "single version" : im.version === 0 ? "v0 (best)" : "v" + im.version;
  return `U ${fmt.num(im.utility, 2)} (${what}) · ${version} · ${fmt.pct(im.window_share)} of link`;
}
async function renderGallery() {
  fillDroneFilter();
  const q = new URLSearchParams({ limit: "24", object: $("g-object").value });
  if ($("g-drone").value) q.set("drone", $("g-drone").value);
  try {
    const body = await api("/api/images?" + q);
    const high = state.config.high_utility;
    $("gallery").innerHTML = body.images.map((im) => `
      <figure class="${high != null && im.utility >= high ? "high" : ""}" data-id="${im.id}">
        <img loading="lazy" src="${im.url}" alt="${esc(im.sender)} #${im.seq}">
        <figcaption><b style="color:${color(im.sender)}">${esc(im.sender)}</b> #${im.seq} · <span class="muted">${fmt.time(im.t_gen)}</span>${im.pose === "none" ? ` · <span class="stale">no position</span>` : im.pose === "stale" ? ` · <span class="stale">position ${fmt.num(im.pose_age_s, 1)} s old</span>` : ""}
        <div class="why" title="why the drone sent it: its utility, the version it chose (0 = best quality) and the drone's share of the link in the ${body.window_s || 5} s before it arrived">why sent: ${whySent(im)}</div></figcaption>
      </figure>`).join("") || `<p class="muted">no stored images yet</p>`;
  } catch (e) { /* token box already shown */ }
}

// -- mission buttons --------------------------------------------------------------------------
async function command(path, body, label) {
  try {
    const res = await api(path, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
    state.mission = res.mission; renderMission();
    const c = res.command;
    toast(c ? `${label}: command #${c.command_id} at ${fmt.time(c.t_exec)} sent to ${res.mission.drones.length} drone(s)` : label);
  } catch (e) { toast(`${label} failed: ${e.message}`); }
}
function initButtons() {
  $("btn-start").onclick = () => command("/api/mission/start", { delay_s: Number($("start-delay").value || 0) }, "start mission");
  $("btn-end").onclick = () => command("/api/mission/end", { delay_s: Number($("start-delay").value || 0) }, "end mission");
  $("btn-params").onclick = () => command("/api/mission/params", { params: $("params").value }, "set params");
  $("btn-report").onclick = () => command("/api/mission/report", {}, "request report");
  $("btn-reset").onclick = () => command("/api/mission/reports/reset", {}, "reports reset");
  $("g-drone").onchange = renderGallery;
  $("g-object").onchange = renderGallery;
  $("g-refresh").onclick = renderGallery;
}

initToken();
initButtons();
connect();
renderGallery();
setInterval(renderGallery, 5000);
setInterval(() => { $("clock").textContent = new Date(now() * 1000).toLocaleTimeString(); renderBadge(); }, 500);
window.addEventListener("resize", renderCharts);
