// Ground-station dashboard: plain JS, no libraries, no network beyond this server.
"use strict";

// 12 colours readable on the dark background, neighbours far apart in hue (uav1, uav2, ...).
const PALETTE = ["#4aa3ff", "#ffa657", "#3fb950", "#f778ba", "#e3b341", "#a371f7",
  "#56d4dd", "#ff7b72", "#b5e853", "#d2a8ff", "#2ec4a6", "#c9b18a"];
const state = {
  drones: new Map(), series: [], alerts: [], drops: {}, mission: null,
  config: {}, ws: null, dirty: new Set(), frame: false, colors: new Map(), imgTimes: new Map(),
  trails: new Map(),
  clockOffset: 0,
};
const $ = (id) => document.getElementById(id);

// -- token ---------------------------------------------------------------------------------
// The page never holds the token: the server keeps the session in an HttpOnly cookie, set by
// the one-time login link (/?login=...) or by sending the token once from the token box.
// The cookie also goes to every other port of this host, so it opens nothing alone: each
// request carries the page key too, which the login hands to this page only (the link's
// redirect fragment, the token box's answer) and localStorage keeps per origin, port included.
function initToken() {
  localStorage.removeItem("gs-token");  // left by older versions
  const m = /^#key=([0-9a-f]+)$/.exec(location.hash);
  if (m) {
    localStorage.setItem("gs-key", m[1]);
    history.replaceState(null, "", location.pathname + location.search);
  }
  $("token-save").onclick = async () => {
    const token = $("token-input").value.trim();
    $("token-input").value = "";
    const res = await fetch("/api/login", { method: "POST", headers: { Authorization: "Bearer " + token } });
    if (!res.ok) { toast("token refused"); return; }
    localStorage.setItem("gs-key", (await res.json()).key);
    location.reload();
  };
}
const pageKey = () => localStorage.getItem("gs-key") || "";
// For what cannot send a header (images, the WebSocket): the key in the query string.
const keyed = (url) => url + (url.includes("?") ? "&" : "?") + "key=" + encodeURIComponent(pageKey());
async function api(path, options = {}) {
  const headers = { ...(options.headers || {}), "X-GS-Key": pageKey() };
  const res = await fetch(path, { ...options, headers, credentials: "same-origin" });
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
  pct: (v) => (v === null || v === undefined ? "–" : Math.round(v * 100) + "\u00a0%"),  // never "23 / %"
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
  const ws = new WebSocket(keyed(`${proto}//${location.host}/ws`));
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
      for (const d of msg.drones) { state.drones.set(d.drone, d); state.dirty.add(d.drone); recordTrail(d); }
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
      recordTrail(msg.drone);
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
      <tr class="peers-row" hidden><td title="peers this drone knows on the shared medium, with the age of each one's position">peers</td><td class="v-peers" colspan="3"></td></tr>
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
      el.querySelector("img").src = keyed(`/api/drones/${encodeURIComponent(d.drone)}/latest.jpg?s=${img.seq}`);
      state.imgTimes.set(d.drone, { tag, at: performance.now() });
    } else if (last.tag !== tag) {
      state.dirty.add(d.drone);
      setTimeout(schedule, 220);
    }
  }
  el.querySelector(".v-fps").textContent = fmt.num(d.fps, 1);
  el.querySelector(".v-lat").textContent = d.latency_s === null ? "–" : fmt.num(d.latency_s * 1000, 0) + " ms";
  el.querySelector(".v-share").innerHTML = `${fmt.pct(d.goodput_share)}<span class="meter"><i style="width:${Math.round((d.goodput_share || 0) * 100)}%"></i></span>`;
  const b = d.battery;
  el.querySelector(".v-batt").innerHTML = b === null ? "–" : `${fmt.pct(b)}<span class="meter batt${b < 0.25 ? " low" : ""}"><i style="width:${Math.round(b * 100)}%"></i></span>`;
  el.querySelector(".v-mode").textContent = (d.mode || "–") + (d.failsafe ? " · FAILSAFE" : "") + (d.autopilot_connected === false ? " · autopilot lost" : "") + (d.mission && d.mission !== "running" ? " · mission " + d.mission : "");
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
    const meter = cell.querySelector(".meter");  // the age goes next to the value, above its bar
    (meter || cell).insertAdjacentHTML(meter ? "beforebegin" : "beforeend", ` <small class="age">${now < 1 ? "" : fmt.num(now, 0) + " s"}</small>`);
  }
  el.querySelector(".v-heard").textContent = fmt.age(d.age_s);
  el.querySelector(".v-fallback").textContent = d.fallback_share == null ? "–" : (d.fallback_share * 100).toFixed(1) + " %";
  // Peer sharing (issue 15): which peers the drone knows, and how old each position is.
  el.querySelector(".peers-row").hidden = d.peers == null;
  if (d.peers != null) {
    const names = Object.keys(d.peers);
    el.querySelector(".v-peers").textContent = names.length ? names.map((p) => `${p} ${fmt.num(d.peers[p] + later, 1)} s`).join(" · ") : "none yet";
  }
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
    // U is the full image's weight times the version sent (eq. 4.33): a half-size copy of a
    // plain frame shows U 0.50, which read as wrong against "1 plain" alone.
    $("key-scale").textContent = `${fmt.num(sc.plain, 0)} plain … ${fmt.num(sc.max, 0)} best (${sc.source}), × the version sent (half size 0.5)`;
    $("key-high").title = sc.fraction == null ? "set in the ground-station config"
      : `1 + ${sc.fraction} × ${fmt.num(sc.max - sc.plain, 1)}: ${Math.round(sc.fraction * 100)} % of the largest gain`;
  }
}

// -- fleet map -------------------------------------------------------------------------------
// Local east/north metres (from the scene's home when the server knows the scene). The scene
// (area, red objects, targets, home) is drawn under per-drone trails; labels are placed so
// that they neither overlap each other nor the dots, nor leave the map.
const TRAIL_POINTS = 300;
function recordTrail(d) {
  if (d.x_m === null || d.x_m === undefined || d.y_m === null) return;
  let trail = state.trails.get(d.drone);
  if (!trail) { trail = []; state.trails.set(d.drone, trail); }
  const last = trail[trail.length - 1];
  if (!last || Math.hypot(last[0] - d.x_m, last[1] - d.y_m) >= 0.5) trail.push([d.x_m, d.y_m]);
  if (trail.length > TRAIL_POINTS) trail.splice(0, trail.length - TRAIL_POINTS);
}
function niceStep(raw) {
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  return [1, 2, 5, 10].map((k) => k * mag).find((v) => v >= raw);
}
function boxOverlap(a, b) {
  const w = Math.min(a.x + a.w, b.x + b.w) - Math.max(a.x, b.x);
  const h = Math.min(a.y + a.h, b.y + b.h) - Math.max(a.y, b.y);
  return w > 0 && h > 0 ? w * h : 0;
}
// Greedy: each label takes the first free spot around its dot (near ring, then far ring with
// a leader line); if none is free, the least overlapping one that stays inside the map.
function placeLabels(items, W, H, taken) {
  const placed = [];
  for (const it of items) {
    const w = it.text.length * 6.4 + 4, h = 13;
    const spots = [];  // rings of growing distance, 12 directions each, right side first
    for (const r of [9, 22, 36, 52, 70, 90]) {
      for (let k = 0; k < 12; k++) {
        const a = (k * Math.PI) / 6, dx = Math.cos(a), dy = -Math.sin(a);
        spots.push([it.x + r * dx - (dx < -0.3 ? w : dx > 0.3 ? 0 : w / 2),
          it.y + r * dy - (dy < -0.3 ? h : dy > 0.3 ? 0 : h / 2)]);
      }
    }
    let best = null, bestScore = Infinity;
    for (const [x, y] of spots) {
      const box = { x, y, w, h };
      if (x < 2 || y < 2 || x + w > W - 2 || y + h > H - 2) continue;
      let score = 0;
      for (const o of [...taken, ...placed]) score += boxOverlap(box, o);
      if (score < bestScore) { best = box; bestScore = score; }
      if (score === 0) break;
    }
    if (!best) best = { x: Math.min(Math.max(2, it.x + 9), W - w - 2), y: Math.min(Math.max(2, it.y - h / 2), H - h - 2), w, h };
    placed.push(best);
    it.box = best;
  }
  return items;
}
function renderMap() {
  const svg = $("map");
  const scene = state.config.scene;
  const pts = [...state.drones.values()].filter((d) => d.x_m !== null && d.x_m !== undefined && d.y_m !== null);
  const W = 300, H = 300, pad = 12;
  const xs = [], ys = [];
  if (scene) { xs.push(scene.area.west_m, scene.area.east_m); ys.push(scene.area.south_m, scene.area.north_m); }
  for (const d of pts) { xs.push(d.x_m); ys.push(d.y_m); }
  if (!scene) for (const tr of state.trails.values()) for (const [x, y] of tr) { xs.push(x); ys.push(y); }
  let span = 20, cx = 0, cy = 0;
  if (xs.length) {
    const minx = Math.min(...xs), maxx = Math.max(...xs), miny = Math.min(...ys), maxy = Math.max(...ys);
    span = Math.max(20, maxx - minx, maxy - miny) * (scene ? 1.04 : 1.2);
    cx = (minx + maxx) / 2; cy = (miny + maxy) / 2;
  }
  const scale = (W - 2 * pad) / span;
  const sx = (x) => W / 2 + (x - cx) * scale, sy = (y) => H / 2 - (y - cy) * scale;
  const f = (v) => v.toFixed(1);
  const step = niceStep(span / 5);
  let html = "";
  for (let g = Math.ceil((cx - span) / step) * step; g <= cx + span; g += step) html += `<line x1="${f(sx(g))}" y1="0" x2="${f(sx(g))}" y2="${H}" stroke="#17202a"/>`;
  for (let g = Math.ceil((cy - span) / step) * step; g <= cy + span; g += step) html += `<line x1="0" y1="${f(sy(g))}" x2="${W}" y2="${f(sy(g))}" stroke="#17202a"/>`;
  const taken = [];  // boxes labels must avoid: dots, scene marks, scale bar, north arrow
  if (scene) {
    const a = scene.area;
    html += `<rect class="area" x="${f(sx(a.west_m))}" y="${f(sy(a.north_m))}" width="${f((a.east_m - a.west_m) * scale)}" height="${f((a.north_m - a.south_m) * scale)}" fill="#1a2a1f" fill-opacity=".45" stroke="#5b6b7c" stroke-dasharray="4 3"/>`;
    for (const r of scene.red_objects) {
      if (r.shape === "box") {
        html += `<rect class="red-object" x="${f(sx(r.east_m) - (r.width_m * scale) / 2)}" y="${f(sy(r.north_m) - (r.length_m * scale) / 2)}" width="${f(Math.max(2, r.width_m * scale))}" height="${f(Math.max(2, r.length_m * scale))}" transform="rotate(${r.heading_deg} ${f(sx(r.east_m))} ${f(sy(r.north_m))})" fill="#ff2d2d" fill-opacity=".55"/>`;
      } else {
        html += `<circle class="red-object" cx="${f(sx(r.east_m))}" cy="${f(sy(r.north_m))}" r="${f(Math.max(1.5, r.radius_m * scale))}" fill="#ff2d2d" fill-opacity=".55"/>`;
      }
    }
    for (const t of scene.targets) {
      const s = Math.max(5, t.size_m * scale), x = sx(t.east_m), y = sy(t.north_m);
      html += `<rect class="target" x="${f(x - s / 2)}" y="${f(y - s / 2)}" width="${f(s)}" height="${f(s)}" fill="#e6edf3" stroke="#0b1016"><title>ArUco target ${t.id}${t.name ? " " + esc(t.name) : ""}</title></rect>`;
      taken.push({ x: x - s / 2 - 1, y: y - s / 2 - 1, w: s + 2, h: s + 2 });
    }
    const hx = sx(0), hy = sy(0);
    html += `<path class="home" d="M${f(hx)} ${f(hy - 6)} L${f(hx + 5)} ${f(hy + 4)} L${f(hx - 5)} ${f(hy + 4)} Z" fill="#e3b341"><title>home</title></path>`;
    taken.push({ x: hx - 6, y: hy - 7, w: 12, h: 12 });
  }
  for (const [drone, trail] of state.trails) {
    if (trail.length < 2 || !state.drones.has(drone)) continue;
    html += `<polyline class="trail" points="${trail.map(([x, y]) => f(sx(x)) + "," + f(sy(y))).join(" ")}" fill="none" stroke="${color(drone)}" stroke-opacity=".5" stroke-width="1.4"/>`;
  }
  // scale bar (bottom left) and north arrow (top right)
  const bar = niceStep(span / 5), barPx = bar * scale;
  html += `<g class="scalebar"><line x1="10" y1="${H - 12}" x2="${f(10 + barPx)}" y2="${H - 12}" stroke="#e6edf3" stroke-width="2"/>` +
    `<line x1="10" y1="${H - 16}" x2="10" y2="${H - 8}" stroke="#e6edf3"/><line x1="${f(10 + barPx)}" y1="${H - 16}" x2="${f(10 + barPx)}" y2="${H - 8}" stroke="#e6edf3"/>` +
    `<text x="${f(14 + barPx)}" y="${H - 8}" fill="#e6edf3" font-size="10">${bar} m</text></g>`;
  taken.push({ x: 6, y: H - 22, w: barPx + 50, h: 18 });
  html += `<text x="${W - 14}" y="14" fill="#8b98a5" font-size="11">N</text>`;
  taken.push({ x: W - 18, y: 2, w: 16, h: 16 });
  const items = [];
  for (const d of pts) {
    const x = sx(d.x_m), y = sy(d.y_m), c = color(d.drone);
    if (d.heading_deg !== null && d.heading_deg !== undefined) {
      const a = (d.heading_deg * Math.PI) / 180;
      html += `<line x1="${f(x)}" y1="${f(y)}" x2="${f(x + 14 * Math.sin(a))}" y2="${f(y - 14 * Math.cos(a))}" stroke="${c}" stroke-width="2"/>`;
    }
    const hi = d.latest_image && d.latest_image.high;
    html += `<circle class="drone" data-drone="${esc(d.drone)}" cx="${f(x)}" cy="${f(y)}" r="6" fill="${c}" stroke="${hi ? "#ff2d2d" : "#0b1016"}" stroke-width="${hi ? 3 : 1.5}" opacity="${d.link_lost ? 0.4 : 1}"/>`;
    taken.push({ x: x - 8, y: y - 8, w: 16, h: 16 });
    items.push({ x, y, c, text: d.drone + (d.alt_m !== null && d.alt_m !== undefined ? " " + fmt.num(d.alt_m, 0) + " m" : "") });
  }
  for (const it of placeLabels(items.sort((a, b) => a.y - b.y), W, H, taken)) {
    const b = it.box, far = Math.hypot(b.x + b.w / 2 - it.x, b.y + b.h / 2 - it.y) > 20;
    if (far) html += `<line x1="${f(it.x)}" y1="${f(it.y)}" x2="${f(Math.min(Math.max(it.x, b.x), b.x + b.w))}" y2="${f(Math.min(Math.max(it.y, b.y), b.y + b.h))}" stroke="${it.c}" stroke-opacity=".6"/>`;
    html += `<text class="label" x="${f(b.x + 2)}" y="${f(b.y + 10)}" fill="${it.c}" font-size="11">${esc(it.text)}</text>`;
  }
  if (!pts.length) html += `<text x="${W / 2}" y="${H / 2}" fill="#8b98a5" font-size="12" text-anchor="middle">no positions yet</text>`;
  svg.innerHTML = html;
  $("map-key").classList.toggle("hidden", !scene);
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
  let text = `#${c.command_id} <b>${esc(c.name)}</b> @ ${fmt.time(c.t_exec)} — acked ${c.acked_by.length}/${total}`;
  if (c.superseded_by) text += ` · superseded by #${esc(c.superseded_by)} before it ran`;  // not sent, skipped
  if (!c.superseded_by || s.done) text += ` · <span class="${s.done === total && total ? "ok" : ""}">done ${s.done || 0}/${total}</span>`;
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
  const kv = (o) => Object.entries(o || {}).map(([k, v]) => `${esc(k)}=${esc(v)}`).join(", ");
  const params = kv(m.params), rejected = kv(m.params_rejected);
  $("mission-info").innerHTML = `<div>drones known: <b>${m.drones.length}</b></div>` +
    `<div>reports: ${reports || "–"}</div><div id="mission-params" title="set by a command some drone applied (or has not answered yet); each command below says which">params: ${params || "–"}</div>` +
    (rejected ? `<div id="mission-params-rejected" class="err" title="every drone that answered rejected these; nothing of those commands changed">rejected: ${rejected}</div>` : "") +
    (cmds || "<div class='muted'>no commands yet</div>");
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
        <img loading="lazy" src="${esc(keyed(im.url))}" alt="${esc(im.sender)} #${im.seq}">
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
