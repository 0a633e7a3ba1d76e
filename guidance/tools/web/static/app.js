// guidance monitor --web: polls /api/fleet and draws every car on a local-metre grid
// (x east, y north), with map tiles underneath when a tile server is configured.
// Text from the cars is only ever set with textContent, never parsed as HTML.
// Each car is drawn on its own (try/catch): a state this page cannot draw costs that car its
// drawing (listed in the status line), never the other cars. The monitor's check
// (guidance/tools/monitor_check.py, the state's JSON Schema) already rejects such states.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const EARTH_M = 6378137.0;
const MIN_ELLIPSE_PX = 6;  // an ellipse smaller than this is drawn at this size, dashed
const state = { config: { tiles: "", poll_ms: 250 }, ref: null, failures: 0, view: null,
                last: null, colours: null, epoch: "", generation: null, tracks: new Map() };
const TRACK_POINTS_KEPT = 20000;  // per car, as the monitor keeps

// After the first answer the page asks only for the track points written since its last one
// (server.py): each car's answer then holds track_start (the car's index of its first point;
// the point before may be the newest position, replaced) and the points from there. The page
// keeps each car's track and splices the new points in; a whole track (track_start null)
// replaces it.
function mergeTracks(fleet) {
  const seen = new Set();
  for (const c of fleet.cars) {
    if (!c || !Array.isArray(c.track)) continue;  // drawCar reports this car as not drawn
    const vid = String(c.vehicle_id);
    seen.add(vid);
    const sent = c.track;
    let kept = state.tracks.get(vid);
    if (typeof c.track_start !== "number" || !kept) {
      kept = { points: sent.slice(), end: typeof c.track_total === "number" ? c.track_total : sent.length };
    } else {
      const drop = Math.min(kept.points.length, Math.max(0, kept.end - c.track_start));
      kept.points.length -= drop;
      for (const pt of sent) kept.points.push(pt);
      kept.end = c.track_start + sent.length;
      if (kept.points.length > TRACK_POINTS_KEPT) kept.points.splice(0, kept.points.length - TRACK_POINTS_KEPT);
    }
    state.tracks.set(vid, kept);
    c.track = kept.points;
  }
  for (const vid of [...state.tracks.keys()]) if (!seen.has(vid)) state.tracks.delete(vid);
  state.epoch = typeof fleet.epoch === "string" ? fleet.epoch : "";
  state.generation = typeof fleet.generation === "number" ? fleet.generation : null;
}

function el(name, attrs, parent) {
  const e = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, String(v));
  if (parent) parent.appendChild(e);
  return e;
}

function html(tag, cls, text, parent) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined && text !== null) e.textContent = String(text);
  if (parent) parent.appendChild(e);
  return e;
}

// A car keeps its colour for good: picked once per vehicle id (its FNV-1a hash, moved on to
// the next colour not yet given to another car) and remembered in localStorage, so it is the
// same after a reload and never handed to another car when one goes (a colour by order in the
// list moved when a car went). Beyond 12 cars colours repeat.
const COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#e8700c", "#0f8f9c",
                 "#8c564b", "#d6479b", "#7f7f00", "#393b79", "#637939", "#843c39"];
const COLOUR_KEY = "guidance-monitor-colours";
const MAX_REMEMBERED = 500;

function colours() {
  if (!state.colours) {
    try { state.colours = new Map(JSON.parse(localStorage.getItem(COLOUR_KEY) || "[]")); }
    catch (err) { state.colours = new Map(); }
  }
  return state.colours;
}

function colour(vid) {
  const known = colours();
  if (!known.has(vid)) {
    let h = 0x811c9dc5;
    for (const ch of String(vid)) {
      h ^= ch.codePointAt(0);
      h = Math.imul(h, 0x01000193) >>> 0;
    }
    const used = new Set(known.values());
    let i = h % COLOURS.length;
    for (let k = 0; k < COLOURS.length && used.has(i); k++) i = (i + 1) % COLOURS.length;
    known.set(vid, used.has(i) ? h % COLOURS.length : i);
    while (known.size > MAX_REMEMBERED) known.delete(known.keys().next().value);
    try { localStorage.setItem(COLOUR_KEY, JSON.stringify([...known])); } catch (err) { /* private mode */ }
  }
  return COLOURS[known.get(vid)];
}

function num(v) { return typeof v === "number" && isFinite(v) ? v : null; }

// [x, y] of an object's two numbers (e.g. "x_m", "y_m"), or null unless both are numbers.
function pair(o, a, b) {
  if (!o || typeof o !== "object") return null;
  const x = num(o[a]), y = num(o[b]);
  return x === null || y === null ? null : [x, y];
}

function compass(headingRad) {  // CCW from east (rad) -> clockwise from north (deg)
  let d = (90 - headingRad * 180 / Math.PI) % 360;
  if (d < 0) d += 360;
  return d >= 359.5 ? 0 : d;
}

// Local metres of a car's origin in the page's reference frame (equirectangular: exact
// enough over a city). Cars without an origin are drawn in their own local metres.
function offset(origin) {
  if (!pair(origin, "lat_deg", "lon_deg") || !state.ref) return [0, 0];
  const lat0 = state.ref.lat_deg * Math.PI / 180;
  const dx = (origin.lon_deg - state.ref.lon_deg) * Math.PI / 180 * EARTH_M * Math.cos(lat0);
  const dy = (origin.lat_deg - state.ref.lat_deg) * Math.PI / 180 * EARTH_M;
  return [dx, dy];
}

function toLatLon(x, y) {
  const lat0 = state.ref.lat_deg * Math.PI / 180;
  return [state.ref.lat_deg + y / EARTH_M * 180 / Math.PI,
          state.ref.lon_deg + x / (EARTH_M * Math.cos(lat0)) * 180 / Math.PI];
}

function fromLatLon(lat, lon) {
  const lat0 = state.ref.lat_deg * Math.PI / 180;
  return [(lon - state.ref.lon_deg) * Math.PI / 180 * EARTH_M * Math.cos(lat0),
          (lat - state.ref.lat_deg) * Math.PI / 180 * EARTH_M];
}

function niceStep(span) {
  const raw = span / 8;
  const p = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}

function bounds(cars) {
  let b = null;
  const add = (x, y, r) => {
    if (x === null || y === null) return;
    r = r || 0;
    if (!b) b = [x - r, y - r, x + r, y + r];
    else b = [Math.min(b[0], x - r), Math.min(b[1], y - r), Math.max(b[2], x + r), Math.max(b[3], y + r)];
  };
  for (const c of cars) {
    try {
      const [ox, oy] = offset(c.state && c.state.origin);
      for (const [x, y] of c.track) add(x + ox, y + oy);
      const s = c.state || {};
      const e = s.ellipse || {};
      const at = pair(s, "x_m", "y_m"), goal = pair(s.goal, "x_m", "y_m");
      if (at) add(at[0] + ox, at[1] + oy, num(e.semi_major_m) || 0);
      if (goal) add(goal[0] + ox, goal[1] + oy);
    } catch (err) { /* this car is left out of the bounds; drawCar reports it */ }
  }
  if (!b) b = [-100, -100, 100, 100];
  const pad = Math.max(20, 0.08 * Math.max(b[2] - b[0], b[3] - b[1]));
  return [b[0] - pad, b[1] - pad, b[2] + pad, b[3] + pad];
}

function projector(b, w, h) {
  // state.view (set by zoom or pan) wins over the automatic fit until a double click
  const v = state.view || { k: Math.min(w / (b[2] - b[0]), h / (b[3] - b[1])),
                            cx: (b[0] + b[2]) / 2, cy: (b[1] + b[3]) / 2 };
  const { k, cx, cy } = v;
  return { k, cx, cy, x: (x) => w / 2 + (x - cx) * k, y: (y) => h / 2 - (y - cy) * k,
           ix: (px) => cx + (px - w / 2) / k, iy: (py) => cy - (py - h / 2) / k };
}

function drawGrid(p, w, h) {
  const g = document.getElementById("grid");
  g.replaceChildren();
  g.setAttribute("class", "grid");
  const x0 = p.ix(0), x1 = p.ix(w), y0 = p.iy(h), y1 = p.iy(0);
  const step = niceStep(Math.max(x1 - x0, y1 - y0));
  for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
    el("line", { x1: p.x(x), y1: 0, x2: p.x(x), y2: h, class: Math.abs(x) < 1e-9 ? "axis" : "" }, g);
    el("text", { x: p.x(x) + 2, y: h - 4 }, g).textContent = `${Math.round(x)} m`;
  }
  for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
    el("line", { x1: 0, y1: p.y(y), x2: w, y2: p.y(y), class: Math.abs(y) < 1e-9 ? "axis" : "" }, g);
    el("text", { x: 2, y: p.y(y) - 2 }, g).textContent = `${Math.round(y)} m`;
  }
  document.getElementById("scale").textContent =
    `grid ${step} m · x east, y north (m)` + (state.ref ? ` · origin ${state.ref.lat_deg.toFixed(5)}, ${state.ref.lon_deg.toFixed(5)}` : "") +
    (state.view ? " · zoomed (double-click: fit all)" : " · wheel: zoom, drag: pan");
}

function drawTiles(p, w, h) {
  const g = document.getElementById("tiles");
  g.replaceChildren();
  if (!state.config.tiles || !state.ref) return;
  const [latN, lonW] = toLatLon(p.ix(0), p.iy(0));
  const [latS, lonE] = toLatLon(p.ix(w), p.iy(h));
  const lat0 = state.ref.lat_deg * Math.PI / 180;
  const z = Math.max(0, Math.min(19, Math.round(Math.log2(2 * Math.PI * EARTH_M * Math.cos(lat0) * p.k / 256))));
  const n = Math.pow(2, z);
  const tx = (lon) => Math.floor((lon + 180) / 360 * n);
  const ty = (lat) => { const r = lat * Math.PI / 180; return Math.floor((1 - Math.log(Math.tan(r) + 1 / Math.cos(r)) / Math.PI) / 2 * n); };
  const lonOf = (x) => x / n * 360 - 180;
  const latOf = (y) => Math.atan(Math.sinh(Math.PI * (1 - 2 * y / n))) * 180 / Math.PI;
  let count = 0;
  for (let x = tx(lonW); x <= tx(lonE); x++) {
    for (let y = ty(latN); y <= ty(latS); y++) {
      if (++count > 100) return;
      const [ax, ay] = fromLatLon(latOf(y), lonOf(x));
      const [bx, by] = fromLatLon(latOf(y + 1), lonOf(x + 1));
      const url = state.config.tiles.replace("{z}", z).replace("{x}", x).replace("{y}", y);
      el("image", { href: url, x: p.x(ax), y: p.y(ay), width: p.x(bx) - p.x(ax), height: p.y(by) - p.y(ay),
                    preserveAspectRatio: "none" }, g);
    }
  }
}

function drawCar(c, p, parent) {
  const s = c.state || {};
  const col = colour(c.vehicle_id);
  const [ox, oy] = offset(s.origin);
  const g = el("g", { class: (c.alive ? "car" : "car gone") + (c.alarm ? " alarm" : ""),
                      "data-vehicle": c.vehicle_id, "data-alive": c.alive,
                      "data-alarm": c.alarm || "" }, parent);
  if (c.track.length > 1) {
    el("polyline", { class: "track", stroke: col,
                     points: c.track.map(([x, y]) => `${p.x(x + ox).toFixed(1)},${p.y(y + oy).toFixed(1)}`).join(" ") }, g);
  }
  const x = num(s.x_m), y = num(s.y_m);
  if (x === null || y === null) return;
  g.setAttribute("data-x", x.toFixed(2));
  g.setAttribute("data-y", y.toFixed(2));
  const px = p.x(x + ox), py = p.y(y + oy);
  const e = s.ellipse || {};
  const a = num(e.semi_major_m), b = num(e.semi_minor_m), o = num(e.orientation_rad);
  let sigma = "";
  if (a !== null && b !== null && o !== null) {
    // to scale when it is big enough to see; else at MIN_ELLIPSE_PX, dashed, its shape kept
    const small = a * p.k < MIN_ELLIPSE_PX;
    const rx = small ? MIN_ELLIPSE_PX : a * p.k;
    const ry = Math.max(small ? MIN_ELLIPSE_PX * (a > 0 ? b / a : 1) : b * p.k, 2);
    el("ellipse", { class: small ? "ellipse min-size" : "ellipse", cx: px, cy: py, rx, ry,
                    transform: `rotate(${(-o * 180 / Math.PI).toFixed(2)} ${px} ${py})`,
                    fill: col, stroke: col, "data-semi-major-m": a, "data-semi-minor-m": b,
                    "data-to-scale": !small, "data-true-rx-px": (a * p.k).toFixed(3) }, g);
    sigma = ` · 2σ ${(2 * a).toFixed(0)} m${small ? " (not to scale)" : ""}`;
  }
  const goal = pair(s.goal, "x_m", "y_m"), target = s.target;
  if (goal) {
    const gx = p.x(goal[0] + ox), gy = p.y(goal[1] + oy);
    const pts = [];
    for (let i = 0; i < 10; i++) {
      const r = i % 2 ? 4 : 10, t = Math.PI / 2 + i * Math.PI / 5;
      pts.push(`${(gx + r * Math.cos(t)).toFixed(1)},${(gy - r * Math.sin(t)).toFixed(1)}`);
    }
    el("polygon", { class: "goal", points: pts.join(" "), fill: col }, g);
  }
  const tp = pair(target, "x_m", "y_m");
  if (tp && target.kind !== "goal") {
    const tx = p.x(tp[0] + ox), ty = p.y(tp[1] + oy);
    el("path", { class: "target", stroke: col, d: `M${tx - 6},${ty - 6}L${tx + 6},${ty + 6}M${tx - 6},${ty + 6}L${tx + 6},${ty - 6}` }, g);
  }
  const h = num(s.heading_rad);
  if (h !== null) {
    el("line", { class: "heading", x1: px, y1: py, x2: px + 16 * Math.cos(h), y2: py - 16 * Math.sin(h),
                 stroke: col, "stroke-width": 3 }, g);
  }
  el("circle", { class: "position", cx: px, cy: py, r: 5, fill: col, stroke: "#fff" }, g);
  const name = (c.alarm ? "⚠ TWO PUBLISHERS: " : "") + (c.alive ? c.vehicle_id : `${c.vehicle_id} (gone)`);
  el("text", { class: "label", x: px + 8, y: py - 8, fill: col }, g).textContent = name + sigma;
}

function chanceText(p) {  // guidance.core.chance.shown: 5 % steps, never "0 %" or "100 %"
  if (p < 0.05) return "<5 %";
  if (p > 0.95) return ">95 %";
  return `${Math.round(p * 20) * 5} %`;
}

function fmt(v, digits, unit) {
  const n = num(v);
  return n === null ? "–" : `${n.toFixed(digits)}${unit}`;
}

function drawCard(c, ul) {
  const s = c.state || {};
  const li = html("li", c.alive ? "card" : "card gone", undefined, ul);
  li.dataset.vehicle = c.vehicle_id;
  li.dataset.alive = String(c.alive);
  li.style.setProperty("--car", colour(c.vehicle_id));
  html("span", "name", c.vehicle_id, li);
  html("span", "state-word", c.alive ? "live" : "gone", li);
  if (c.alarm) {  // two publishers behind this id (guidance/tools/monitor_ids.py)
    const a = html("div", "alarm", `⚠ ${c.alarm}`, li);
    a.title = "Two programs publish as this vehicle id (two zenoh sessions, or sequence " +
      "numbers that go back and both go on): the position shown jumps between them. Give " +
      "each car its own [vehicle] id.";
  }
  const pos = html("div", "position", undefined, li);
  const h = num(s.heading_rad);
  pos.textContent = `x ${fmt(s.x_m, 1, " m")}  y ${fmt(s.y_m, 1, " m")}  hdg ${h === null ? "–" : compass(h).toFixed(0) + "°"}`;
  const geo = pair(s, "lat_deg", "lon_deg");
  if (geo) html("div", "geo", `${geo[0].toFixed(6)}, ${geo[1].toFixed(6)}`, li);
  const axis = html("div", "axis", `2σ axis ${fmt((s.ellipse || {}).major_axis_m, 1, " m")}`, li);
  if (s.lost) html("span", "lost", " LOST", axis);
  const goal = pair(s.goal, "x_m", "y_m"), at = pair(s, "x_m", "y_m");
  if (goal && at) {
    const d = Math.hypot(goal[0] - at[0], goal[1] - at[1]);
    html("div", "goal-text", `to goal (${goal[0].toFixed(0)}, ${goal[1].toFixed(0)}): ${d.toFixed(0)} m`, li);
  }
  const ch = num(s.chance);
  if (ch !== null && ch >= 0 && ch <= 1) {
    const line = html("div", ch < 0.5 ? "chance low" : "chance", `chance of reaching the goal ${chanceText(ch)}`, li);
    line.title = "From the study engine's table for this car's method, landmarks, camera and " +
      "compass, the distance to go and the 2σ axis: the share of simulated cars like it that arrive.";
  }
  if (s.target && s.target.kind === "landmark") html("div", "target-text", `target: landmark ${s.target.id}`, li);
  html("div", "age", `age ${fmt(c.age_s, 1, " s")}`, li);
  if (!c.alive) {  // its last health is no news: say it went, when, and what that means
    const gone = html("div", "health gone-text", c.gone || "gone: liveliness token dropped", li);
    gone.title = "The car's liveliness token dropped: its process ended or its link to this " +
      "monitor went. The position shown is the last one received.";
  } else {
    html("div", c.health.ok === false ? "health bad" : "health", `health: ${c.health.summary}`, li);
  }
  if (c.health.dropped) {
    const d = html("div", "dropped", c.health.dropped_text || `${c.health.dropped} dropped`, li);
    d.title = "Telemetry messages the car made but did not send (counted by the car itself, " +
      "in its health message). A state replaced by a newer one before it was sent costs " +
      "nothing: only the newest position matters. Gaps in what this monitor received are " +
      "counted separately (seq gaps).";
  }
  if (c.bad_messages) html("div", "health bad", c.bad, li);  // malformed messages, left out
  if (c.prompt) html("div", "prompt", `“${c.prompt}”`, li);
}

function zoomPan() {
  const svg = document.getElementById("map");
  let drag = null;
  const current = () => {
    const w = svg.clientWidth || 800, h = svg.clientHeight || 600;
    return { w, h, p: projector(bounds(state.last ? state.last.cars : []), w, h) };
  };
  svg.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const { w, h, p } = current();
    const r = svg.getBoundingClientRect();
    const mx = p.ix(ev.clientX - r.left), my = p.iy(ev.clientY - r.top);
    const k = p.k * Math.pow(1.2, -Math.sign(ev.deltaY));
    // keep the point under the cursor where it is
    state.view = { k, cx: mx - (ev.clientX - r.left - w / 2) / k, cy: my + (ev.clientY - r.top - h / 2) / k };
    if (state.last) render(state.last);
  }, { passive: false });
  svg.addEventListener("mousedown", (ev) => { drag = { x: ev.clientX, y: ev.clientY, p: current().p }; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (ev) => {
    if (!drag) return;
    const { k, cx, cy } = drag.p;
    state.view = { k, cx: cx - (ev.clientX - drag.x) / k, cy: cy + (ev.clientY - drag.y) / k };
    if (state.last) render(state.last);
  });
  svg.addEventListener("dblclick", () => { state.view = null; if (state.last) render(state.last); });
}

function render(fleet) {
  state.last = fleet;
  const cars = fleet.cars;
  if (!state.ref) {
    const withOrigin = cars.find((c) => c.state && pair(c.state.origin, "lat_deg", "lon_deg"));
    if (withOrigin) {
      const [lat, lon] = pair(withOrigin.state.origin, "lat_deg", "lon_deg");
      state.ref = { lat_deg: lat, lon_deg: lon };
    }
  }
  const svg = document.getElementById("map");
  const w = svg.clientWidth || 800, h = svg.clientHeight || 600;
  svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
  const p = projector(bounds(cars), w, h);
  drawTiles(p, w, h);
  drawGrid(p, w, h);
  const g = document.getElementById("cars");
  g.replaceChildren();
  const failed = new Set();
  const each = (list, draw) => {  // one car's failure is that car's alone
    for (const c of list) {
      try { draw(c); } catch (err) { failed.add(String(c && c.vehicle_id)); }
    }
  };
  each(cars.filter((c) => !c.alive), (c) => drawCar(c, p, g));  // live cars on top
  each(cars.filter((c) => c.alive), (c) => drawCar(c, p, g));
  const ul = document.getElementById("cards");
  ul.replaceChildren();
  each(cars, (c) => drawCard(c, ul));
  document.getElementById("empty").hidden = cars.length > 0;
  const live = cars.filter((c) => c.alive).length;
  const st = document.getElementById("status");
  st.className = "";
  const bad = fleet.bad_messages ? ` · ${fleet.bad_messages} bad messages left out` : "";
  const undrawn = failed.size ? ` · not drawn: ${[...failed].sort().join(", ")}` : "";
  st.dataset.undrawn = [...failed].sort().join(",");
  st.textContent = `${live} live, ${cars.length - live} gone · ${fleet.messages} messages${bad}${undrawn} · ${new Date().toLocaleTimeString()}`;
}

async function poll() {
  try {
    const since = state.generation === null ? ""
      : `?since=${state.generation}&epoch=${encodeURIComponent(state.epoch)}`;
    const r = await fetch(`/api/fleet${since}`, { cache: "no-store" });
    if (!r.ok) throw new Error(`HTTP ${r.status}`);
    const fleet = await r.json();
    mergeTracks(fleet);
    render(fleet);
    state.failures = 0;
  } catch (err) {
    state.failures += 1;
    const st = document.getElementById("status");
    st.className = "error";
    st.textContent = `monitor unreachable (${err.message}); retrying`;
  }
  setTimeout(poll, state.config.poll_ms);
}

async function start() {
  try {
    const r = await fetch("/api/config", { cache: "no-store" });
    if (r.ok) state.config = await r.json();
  } catch (err) { /* defaults */ }
  zoomPan();
  poll();
}

start();
