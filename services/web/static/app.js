// SkyNet Inspect live fleet page: plain JavaScript, no build step. Reads the WebSocket at /ws:
// a "static" document (scenario, planned paths) then "snapshot"s at 5-10 Hz (services/web/view.py).
// Everything in them came from the bus: it is put in the page as text (textContent, DOM nodes), never as HTML.
"use strict";
const COLOURS = ["#4cf", "#fc4", "#f6c", "#6f6", "#f84", "#a8f", "#ccc", "#4fa", "#f44", "#48f", "#ff8", "#8ff"];
let world = null;          // the static document
let snap = null;           // the newest snapshot
let updates = [];          // arrival times of snapshots (update rate shown in the header)
let connected = false;     // the WebSocket is open
window.skynet = { snapshots: 0 };  // read by the browser test

function colour(uav) { return COLOURS[(Number(uav) - 1) % COLOURS.length]; }

function projector(canvas, xr, yr) {  // world (a, b) -> canvas pixels, equal scale on both axes
  const pad = 10, w = canvas.width - 2 * pad, h = canvas.height - 2 * pad;
  const s = Math.min(w / (xr[1] - xr[0]), h / (yr[1] - yr[0]));
  return (a, b) => [pad + (a - xr[0]) * s, canvas.height - pad - (b - yr[0]) * s, s];
}

function path(ctx, pts, P, ia, ib) {
  ctx.beginPath();
  pts.forEach((p, k) => { const [x, y] = P(p[ia], p[ib]); k ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
  ctx.stroke();
}

function drawView(id, ia, ib) {
  const c = document.getElementById(id), ctx = c.getContext("2d");
  ctx.clearRect(0, 0, c.width, c.height);
  if (!world || !world.box) return;
  const lo = world.box.lo, hi = world.box.hi, P = projector(c, [lo[ia], hi[ia]], [lo[ib], hi[ib]]);
  ctx.strokeStyle = "#555"; ctx.lineWidth = 1;
  const [x0, y0] = P(lo[ia], lo[ib]), [x1, y1] = P(hi[ia], hi[ib]);
  ctx.strokeRect(x0, y1, x1 - x0, y0 - y1);
  ctx.fillStyle = "#433";
  for (const o of world.obstacles || []) {
    if (ib === 1) {  // top view: circles
      const [x, y, s] = P(o.centre[0], o.centre[1]);
      ctx.beginPath(); ctx.arc(x, y, o.radius * s, 0, 2 * Math.PI); ctx.fill();
    } else {         // side view: rectangles standing on the ground
      const a = ia === 1 ? o.centre[1] : o.centre[0];
      const [xa, yg] = P(a - o.radius, 0), [xb, yt] = P(a + o.radius, o.height);
      ctx.fillRect(xa, yt, xb - xa, yg - yt);
    }
  }
  if (world.wall) { ctx.strokeStyle = "#9c6"; ctx.lineWidth = 3; path(ctx, [...world.wall, world.wall[0]], P, ia, ib); }
  ctx.lineWidth = 1; ctx.setLineDash([4, 4]);
  for (const [uav, pts] of Object.entries(world.planned || {})) { ctx.strokeStyle = colour(uav) + "88"; path(ctx, pts, P, ia, ib); }
  ctx.setLineDash([]);
  if (!snap) return;
  for (const [uav, u] of Object.entries(snap.uavs)) {
    ctx.strokeStyle = colour(uav); ctx.lineWidth = 1.5;
    if (u.trail && u.trail.length > 1) path(ctx, u.trail, P, ia, ib);
    if (u.pos) {
      const [x, y] = P(u.pos[ia], u.pos[ib]);
      ctx.fillStyle = colour(uav); ctx.beginPath(); ctx.arc(x, y, 5, 0, 2 * Math.PI); ctx.fill();
      ctx.fillText(uav, x + 7, y - 7);
    }
  }
}

function drawWall() {
  const c = document.getElementById("wall"), ctx = c.getContext("2d");
  ctx.clearRect(0, 0, c.width, c.height);
  if (!world || !world.wall) return;
  const [p0, p1, , p3] = world.wall;
  const sub = (a, b) => a.map((v, k) => v - b[k]), dot = (a, b) => a.reduce((s, v, k) => s + v * b[k], 0);
  const len = (a) => Math.sqrt(dot(a, a)), eu = sub(p1, p0), ev = sub(p3, p0), L = len(eu), H = len(ev);
  const P = projector(c, [0, L], [0, H]);
  const [x0, y0] = P(0, 0), [x1, y1] = P(L, H);
  ctx.fillStyle = "#2a2a22"; ctx.fillRect(x0, y1, x1 - x0, y0 - y1);
  if (!snap) return;
  for (const d of snap.defects) {
    const r = sub(d.pos, p0), [x, y] = P(dot(r, eu) / L, dot(r, ev) / H);
    ctx.fillStyle = colour(d.uav); ctx.fillRect(x - 2, y - 2, 4, 4);
  }
}

function fmt(v, nd) { return v === undefined || v === null ? "-" : Number(v).toFixed(nd); }

function el(tag, text, cls) {  // an element holding text as text (bus data is never parsed as HTML)
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  if (cls) e.className = cls;
  return e;
}

function safeUav(uav) { return /^[0-9]{1,3}$/.test(String(uav)) ? String(uav) : null; }  // keys are UAV numbers

function updateTable() {
  const body = document.querySelector("#uavs tbody"), previews = document.getElementById("previews");
  const rows = [];
  for (const [key, u] of Object.entries(snap.uavs)) {
    const uav = safeUav(key);
    if (uav === null) continue;
    const tr = document.createElement("tr");
    tr.dataset.uav = uav;
    const id = el("td", uav); id.style.color = colour(uav); tr.appendChild(id);
    tr.appendChild(el("td", u.mode || "-", "mode"));
    tr.appendChild(el("td", u.battery === undefined ? "-" : Math.round(100 * u.battery) + " %"));
    tr.appendChild(el("td", fmt(u.rate_hz, 1)));
    tr.appendChild(el("td", fmt(u.age_s, 1) + " s", u.age_s > 1 ? "stale" : ""));
    tr.appendChild(el("td", u.captures ?? "-"));
    tr.appendChild(el("td", u.progress === undefined ? "-" : Math.round(100 * u.progress) + " %"));
    tr.appendChild(el("td", Array.isArray(u.pos) ? u.pos.map((v) => Number(v).toFixed(1)).join(", ") : "-", "pos"));
    rows.push(tr);
    let img = document.getElementById("preview-" + uav);
    if (!img && u.preview > 0) {
      const fig = document.createElement("figure");
      img = document.createElement("img");
      img.id = "preview-" + uav; img.alt = "UAV " + uav + " preview";
      fig.appendChild(img); fig.appendChild(el("figcaption", "UAV " + uav));
      previews.appendChild(fig);
    }
    if (img && u.preview > 0 && img.dataset.seq !== String(u.preview)) {
      img.dataset.seq = String(u.preview);
      img.src = "/preview/" + uav + ".jpg?n=" + encodeURIComponent(String(u.preview));
    }
  }
  body.replaceChildren(...rows);
}

const LEVELS = new Set(["info", "warning", "error"]);

function updateEvents() {
  const box = document.getElementById("events");
  const lines = snap.events.slice().reverse().map((e) => {
    const t = Number(e.t), when = Number.isFinite(t) && Math.abs(t) < 1e11 ? new Date(t * 1000).toISOString().slice(11, 19) : "--:--:--";
    const line = el("div", `${when} ${e.source} ${e.kind} ${e.text}`, LEVELS.has(e.level) ? e.level : "");
    line.dataset.kind = String(e.kind);
    return line;
  });
  box.replaceChildren(...lines);
}

function render() {
  if (!snap) return;
  document.getElementById("formation").textContent = snap.formation_error_m === null ? "-" : snap.formation_error_m.toFixed(2) + " m";
  document.getElementById("tracking").textContent = snap.tracking_error_m === null ? "-" : snap.tracking_error_m.toFixed(2) + " m";
  document.getElementById("defect-count").textContent = snap.defect_count === null ? "-" : String(snap.defect_count);
  document.getElementById("detections").textContent = String(snap.detections);
  document.getElementById("reports").textContent = String(snap.reports);
  const conn = document.getElementById("conn");  // the data's source once the page is connected
  if (connected) {
    conn.textContent = snap.source === "replay" ? "replay" : snap.source === "live+replay" ? "live + replay" : "live";
    conn.className = snap.source && snap.source !== "live" ? "replay" : "";
  }
  const now = performance.now();
  updates = updates.filter((t) => t > now - 2000);
  document.getElementById("rate").textContent = (updates.length / 2).toFixed(1);
  updateTable(); updateEvents();
  drawView("top", 0, 1); drawView("side", 1, 2); drawWall();
}

function connect() {
  const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws");
  ws.onopen = () => { connected = true; document.getElementById("conn").textContent = "live"; };
  ws.onclose = () => {
    connected = false;
    const conn = document.getElementById("conn");
    conn.textContent = "reconnecting"; conn.className = "";
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (msg.type === "static") { world = msg; document.getElementById("fleet").textContent = msg.fleet; }
    else if (msg.type === "snapshot") { snap = msg; updates.push(performance.now()); window.skynet.snapshots++; }
    requestAnimationFrame(render);
  };
}
connect();
