// The missing-link device console (docs/web.md): one WebSocket from the daemon's web face
// (publishers/web_server.py), the page built from what it says. Plain JS, no framework; plots
// with uPlot (bundled, see scripts/build-web.sh). Text from boards is set as text, never as HTML.
"use strict";

const WINDOW_S = 30;
const S = {                 // what the page knows
  ws: null, nextId: 1, pending: new Map(), commands: false, attached: false,
  topics: new Map(),        // topic -> {meta, xs, ys: [[...]...], plot, el}
  boards: new Map(),        // board name -> {el, parts}
  config: new Map(),        // board name -> config view
  ids: new Map(),           // board name -> small number (element ids)
};

const $ = (id) => document.getElementById(id);
function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else if (k === "text") e.textContent = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const c of children) if (c !== null && c !== undefined) e.append(c);
  return e;
}
function fmt(v) {
  if (v === null || v === undefined) return "N/A";
  if (typeof v === "boolean") return v ? "true" : "false";
  if (typeof v === "number") {
    if (Number.isInteger(v)) return String(v);
    return String(Number(v.toPrecision(5)));
  }
  return String(v);
}
function boardId(name) {
  if (!S.ids.has(name)) S.ids.set(name, S.ids.size + 1);
  return "b" + S.ids.get(name);
}

// ---- connection -------------------------------------------------------------------------------
// A login's session secret is kept in sessionStorage, this origin's own (port included), and
// sent as the WebSocket's first message: no cookie, since cookies go to every port of a host
// (docs/security.md).
const SESSION = "ml_session";

async function start() {
  let session = { token: false };
  try {
    const r = await fetch("/session", { cache: "no-store" });
    if (r.ok) session = await r.json();
  } catch (e) { /* the daemon is gone: retried below */ }
  if (session.name) $("title").textContent = session.name;
  S.token = session.token;
  if (session.token && !sessionStorage.getItem(SESSION)) {
    $("login").hidden = false;
    $("link").textContent = "log in to see the boards";
    $("token").focus();
    return;
  }
  $("login").hidden = true;
  connect();
}

async function login(ev) {
  ev.preventDefault();
  const token = $("token").value;
  const r = await fetch("/login", { headers: { Authorization: "Bearer " + token }, cache: "no-store" });
  $("token").value = "";
  if (r.ok) {
    sessionStorage.setItem(SESSION, (await r.json()).session);
    $("login-message").textContent = "";
    start();
  }
  else $("login-message").textContent = r.status === 429 ? "Too many failed logins: wait a minute." : "Wrong token.";
}

function connect() {
  const proto = location.protocol === "https:" ? "wss://" : "ws://";
  const ws = new WebSocket(proto + location.host + "/ws");
  S.ws = ws;
  ws.onopen = () => {
    if (S.token) ws.send(JSON.stringify({ op: "auth", session: sessionStorage.getItem(SESSION) || "" }));
    $("link").textContent = "connected";
  };
  ws.onmessage = (ev) => handle(JSON.parse(ev.data));
  ws.onclose = (ev) => {
    if (ev.code === 4401) sessionStorage.removeItem(SESSION);  // (expired, or another daemon)
    $("link").textContent = "disconnected from the daemon: trying again…";
    for (const done of S.pending.values()) done({ ok: false, text: "disconnected" });
    S.pending.clear();
    setTimeout(start, 1000);
  };
}

function ask(op, fields) {
  return new Promise((resolve) => {
    if (!S.ws || S.ws.readyState !== WebSocket.OPEN) return resolve({ ok: false, text: "not connected" });
    const id = S.nextId++;
    S.pending.set(id, resolve);
    S.ws.send(JSON.stringify({ op, id, ...fields }));
  });
}

function handle(m) {
  if (m.op === "hello") {
    S.commands = m.commands; S.attached = m.attached;
    for (const meta of m.topics) addTopic(meta, m.history[meta.topic] || []);
    for (const [board, view] of Object.entries(m.config)) showConfig(board, view);
    showStatus(m.boards, m.publishers);
    $("link").textContent = "connected · commands " + (m.commands ? "on" : "off") +
      (m.attached ? "" : " · configuration read-only (not attached to a daemon)");
  } else if (m.op === "tick") {
    for (const meta of m.topics || []) addTopic(meta, []);
    for (const [board, view] of Object.entries(m.config || {})) showConfig(board, view);
    for (const [name, points] of Object.entries(m.data)) addPoints(name, points);
    showRates(m.rates, m.t);
    showStatus(m.boards, m.publishers);
  } else if (m.op === "reply") {
    const done = S.pending.get(m.id);
    S.pending.delete(m.id);
    if (done) done(m);
  }
}

// ---- boards -----------------------------------------------------------------------------------
function ensureBoard(name) {
  let b = S.boards.get(name);
  if (b) return b;
  const id = boardId(name);
  const parts = {
    state: el("p", { class: "state waiting", text: "…" }),
    facts: el("dl", { class: "facts" }),
    transducers: el("div", { class: "transducers" }),
    actuators: el("div", { class: "actuators" }),
    config: el("div", { class: "config" }),
    extra: el("div", { class: "extra" }), log: null, update: null,  // (the last two: showExtra)
    dd: new Map(),
  };
  const section = el("section", { class: "board", id, "aria-labelledby": id + "-h" },
    el("h2", { id: id + "-h", text: name }), parts.state, parts.facts,
    el("h3", { text: "Transducers" }), parts.transducers, parts.actuators, parts.config, parts.extra);
  const after = [...S.boards.keys()].filter((n) => n > name).sort()[0];  // (sorted by name)
  $("boards").insertBefore(section, after === undefined ? null : S.boards.get(after).el);
  b = { el: section, parts };
  S.boards.set(name, b);
  return b;
}

function us(v) { return v === null || v === undefined ? null : fmt(v) + " µs"; }

function facts(s) {
  const losses = [["lost_sifs", "lost SIFs"], ["bad_sifs", "bad SIFs"], ["unknown_sifs", "unknown SIFs"],
    ["bad_checksums", "bad checksums"], ["cut_frames", "cut frames"], ["timeouts", "call timeouts"],
    ["stale_links", "stale links"], ["sync_outliers", "clock outliers"], ["sync_lost", "clock probes lost"]]
    .filter(([k]) => k in s).map(([k, label]) => `${s[k]} ${label}`).join(" · ");
  const clock = s.offset_us === undefined ? (s.sync_state || "none") :
    `${s.sync_state}, offset ${fmt(s.offset_us)} µs, skew ${fmt(s.skew_ppm)} ppm`;
  const failsafe = "failsafe_trips" in s ? `${s.failsafe_trips} trips` +
    (s.failsafe_last_trip_ms === null ? "" : `, last ${fmt(s.failsafe_last_trip_ms)} ms ago`) : null;
  const identity = ["board_id", "serial"].filter((k) => s[k]).map((k) => `${k} ${s[k]}`).join(" · ");
  const firmware = ["fw_version", "fw_hash"].filter((k) => s[k]).map((k) => String(s[k])).join(" · ");
  return [
    ["Link", s.url], ["Error", s.state !== "up" ? s.error : null], ["RTT", us(s.rtt_us)],
    ["Clock", clock], ["Bound", s.bound_us === undefined ? null : "± " + us(s.bound_us)],
    ["Estimate", s.est_error_us === undefined ? null : "± " + us(s.est_error_us)],
    ["Losses", losses], ["Failsafe", failsafe], ["Identity", identity || null],
    ["Firmware", firmware || null], ["Samples", fmt(s.samples)], ["Connects", fmt(s.connects)],
    ["Warnings", s.warnings || null],
  ];
}

function showStatus(boards, publishers) {
  const seen = new Set();
  for (const s of boards) {
    seen.add(s.board);
    const { parts } = ensureBoard(s.board);
    const up = s.state === "up";
    const label = up ? "up" : (s.connects > 0 ? "lost" : "connecting");
    parts.state.className = "state " + (up ? "up" : (label === "lost" ? "lost" : "waiting"));
    parts.state.textContent = up ? "up" : `${label} (${s.state})`;
    for (const [k, v] of facts(s)) setFact(parts, k, v);
    showExtra(parts, s);
  }
  for (const [name, b] of S.boards) {
    const hasTopics = [...S.topics.values()].some((t) => t.meta.board === name);
    if (!seen.has(name) && !hasTopics) { b.el.remove(); S.boards.delete(name); }
  }
  showRecording(publishers);
}

function setFact(parts, label, value) {
  let dd = parts.dd.get(label);
  if (value === null || value === undefined || value === "") {
    if (dd) { dd.previousSibling.remove(); dd.remove(); parts.dd.delete(label); }
    return;
  }
  if (!dd) {
    dd = el("dd");
    parts.facts.append(el("dt", { text: label }), dd);
    parts.dd.set(label, dd);
  }
  if (dd.textContent !== String(value)) dd.textContent = String(value);
}

// A board's log and firmware update, where the daemon reports them (status keys `log`, `update`):
// built once, then changed in place (a rebuild each tick took the log's focus and scroll).
function showExtra(parts, s) {
  const lines = Array.isArray(s.log) ?
    s.log.map((l) => typeof l === "string" ? l : `${l.level || ""} ${l.text || ""}`).join("\n") : null;
  if (lines === null) { if (parts.log) parts.log.remove(); parts.log = null; } else {
    if (!parts.log) {
      parts.log = el("div", {}, el("h3", { text: "Log" }), el("pre", { class: "log", tabindex: "0" }));
      parts.extra.prepend(parts.log);
    }
    const pre = parts.log.lastChild;
    if (pre.textContent !== lines) pre.textContent = lines;
  }
  const u = s.update && typeof s.update === "object" ? s.update : null;
  if (!u) { if (parts.update) parts.update.remove(); parts.update = null; return; }
  if (!parts.update) {
    parts.update = el("div", {}, el("h3", { text: "Firmware update" }), el("p", { class: "update" }),
      el("progress", { "aria-label": "firmware update" }));
    parts.extra.append(parts.update);
  }
  const [, line, bar] = parts.update.children;
  const total = Number(u.total) || 0, done = Number(u.done) || 0;
  const hashes = u.from || u.to ? ` · ${u.from || "?"} → ${u.to || "?"}` : "";  // (fw.hash, old → new)
  const text = `${u.state || ""} ${done}/${total} bytes${hashes}`;
  if (line.textContent !== text) line.textContent = text;
  bar.max = total || 1;
  bar.value = done;
}

function showRecording(publishers) {
  $("recording").hidden = false;
  const rec = publishers.filter((p) => p.publisher === "mcap");
  $("recording-state").textContent = rec.length === 0 ? "not recording" : rec.map((p) => p.error
    ? `ERROR: ${p.error}`
    : `recording to ${p.path}: ${p.recorded ?? p.messages} messages written, ${p.dropped} dropped`).join("; ");
  $("recording-state").className = rec.some((p) => p.error) ? "message error" : "";
  $("publishers").replaceChildren(...publishers.map((p) =>
    el("li", { text: `${p.publisher}: ${p.message || "ok"}, ${p.dropped ?? 0} dropped` +
      ("commands_refused" in p ? `, ${p.commands_refused} commands refused` : "") })));
}

// The transducers, their plots and the actuators' controls: transducers.js.
