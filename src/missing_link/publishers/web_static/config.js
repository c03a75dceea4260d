// The missing-link device console: a board's run-time configuration (docs/configuration.md),
// the same keys and rules as `missing-link config` and the ROS 2 parameters: the daemon checks
// every value (the page does not second-guess it) and sets them all or none.
"use strict";

function showConfig(board, view) {
  S.config.set(board, view);
  const { parts } = ensureBoard(board);
  const id = boardId(board);
  let form = parts.config.querySelector("form");
  if (!form) form = buildConfig(parts.config, board, id);
  const tbody = form.querySelector("tbody");
  const rows = new Map([...tbody.rows].map((r) => [r.dataset.key, r]));
  const now = new Set(view.keys.map((k) => k.key));
  for (const [key, row] of rows) if (!now.has(key)) row.remove();  // (another board file since)
  for (const k of view.keys) {
    let row = rows.get(k.key);
    if (!row) { row = configRow(id, k); tbody.append(row); }
    row.cells[4].textContent = fmt(k.value);
    row.cells[5].textContent = k.saved === "?" ? "differs (not readable)" : (k.saved === null ? "none (defaults)" : fmt(k.saved));
    const input = row.querySelector("input, select");
    if (!input.dataset.edited && document.activeElement !== input) setInput(input, k);
  }
  const state = view.state.length ? view.state.join(", ") : "defaults";
  form.querySelector(".config-state").textContent = "Configuration on the board: " + state;
}

function buildConfig(box, board, id) {
  const msg = el("p", { class: "message", role: "status", "aria-live": "polite" });
  const state = el("p", { class: "muted config-state" });
  const head = el("tr", {}, ...["Key", "Type", "Unit", "Range", "Current", "Saved", "New value"]
    .map((h) => el("th", { scope: "col", text: h })));
  const form = el("form", { novalidate: "", "aria-label": `${board} configuration` },
    el("table", { class: "config" }, el("thead", {}, head), el("tbody")), state,
    el("div", { class: "buttons" },
      el("button", { type: "submit", text: "Apply" }),
      el("button", { type: "button", text: "Save", onclick: () => send(board, form, msg, "save") }),
      el("button", { type: "button", text: "Reset", onclick: () => send(board, form, msg, "reset") }),
      el("input", { type: "checkbox", id: `${id}-erase`, class: "erase" }),
      el("label", { for: `${id}-erase`, text: "Reset also forgets the saved configuration" })),
    msg);
  form.addEventListener("submit", (ev) => { ev.preventDefault(); send(board, form, msg, "apply"); });
  box.append(el("h3", { text: "Configuration" }), form);
  return form;
}

function configRow(id, k) {
  const inputId = `${id}-cfg-${k.key}`;
  let input;
  if (k.kind === "bool") input = el("input", { type: "checkbox" });
  else if (k.kind === "enum") input = el("select", {}, ...k.choices.map((c) => el("option", { value: c, text: c })));
  else {
    input = el("input", { type: "number", step: k.kind === "int" ? "1" : "any", inputmode: "decimal" });
    if (k.lo !== null) input.min = String(k.lo);
    if (k.hi !== null) input.max = String(k.hi);
  }
  input.id = inputId;
  input.dataset.kind = k.kind;
  if (k.read_only) input.disabled = true;
  input.addEventListener("input", () => { input.dataset.edited = "1"; });
  const range = k.kind === "int" || k.kind === "float" ? `${fmt(k.lo)} … ${fmt(k.hi)}` : k.allowed;
  const row = el("tr", {},
    el("th", { scope: "row" }, el("label", { for: inputId, text: k.key })),
    el("td", { text: k.kind + (k.read_only ? " (read-only)" : "") }), el("td", { text: k.unit || "–" }),
    el("td", { class: "num", text: range }), el("td", { class: "num" }), el("td", { class: "num" }),
    el("td", {}, input));
  row.dataset.key = k.key;
  return row;
}

function setInput(input, k) {
  if (k.kind === "bool") input.checked = Boolean(k.value);
  else input.value = k.value === null || k.value === undefined ? "" : String(k.value);
}

// The keys whose field differs from what runs (text as typed: the daemon parses it, as the CLI).
function changed(board, form) {
  const view = S.config.get(board);
  const out = {};
  for (const k of view.keys) {
    if (k.read_only) continue;
    const input = form.querySelector(`[id="${CSS.escape(boardId(board) + "-cfg-" + k.key)}"]`);
    if (!input) continue;
    const v = k.kind === "bool" ? input.checked : input.value.trim();
    if (k.kind === "bool" ? v !== Boolean(k.value) : v !== String(k.value)) out[k.key] = v;
  }
  return out;
}

async function send(board, form, msg, what) {
  const set = changed(board, form);
  let r;
  if (what === "reset") r = await ask("reset", { board, erase: form.querySelector(".erase").checked });
  else if (what === "apply" && Object.keys(set).length === 0) r = { ok: true, text: "nothing changed" };
  else r = await ask("config", { board, set, save: what === "save" });
  const words = { apply: "applied", save: "saved on the board", reset: "the defaults again" };
  if (r.ok && r.values) {
    for (const input of form.querySelectorAll("input, select")) delete input.dataset.edited;
    const view = S.config.get(board);
    for (const k of view.keys) if (k.key in r.values) k.value = r.values[k.key];
    showConfig(board, view);
    for (const k of view.keys) {
      const input = form.querySelector(`[id="${CSS.escape(boardId(board) + "-cfg-" + k.key)}"]`);
      if (input) setInput(input, k);
    }
  }
  msg.textContent = r.ok ? (r.text || words[what] + (Object.keys(set).length ? ": " +
    Object.entries(set).map(([k, v]) => `${k} = ${v}`).join(", ") : "")) : r.text;
  msg.className = "message" + (r.ok ? "" : " error");
}

$("login-form").addEventListener("submit", login);
window.addEventListener("resize", resizePlots);
start();
