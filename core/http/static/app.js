// fieldgate live page: plain JavaScript, no build step, no CDN. Reads the read-only API.
"use strict";

const QUALITIES = ["good", "not-read", "stale", "comm-fault", "over-range", "under-range", "watchdog", "config-error"];
const STATUS_PERIOD_MS = 2000;
const TREND_WINDOW_S = 300;  // at most: the server keeps 5 minutes
const TREND_MIN_SPAN_S = 10;

const state = {
  points: new Map(),   // id -> point (full or compact fields)
  tiles: new Map(),    // id -> tile element
  trends: new Map(),   // id -> {samples: [[t, v]], unit, canvas, value}
  seenEvents: new Set(),
  status: null,
};

const $ = (sel) => document.querySelector(sel);

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (key === "class") node.className = value;
    else if (key === "text") node.textContent = value;
    else node.setAttribute(key, value);
  }
  for (const child of children) node.append(child);
  return node;
}

async function getJSON(path) {
  const response = await fetch(path, { cache: "no-store", credentials: "same-origin" });
  if (!response.ok) throw new Error(`${path}: ${response.status}`);
  return response.json();
}

function fmtValue(p) {
  if (typeof p.value === "boolean") return p.value ? "1" : "0";
  if (p.eng !== undefined) return `${round(p.eng)}`;
  if (p.engineering) return `${round(p.engineering.value)}`;
  return `${p.value}`;
}

function round(x) {
  if (typeof x !== "number") return x;
  const a = Math.abs(x);
  return a >= 100 ? x.toFixed(0) : a >= 1 ? x.toFixed(2) : a >= 0.001 ? x.toFixed(3) : "0";
}

function fmtAge(seconds) {
  if (seconds === null || seconds === undefined) return "never";
  if (seconds < 1) return `${Math.round(seconds * 1000)} ms`;
  if (seconds < 120) return `${seconds.toFixed(1)} s`;
  return `${Math.round(seconds / 60)} min`;
}

function fmtUptime(s) {
  const d = Math.floor(s / 86400), h = Math.floor((s % 86400) / 3600), m = Math.floor((s % 3600) / 60);
  return d ? `up ${d} d ${h} h` : h ? `up ${h} h ${m} min` : `up ${m} min ${Math.floor(s % 60)} s`;
}

// -- header, fronts, modules ---------------------------------------------------------
function renderStatus(st) {
  state.status = st;
  $("#gw-name").textContent = st.gateway;
  $("#gw-desc").textContent = st.description || "";
  document.title = `${st.gateway} · fieldgate`;
  const ready = $("#ready");
  ready.textContent = st.ready ? "ready" : "not ready";
  ready.className = "badge " + (st.ready ? "ok" : "bad");
  ready.title = st.ready ? "every front and back is running" : st.not_ready.join("\n");
  $("#uptime").textContent = `${fmtUptime(st.uptime_s)} · v${st.version}`;
  renderFronts(st);
  renderModules(st);
  renderProcesses(st);
  for (const event of st.events || []) addEvent(event);
}

function frontFacts(name, f) {
  const facts = [];
  if (f.nmt_state) facts.push(["NMT", f.nmt_state]);
  if (f.node_id !== undefined) facts.push(["node-ID", f.node_id ?? "unconfigured"]);
  if (f.state && !f.nmt_state) facts.push(["state", f.state]);
  if (f.mac_id !== undefined) facts.push(["MAC ID", f.mac_id]);
  if (f.connections) {
    const open = Object.entries(f.connections).map(([n, c]) => `${n} ${c.state}`).join(", ");
    facts.push(["connections", open || "none"]);
  }
  if (f.endpoint) facts.push(["endpoint", f.endpoint]);
  // a server front (OPC UA, Modbus TCP) lists its clients and counters; it has no master
  if (Array.isArray(f.clients)) {
    const who = f.clients.map((c) => (c.user ? `${c.peer} (${c.user})` : c.peer));
    facts.push(["clients", who.length ? `${who.length}: ${who.join(", ")}` : "none"]);
  } else {
    facts.push(["master", f.master_ok ? "present" : "lost" + (f.master && f.master.reason ? `: ${f.master.reason}` : "")]);
  }
  if (Array.isArray(f.clients) && f.counters) {
    const shown = Object.entries(f.counters).map(([k, v]) => `${k.replace(/_/g, " ")} ${v}`);
    if (shown.length) facts.push(["counters", shown.join(" · ")]);
  }
  if (f.bus) {
    const state = f.bus.controller || (f.bus.bus_off ? "bus-off" : "error-active");
    const lost = Object.entries(f.bus.overruns || {}).filter(([, n]) => n > 0).map(([k, n]) => `${k} overrun ${n}`);
    facts.push(["CAN", [state === "error-active" ? "ok" : state.toUpperCase(), `rx ${f.bus.rx}`, `tx ${f.bus.tx}`, ...lost].join(" · ")]);
  }
  const services = f.services || {};
  if (services.emcy) facts.push(["EMCY", services.emcy.active.length ? `active ${services.emcy.active.join(", ")}` : "none active"]);
  if (services.io) facts.push(["PDO", `TPDOs sent ${services.io.tpdo_sent} · RPDOs ${services.io.rpdo_received}`]);
  if (f.restarts) facts.push(["restarts", f.restarts]);
  return facts;
}

function renderFronts(st) {
  const box = $("#fronts");
  box.replaceChildren();
  for (const [name, f] of Object.entries(st.fronts)) {
    const dl = el("dl");
    for (const [k, v] of frontFacts(name, f)) dl.append(el("dt", { text: k }), el("dd", { text: String(v) }));
    const down = st.down && st.down[name];
    box.append(el("div", { class: "front" + (f.master_ok && !down ? "" : " lost"), "data-front": name },
      el("h3", { text: name + (down ? " (down)" : "") }), dl));
  }
  if (!box.children.length) box.append(el("p", { class: "empty", text: "no fronts" }));
}

function renderModules(st) {
  const body = $("#modules tbody");
  body.replaceChildren();
  for (const m of st.modules) {
    const key = `${m.back}/m${m.address}`;
    const down = st.down && st.down[m.back];
    const health = down ? "down" : m.online ? "online" : "offline";
    const errors = Object.values(m.errors).reduce((a, b) => a + b, 0);
    const byKind = Object.entries(m.errors).map(([k, n]) => `${k} ${n}`).join(", ");
    body.append(el("tr", { "data-module": key, "data-health": health },
      el("td", { text: key }),
      el("td", { text: m.model || "-" }),
      el("td", {}, el("span", { class: `pill ${health}`, text: health })),
      el("td", { class: "num", text: String(m.requests) }),
      el("td", { class: "num", text: String(errors), title: byKind || "no errors" }),
      el("td", { class: "err", text: m.last_error || "", title: m.last_error || "" }),
      el("td", { class: "num", text: m.last_rtt_ms === null ? "-" : `${m.last_rtt_ms.toFixed(1)} ms` })));
    const box = document.querySelector(`.module[data-module="${key}"]`);
    if (box) box.classList.toggle("offline", health !== "online");
  }
  if (!st.modules.length) body.append(el("tr", {}, el("td", { class: "empty", colspan: "7", text: "no modules" })));
  renderLineNotes(st);
}

// the fieldbus process and the children beside it (docs/architecture.md, "Process layout")
function renderProcesses(st) {
  const body = $("#processes tbody");
  body.replaceChildren();
  const rows = [];
  if (st.process) rows.push(["fieldbus", { ...st.process, state: "running" }]);
  for (const [name, c] of Object.entries(st.children || {})) rows.push([name, c]);
  for (const [name, c] of rows) {
    const limit = c.memory_limit_mb ? ` of ${c.memory_limit_mb}` : "";
    const kills = Object.entries(c.kills || {}).map(([k, n]) => `${k} ${n}`).join(", ");
    body.append(el("tr", { "data-process": name, "data-state": c.state },
      el("td", { text: name }),
      el("td", { class: "num", text: c.pid ? String(c.pid) : "-" }),
      el("td", {}, el("span", { class: `pill ${c.state === "running" ? "online" : "offline"}`, text: c.state })),
      el("td", { class: "num", text: `${Math.round(c.rss_mb)}${limit} MB` }),
      el("td", { class: "num", text: `${c.cpu_s.toFixed(1)} s` }),
      el("td", { class: "num", text: c.resyncs === undefined ? "-" : String(c.resyncs) }),
      el("td", { text: kills || "-" })));
  }
}

// what a back found on its line: a start scan (modules: auto), modules it does not list
function renderLineNotes(st) {
  const notes = $("#line-notes");
  notes.replaceChildren();
  for (const [name, b] of Object.entries(st.backs || {})) {
    const scan = b.start_scan;
    if (scan && scan.error) {  // modules: auto without its line (docs/dcon.md)
      const from = scan.modules.length ? `: ${scan.modules.join(", ")}` : "";
      notes.append(el("li", { class: "warn", "data-back": name, text: `${name}: start scan failed: ${scan.error}; modules from ${scan.modules_from}${from} (scanned again ${scan.rescans} time(s))` }));
      if (scan.restart_needed) notes.append(el("li", { class: "warn", text: `${name}: modules answer now (${scan.found_later.join(", ")}): restart the gateway to serve them` }));
    } else if (scan) {
      const cs = scan.checksum ? "on" : "off";
      notes.append(el("li", { "data-back": name, text: `${name}: found at start (${scan.baudrate} bit/s, checksum ${cs}): ${scan.modules.join(", ")}` }));
      for (const line of scan.left_out) notes.append(el("li", { class: "warn", text: `${name}: ${line}` }));
      if (scan.changed_since_last_start.length) notes.append(el("li", { class: "warn", text: `${name}: changed since the last start: ${scan.changed_since_last_start.join("; ")}` }));
      if (scan.differs_from_scan_file.length) notes.append(el("li", { class: "warn", text: `${name}: differs from its scan file: ${scan.differs_from_scan_file.join("; ")}` }));
    }
    if (b.survey && b.survey.length) notes.append(el("li", { class: "warn", text: `${name}: answer but not in the topology: ${b.survey.join(", ")}` }));
  }
}

// -- process image -------------------------------------------------------------------
function renderLegend() {
  const box = $("#legend");
  for (const q of QUALITIES.filter((q) => q !== "under-range")) {
    box.append(el("span", {}, el("i", { class: `q-${q}` }), q === "over-range" ? "over/under-range" : q));
  }
}

function renderImage(points) {
  const groups = new Map();
  for (const p of points) {
    state.points.set(p.id, p);
    const key = `${p.source.back}/m${p.source.module}`;
    if (!groups.has(key)) groups.set(key, { model: p.source.model, points: [] });
    groups.get(key).points.push(p);
  }
  const box = $("#image");
  box.replaceChildren();
  for (const [key, group] of groups) {
    const tiles = el("div", { class: "tiles" });
    for (const p of group.points) {
      const tile = el("div", { class: "tile", "data-point": p.id, tabindex: "0" }, el("small"), el("b"));
      tile.addEventListener("mouseenter", () => showTip(tile, p.id));
      tile.addEventListener("focus", () => showTip(tile, p.id));
      tile.addEventListener("mouseleave", hideTip);
      tile.addEventListener("blur", hideTip);
      state.tiles.set(p.id, tile);
      paintTile(p.id);
      tiles.append(tile);
    }
    box.append(el("div", { class: "module", "data-module": key },
      el("header", {}, el("b", { text: key }), el("span", { text: group.model || "" })), tiles));
  }
}

function paintTile(id) {
  const p = state.points.get(id);
  const tile = state.tiles.get(id);
  if (!p || !tile) return;
  const local = id.split("/").pop();
  tile.className = `tile q-${p.quality}` + (typeof p.value === "boolean" ? " digital" + (p.value ? " on" : "") : "");
  tile.dataset.quality = p.quality;
  tile.dataset.value = String(p.value);
  tile.querySelector("small").textContent = local;
  tile.querySelector("b").textContent = typeof p.value === "boolean" ? (p.value ? "on" : "off") : fmtValue(p);
}

function applyPoints(batch) {
  for (const c of batch) {
    const p = state.points.get(c.id);
    if (!p) continue;
    const changed = p.value !== c.value;
    p.value = c.value;
    p.quality = c.quality;
    if (c.eng !== undefined) p.eng = c.eng;
    paintTile(c.id);
    if (changed) flash(c.id);
    const trend = state.trends.get(c.id);
    if (trend) {
      trend.samples.push([Date.now() / 1000, c.quality === "good" || c.quality === "stale" ? (c.eng ?? c.value) : null]);
      drawTrend(c.id);
    }
  }
}

function flash(id) {
  const tile = state.tiles.get(id);
  if (!tile) return;
  tile.classList.add("flash");
  setTimeout(() => tile.classList.remove("flash"), 400);
}

// -- tooltip ---------------------------------------------------------------------------
let tipFor = null;

async function showTip(tile, id) {
  tipFor = id;
  drawTip(tile, state.points.get(id));
  try {
    const full = await getJSON(`/api/v1/points/${id.split("/").map(encodeURIComponent).join("/")}`);
    if (tipFor !== id) return;
    Object.assign(state.points.get(id), full);
    drawTip(tile, full);
  } catch (err) {
    // the compact data stays on screen
  }
}

function drawTip(tile, p) {
  const tip = $("#tip");
  const dl = el("dl");
  const add = (k, v) => { if (v !== undefined && v !== null && v !== "") dl.append(el("dt", { text: k }), el("dd", { text: String(v) })); };
  add("value", typeof p.value === "boolean" ? (p.value ? "1 (on)" : "0 (off)") : p.value);
  if (p.engineering) add("engineering", `${round(p.engineering.value)} ${p.engineering.unit}`);
  add("quality", p.quality);
  add("cause", p.cause);
  add("age", p.age_s !== undefined ? fmtAge(p.age_s) : undefined);
  if (p.last_good !== undefined && p.quality !== "good") add("last good", p.last_good);
  if (p.source) {
    add("source", `${p.source.back}, module ${p.source.module}${p.source.model ? " (" + p.source.model + ")" : ""}, channel ${p.source.index}`);
    if (p.source.at) add("on the wire", p.source.at.join("; "));
  }
  for (const s of p.served_by || []) add(`served by ${s.component}`, s.at);
  add("written by", p.written_by);
  tip.replaceChildren(el("h4", { text: p.id }), dl);
  tip.hidden = false;
  const r = tile.getBoundingClientRect();
  const x = Math.min(r.left, window.innerWidth - tip.offsetWidth - 8);
  const below = r.bottom + 8 + tip.offsetHeight < window.innerHeight;
  tip.style.left = `${Math.max(8, x)}px`;
  tip.style.top = `${below ? r.bottom + 8 : r.top - tip.offsetHeight - 8}px`;
}

function hideTip() {
  tipFor = null;
  $("#tip").hidden = true;
}

// -- trends ----------------------------------------------------------------------------
function renderTrends(data) {
  const box = $("#trends");
  const ids = Object.keys(data.series);
  if (!ids.length) return;
  box.replaceChildren();
  for (const id of ids) {
    const s = data.series[id];
    const canvas = el("canvas", { width: "480", height: "140" });
    const value = el("b", { text: "-" });
    const span = el("span", { class: "span" });
    box.append(el("div", { class: "trend", "data-point": id },
      el("div", { class: "head" }, el("span", { text: id + (s.unit ? ` [${s.unit}]` : "") }), value), canvas,
      el("div", { class: "foot" }, span, el("span", { text: "now" }))));
    state.trends.set(id, { samples: s.samples.slice(), unit: s.unit, canvas, value, span });
    drawTrend(id);
  }
}

function drawTrend(id) {
  const t = state.trends.get(id);
  const now = Date.now() / 1000;
  t.samples = t.samples.filter((s) => s[0] >= now - TREND_WINDOW_S);
  const vals = t.samples.map((s) => s[1]).filter((v) => v !== null);
  const last = t.samples.length ? t.samples[t.samples.length - 1][1] : null;
  const p = state.points.get(id);
  const bad = p && p.quality !== "good";
  t.value.textContent = last === null ? (bad ? p.quality : "-") : `${round(last)}${t.unit ? " " + t.unit : ""}`;
  t.value.className = bad ? "bad" : "";
  // the time axis spans the data there is (a fresh page fills the plot), up to 5 minutes
  const span = Math.min(TREND_WINDOW_S, Math.max(TREND_MIN_SPAN_S, t.samples.length ? now - t.samples[0][0] : 0));
  t.span.textContent = span >= 120 ? `last ${Math.round(span / 60)} min` : `last ${Math.round(span)} s`;
  const c = t.canvas, g = c.getContext("2d");
  const W = c.width, H = c.height, pad = 10;
  g.clearRect(0, 0, W, H);
  g.strokeStyle = "#e2e7ee";
  g.lineWidth = 1;
  for (let i = 0; i <= 4; i++) {
    const y = pad + ((H - 2 * pad) * i) / 4;
    g.beginPath(); g.moveTo(0, y); g.lineTo(W, y); g.stroke();
  }
  if (!vals.length) return;
  let lo = Math.min(...vals), hi = Math.max(...vals);
  if (hi - lo < 1e-9) { lo -= 1; hi += 1; }
  const x = (ts) => W - ((now - ts) / span) * W;
  const y = (v) => H - pad - ((v - lo) / (hi - lo)) * (H - 2 * pad);
  g.strokeStyle = "#1f6feb";
  g.lineWidth = 2.5;
  g.lineJoin = "round";
  g.beginPath();
  let pen = false;
  for (const [ts, v] of t.samples) {
    if (v === null) { pen = false; continue; }
    if (pen) g.lineTo(x(ts), y(v)); else g.moveTo(x(ts), y(v));
    pen = true;
  }
  g.stroke();
  g.fillStyle = "#6b7687";
  g.font = "20px system-ui, sans-serif";
  g.fillText(`${round(hi)}`, 4, pad + 16);
  g.fillText(`${round(lo)}`, 4, H - pad - 4);
}

// -- events ----------------------------------------------------------------------------
function addEvent(e) {
  if (state.seenEvents.has(e.seq)) return;
  state.seenEvents.add(e.seq);
  const list = $("#events");
  const empty = list.querySelector(".empty");
  if (empty) empty.remove();
  const when = new Date(e.time * 1000).toLocaleTimeString([], { hour12: false });
  const item = el("li", { class: e.level, "data-kind": e.kind },
    el("time", { text: when }), el("span", { class: "kind", text: e.kind }), el("span", { text: e.text }));
  // newest first, by sequence number
  let before = null;
  for (const child of list.children) {
    if (Number(child.dataset.seq) < e.seq) { before = child; break; }
  }
  item.dataset.seq = String(e.seq);
  list.insertBefore(item, before);
  while (list.children.length > 200) list.lastChild.remove();
}

// -- live updates ----------------------------------------------------------------------
function connect() {
  const live = $("#live");
  const source = new EventSource("/api/v1/events");
  source.addEventListener("open", () => { live.textContent = "live"; live.className = "badge ok"; });
  source.addEventListener("error", () => { live.textContent = "reconnecting"; live.className = "badge off"; });
  source.addEventListener("points", (msg) => applyPoints(JSON.parse(msg.data).points));
  source.addEventListener("event", (msg) => {
    addEvent(JSON.parse(msg.data));
    refreshStatus();
  });
}

async function refreshStatus() {
  try {
    renderStatus(await getJSON("/api/v1/status"));
  } catch (err) {
    $("#ready").textContent = "unreachable";
    $("#ready").className = "badge bad";
  }
}

async function main() {
  renderLegend();
  const [status, points, trends] = await Promise.all([
    getJSON("/api/v1/status"), getJSON("/api/v1/points"), getJSON("/api/v1/trends"),
  ]);
  renderImage(points.points);
  renderTrends(trends);
  renderStatus(status);
  connect();
  setInterval(refreshStatus, STATUS_PERIOD_MS);
  setInterval(() => { for (const id of state.trends.keys()) drawTrend(id); }, 1000);
}

main().catch((err) => {
  $("#ready").textContent = "cannot load";
  $("#ready").className = "badge bad";
  $("#ready").title = String(err);
});
