// The device console's transducers (docs/web.md): every channel named, its value in SI and in the
// unit the part is sold in, one plot per quantity (uPlot: commands drawn as steps, the time axis
// in seconds before now), and an actuator's control in SI with its range: a slider and a number.
// What each channel is comes from the daemon (publishers/web_channels.py: "layout", "control").
"use strict";

function sig(v) {  // a value as a person reads it: four significant digits, no exponent noise
  if (v === null || v === undefined) return "N/A";
  if (typeof v !== "number") return fmt(v);
  return Number.isInteger(v) ? String(v) : String(Number(v.toPrecision(4)));
}
function withUnit(v, unit) { return sig(v) + (unit ? " " + unit : ""); }
function inPart(ch, v) {  // the same value in the part's unit ("" where it has none)
  if (!ch.part_unit || v === null || v === undefined) return "";
  const p = v * ch.part_scale;
  return withUnit(ch.part_unit === "counts" ? Math.round(p) : p, ch.part_unit);
}
function layoutOf(meta) {
  return meta.layout && meta.layout.length === meta.channels ? meta.layout :
    Array.from({ length: meta.channels }, (_, c) => ({ name: meta.channels === 1 ? meta.name : `ch${c}`,
      unit: meta.unit || "", scale: 1, offset: 0, part_unit: "", part_scale: 1, plot: meta.unit || "value" }));
}

function addTopic(meta, history) {
  let t = S.topics.get(meta.topic);
  if (t) { t.meta = meta; showActuator(t); return; }
  const b = ensureBoard(meta.board);
  const id = boardId(meta.board) + "-" + meta.name;
  const layout = layoutOf(meta);
  const values = el("dl", { class: "channels" + (layout.length > 7 ? " many" : "") });
  const cells = layout.map((ch) => {  // (a name and its value, grouped: columns when many)
    const dd = el("dd", { class: "value", text: "no value yet" });
    values.append(el("div", {}, el("dt", { text: ch.name }), dd));
    return dd;
  });
  const rate = el("p", { class: "muted" });
  const plots = el("div", { class: "plots" });
  const art = el("article", { class: "transducer", "aria-labelledby": id },
    el("h4", { id, text: meta.name }, el("span", { class: "muted", text: " · " + meta.model })),
    values, rate, plots);
  b.parts.transducers.append(art);
  const groups = new Map();  // plot -> channel indices, in the order they come
  layout.forEach((ch, c) => { if (!groups.has(ch.plot)) groups.set(ch.plot, []); groups.get(ch.plot).push(c); });
  t = { meta, layout, cells, rate, xs: [], ys: layout.map(() => []), act: null,
        plots: [...groups].map(([name, idx]) => plotBox(plots, meta, layout, name, idx)) };
  S.topics.set(meta.topic, t);
  addPoints(meta.topic, history);
  showActuator(t);
}

function plotBox(into, meta, layout, name, idx) {
  const unit = layout[idx[0]].unit;
  const title = `${name}${unit ? " (" + unit + ")" : ""}`;
  const box = el("div", { class: "plot", role: "img", "aria-label": `${meta.name} ${title}: the last ${WINDOW_S} s` });
  into.append(el("figure", {}, el("figcaption", { text: title }), box));
  return { box, idx, plot: null };
}

function addPoints(name, points) {
  const t = S.topics.get(name);
  if (!t || points.length === 0) return;
  for (const p of points) {
    t.xs.push(p[0]);
    for (let c = 0; c < t.ys.length; c++) t.ys[c].push(p[1 + c] ?? null);
  }
  const last = points[points.length - 1];
  t.layout.forEach((ch, c) => {
    const v = last[1 + c] ?? null;
    const part = inPart(ch, v);
    const text = v === null ? "N/A" : withUnit(v, ch.unit) + (part ? " · " + part : "");
    if (t.cells[c].textContent !== text) t.cells[c].textContent = text;
  });
}

function showRates(rates, now) {
  for (const [name, t] of S.topics) {
    const r = rates[name];
    if (r) t.rate.textContent = `${r.rate === null ? "–" : fmt(r.rate)} updates/s · ${r.count} updates` +
      (r.dropped ? ` · ${r.dropped} not shown (too fast)` : "");
    let cut = 0;
    while (cut < t.xs.length && t.xs[cut] < now - WINDOW_S) cut++;
    if (cut) { t.xs.splice(0, cut); for (const y of t.ys) y.splice(0, cut); }
    for (const p of t.plots) draw(t, p, now);
  }
}

const AXIS_STEP_S = 5;  // a tick every 5 s, labelled by how long ago: "-25 s" ... "now"
function timeAxis() {
  return {
    splits: (u) => {
      const max = u.scales.x.max, out = [];
      for (let s = WINDOW_S; s >= 0; s -= AXIS_STEP_S) out.push(max - s);
      return out;
    },
    values: (u, splits) => splits.map((v) => {
      const ago = Math.round(v - u.scales.x.max);
      return ago === 0 ? "now" : `${ago} s`;
    }),
    space: 30,
  };
}

function plotWidth(p) { return Math.max(260, p.box.clientWidth || 380); }

function draw(t, p, now) {
  if (typeof uPlot === "undefined") return;
  if (!p.plot) {
    const step = t.meta.kind === "actuator";  // a command holds until the next: a step, not a slope
    const series = [{}].concat(p.idx.map((c, k) => ({
      label: t.layout[c].name, stroke: `hsl(${(k * 67 + 210) % 360} 70% 42%)`, width: 1.5,
      spanGaps: true,  // (N/A between values: a sonar group's turn is a gap, not a break)
      paths: step ? uPlot.paths.stepped({ align: 1 }) : undefined, points: { show: step }, stepped: step,
    })));
    p.plot = new uPlot({ width: plotWidth(p), height: 130, series,
      legend: { show: p.idx.length <= 8, live: false }, scales: { x: { time: false } },
      axes: [timeAxis(), { size: 56, space: 18, values: (u, vals) => vals.map(sig) }],
      cursor: { drag: { x: false, y: false } } }, [t.xs, ...p.idx.map((c) => t.ys[c])], p.box);
  }
  if (Math.abs(p.plot.width - plotWidth(p)) > 20) p.plot.setSize({ width: plotWidth(p), height: 130 });
  p.plot.setData([t.xs, ...p.idx.map((c) => t.ys[c])], false);
  p.plot.setScale("x", { min: now - WINDOW_S, max: now });
}

function resizePlots() {
  for (const t of S.topics.values()) for (const p of t.plots) if (p.plot) p.plot.setSize({ width: plotWidth(p), height: 130 });
}

// ---- actuators (only where this face takes commands) ------------------------------------------
function showActuator(t) {
  const c = t.meta.control;
  if (!S.commands || !c || t.act) return;
  const b = ensureBoard(t.meta.board);
  const id = boardId(t.meta.board) + "-cmd-" + t.meta.name;
  const unit = c.si ? c.unit : "raw " + t.meta.dtype;
  const bounded = c.lo !== null && c.hi !== null;
  const number = el("input", { id, type: "number", step: c.step ?? "any", required: "",
    "aria-describedby": id + "-d", ...(bounded ? { min: c.lo, max: c.hi } : {}) });
  const slider = bounded ? el("input", { type: "range", min: c.lo, max: c.hi, step: c.step ?? "any",
    "aria-label": `${t.meta.name} command (slider)`, tabindex: "-1" }) : null;
  const echo = el("span", { id: id + "-d", class: "muted" });
  const say = () => {
    const v = Number(number.value);
    const partRange = bounded && c.part_unit ? ` (${sig(c.lo * c.part_scale)}..${sig(c.hi * c.part_scale)} ${c.part_unit})` : "";
    const range = bounded ? `${sig(c.lo)}..${sig(c.hi)}${unit ? " " + unit : ""}${partRange}` : `any ${unit || "value"}`;
    const part = number.value === "" ? "" : c.si ? inPart(c, v) : withUnit(v * c.part_scale, c.part_unit);
    echo.textContent = range + (part ? " · " + part : "");
  };
  const msg = el("span", { class: "message", role: "status" });
  const form = el("form", { class: "actuator", novalidate: "" },
    el("label", { for: id, text: `${t.meta.name} command` }), slider, number,
    el("span", { class: "unit", text: unit }), echo, el("button", { type: "submit", text: "Send" }), msg);
  const send = async () => {
    if (number.value === "" || !Number.isFinite(Number(number.value))) {
      msg.textContent = "a number first"; msg.className = "message error"; return;
    }
    const r = await ask("command", { topic: c.topic, value: Number(number.value) });
    msg.textContent = r.ok ? "sent" : r.text;
    msg.className = "message" + (r.ok ? "" : " error");
  };
  number.addEventListener("input", () => { if (slider) slider.value = number.value; say(); });
  if (slider) {
    slider.addEventListener("input", () => { number.value = slider.value; say(); });
    slider.addEventListener("change", send);  // (let go of the slider: the actuator goes there)
  }
  form.addEventListener("submit", (ev) => { ev.preventDefault(); send(); });
  if (slider) slider.value = c.lo <= 0 && 0 <= c.hi ? 0 : c.lo;  // (nothing sent until asked)
  say();
  if (!b.parts.actuators.firstChild) b.parts.actuators.append(el("h3", { text: "Actuators" }));
  b.parts.actuators.append(form);
  t.act = form;
}
