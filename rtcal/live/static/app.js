// rtcal live view: reads /api/events (server-sent events) and draws the run. No external asset.
// The control token lives in this page's memory only (typed in, or given as #token=... in the URL).
"use strict";

const MARKERS = new Set(["skipped", "rejected"]);
// Okabe & Ito's eight colours, told apart with every colour vision; beyond eight a dash pattern too
const COLORS = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#8C7A00"];
const DASHES = ["none", "2 3", "8 3 2 3", "1 2"];
const FINAL = new Set(["finished", "failed", "aborted"]);
const UNITS = { um: "µm", degC: "°C", arcsec: "″", deg: "°", pct: "%", percent: "%" };
function unitText(u) { return u in UNITS ? UNITS[u] : (u || ""); }
const S = {
  token: null,
  state: null,
  attempts: new Map(),   // "plan_index:attempt" -> {rows: [], marked: false}
  quantities: new Map(), // "instrument.quantity" -> unit
  events: [],
  seenEvents: new Set(),
  lastId: 0,
  lastData: 0,
  source: null,
  dirty: false,
};

const $ = (id) => document.getElementById(id);
const SVGNS = "http://www.w3.org/2000/svg";

function readFragment() {
  const m = location.hash.match(/(?:^#|&)token=([^&]+)/);
  if (m) {
    S.token = decodeURIComponent(m[1]);
    $("token").value = S.token;
    history.replaceState(null, "", location.pathname + location.search); // not left in the address bar
  }
}

// ---- the stream ------------------------------------------------------------------------------
function connect() {
  const url = "api/events" + (S.lastId ? "?after=" + S.lastId : "");
  const es = new EventSource(url);
  S.source = es;
  es.addEventListener("open", () => setConn("live"));
  es.addEventListener("error", () => {
    if (S.ended) return;
    if (es.readyState === EventSource.CLOSED) { // the browser gave up: start again from the last reading seen
      setConn("reconnecting…");
      setTimeout(connect, 2000);
    } else {
      setConn("reconnecting…");
    }
  });
  es.addEventListener("reading", (ev) => {
    const r = JSON.parse(ev.data);
    if (r.id <= S.lastId) return;
    S.lastId = r.id;
    addReading(r);
    touched();
  });
  es.addEventListener("log", (ev) => {
    const e = JSON.parse(ev.data);
    if (S.seenEvents.has(e.id)) return;
    S.seenEvents.add(e.id);
    S.events.push(e);
    touched();
  });
  es.addEventListener("state", (ev) => {
    S.state = JSON.parse(ev.data);
    if (FINAL.has(S.state.state) && (S.state.state !== "finished" || S.state.result)) { // nothing more will come
      es.close();
      S.ended = true;
      setConn("the run has ended: this page keeps its last state");
    }
    touched();
  });
}

function setConn(text) { $("conn").textContent = text; }

function touched() {
  S.lastData = Date.now();
  if (!S.dirty) {
    S.dirty = true;
    setTimeout(() => { S.dirty = false; render(); }, 150);
  }
}

function addReading(r) {
  if (r.plan_index === null || r.plan_index === undefined) return;
  const key = r.plan_index + ":" + r.attempt;
  let a = S.attempts.get(key);
  if (!a) { a = { rows: [], marked: false }; S.attempts.set(key, a); }
  if (MARKERS.has(r.quantity)) { a.marked = true; return; }
  a.rows.push(r);
  const q = r.instrument + "." + r.quantity;
  if (!S.quantities.has(q)) {
    S.quantities.set(q, r.unit);
    const opt = document.createElement("option");
    opt.value = q;
    opt.textContent = plotLabel(q, r.unit);
    $("plot-select").appendChild(opt);
    const preferred = ["autocollimator.x_arcsec", "encoder.angle_deg", "stage.feedback_deg"];
    const sel = $("plot-select");
    const current = preferred.indexOf(sel.value);
    const candidate = preferred.indexOf(q);
    if (sel.dataset.chosen !== "1" && candidate >= 0 && (current < 0 || candidate < current)) sel.value = q;
  }
}

function plotLabel(q, unit) {  // an angle (its unit, from the store) is plotted as its departure from the command
  return unit === "deg" ? q + " − command (″)" : q + " (" + unitText(unit) + ")";
}

// ---- formatting ------------------------------------------------------------------------------
function fmtDuration(s) {
  if (s === null || s === undefined) return "–";
  s = Math.round(s);
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
  return (h ? h + " h " : "") + (h || m ? m + " min " : "") + sec + " s";
}
function fmtNum(v, digits) {
  if (v === null || v === undefined || !isFinite(v)) return "–";
  const a = Math.abs(v);
  if (a !== 0 && (a >= 1e6 || a < 1e-3)) return v.toExponential(3);
  return v.toFixed(digits === undefined ? (a >= 100 ? 3 : 4) : digits);
}
function fmtCurrent(c) {
  if (!c || !Object.keys(c).length) return "–";
  const parts = [];
  if (c.target_deg !== undefined && c.target_deg !== null) parts.push("target " + (+c.target_deg).toFixed(3).replace(/\.?0+$/, "") + "°");
  if (c.run !== undefined) parts.push("run " + c.run);
  if (c.direction !== undefined) parts.push(c.direction === "+" ? "↑" : c.direction === "-" ? "↓" : c.direction);
  if (c.point !== undefined) parts.push("point " + c.point);
  if (c.station !== undefined && c.target_deg === undefined) parts.push("station " + c.station);
  if (c.mount !== undefined) parts.push("mount " + c.mount);
  if (c.seating !== undefined && c.seating > 1) parts.push("seating " + c.seating);
  return parts.join(" · ") || JSON.stringify(c);
}

// ---- rendering -------------------------------------------------------------------------------
function render() {
  const st = S.state;
  if (st) renderState(st);
  renderPlot();
  renderEvents();
  renderAbort();
}

function renderState(st) {
  const badge = $("state");
  badge.textContent = st.state;
  badge.className = "badge " + st.state;
  document.body.className = st.state;
  $("title").textContent = st.name || "rtcal live view";
  $("subtitle").textContent = st.method ? "method " + st.method : "";
  $("method").textContent = st.method || "–";
  $("done").textContent = st.done_readings;
  $("planned").textContent = st.planned_readings === null ? "?" : st.planned_readings;
  const pct = st.planned_readings ? Math.min(100, 100 * st.done_readings / st.planned_readings) : 0;
  $("bar-fill").style.width = pct.toFixed(1) + "%";
  $("bar").setAttribute("aria-valuenow", pct.toFixed(0));
  $("percent").textContent = st.planned_readings ? pct.toFixed(0) + " %" : "";
  renderEta(st);
  const marking = $("marking");
  marking.hidden = !st.marking;
  marking.textContent = st.marking || "";
  $("current").textContent = FINAL.has(st.state) ? "–" : fmtCurrent(st.current);
  $("faults").textContent = st.faults;
  $("faults").className = st.faults ? "has" : "";
  renderOperator(st);
  $("control-live").hidden = !st.control;
  $("control-readonly").hidden = !!st.control;
  if (st.control) {
    $("btn-pause").disabled = !["running", "starting"].includes(st.state);
    $("btn-resume").disabled = st.state !== "paused";
    $("btn-abort").disabled = ["finished", "failed", "aborted"].includes(st.state);
  }
  renderGrid(st);
  renderLatest(st.latest || []);
  renderResult(st.result);
  $("events-count").textContent = st.events_count ? "(" + st.events_count + ")" : "";
}

function fmtClockTime(iso) {  // the expected end in this computer's local time (the date too when not today)
  const d = new Date(iso);
  if (isNaN(d)) return "";
  const time = d.toLocaleTimeString([], { hour: "2-digit", minute: "2-digit" });
  return d.toDateString() === new Date().toDateString() ? time : d.toLocaleDateString() + " " + time;
}

function renderEta(st) {
  const virtual = st.clock === "virtual";
  let text, note = "";
  if (st.state === "finished") text = "done";
  else if (FINAL.has(st.state)) text = "–";
  else if (st.eta_s === null || st.eta_s === undefined) text = st.operator ? "– (waiting for the operator)" : "– (no rate yet)";
  else {
    text = fmtDuration(st.eta_s) + (virtual ? " on the virtual clock" : "") + (st.operator ? " once the operator's step is done" : "");
    const end = st.ends_utc ? fmtClockTime(st.ends_utc) : "";
    if (end) text += " · ends about " + end + (virtual ? " (virtual clock)" : "");
    if (virtual) note = "the virtual clock's: the simulated measurement's time, as its certificate dates it (the run itself takes far less)";
    else if (st.solving_s) note = "includes about " + fmtDuration(st.solving_s) + " to solve and write the results (estimated from the plan's size)";
  }
  $("eta").textContent = text;
  $("eta-note").textContent = note;
}

function renderOperator(st) {
  const op = st.operator;
  const card = $("operator-card");
  const waiting = !!(op && op.instruction);
  const asked = waiting ? (op.step ?? "") + ":" + op.instruction : "";
  if (waiting && card.dataset.asked !== asked) $("operator-msg").textContent = ""; // a new step: no old answer
  card.dataset.asked = asked;
  S.operatorStep = waiting && Number.isInteger(op.step) ? op.step : null; // Done answers this step, never a later one
  card.hidden = !waiting;
  document.title = (waiting ? "Operator step · " : "") + (st.name || "rtcal live view");
  if (!waiting) return;
  $("operator-instruction").textContent = op.instruction;
  $("operator-live").hidden = !st.control;
  $("operator-readonly").hidden = !!st.control;
  $("operator-since").textContent = (S.operatorStep ? "operator step " + S.operatorStep + (op.t_s == null ? "" : " · ") : "")
    + (op.t_s == null ? "" : "asked at " + fmtNum(op.t_s, 1) + " s of the run's clock");
}

function renderGrid(st) {
  const p = st.progress;
  const box = $("grid");
  if (!p) return;
  $("grid-axis").textContent = p.axis === "target" ? "target, run and direction" : "point and station";
  const ended = FINAL.has(st.state);
  const cur = ended ? {} : (st.current || {}); // a run that has ended is nowhere now
  // a finished run took every planned reading: a cell it has not is no target of that row (another seating's)
  const unseen = st.state === "finished" ? "none" : ended ? "unmeasured" : "pending";
  $("legend-pending").textContent = CELL_WORDS[unseen];
  $("legend-pending-cell").className = "cell " + unseen;
  $("legend-now").hidden = ended;
  const table = document.createElement("table");
  table.className = "grid";
  const head = table.createTHead().insertRow();
  head.appendChild(document.createElement("th"));
  const label = (text) => {  // turned upright in a span, centred over its column's cells
    const th = document.createElement("th"), span = document.createElement("span");
    span.textContent = text; th.appendChild(span); head.appendChild(th);
  };
  p.columns.forEach(label);
  label("done");
  const body = table.createTBody();
  for (const row of p.rows) {
    const tr = body.insertRow();
    const th = document.createElement("th"); th.textContent = row.label; tr.appendChild(th);
    row.cells.forEach((status, i) => {
      const td = tr.insertCell();
      const span = document.createElement("span");
      const isCurrent = status !== "done" && isCurrentCell(cur, row.label, p.columns[i], p.axis);
      const shown = isCurrent ? "current" : status === "pending" ? unseen : status;
      span.className = "cell " + shown;
      span.title = row.label + ", " + p.columns[i] + ": " + CELL_WORDS[shown];
      td.appendChild(span);
    });
    const n = tr.insertCell(); n.textContent = row.done; n.className = "num";
  }
  box.replaceChildren(table);
}

const CELL_WORDS = { done: "done", current: "now", rejected: "rejected", skipped: "skipped", pending: "to do",
  unmeasured: "not measured", none: "not planned in this row" };

function isCurrentCell(cur, rowLabel, column, axis) {
  if (axis !== "target" || cur.target_deg === undefined || cur.run === undefined) return false;
  const arrow = cur.direction === "+" ? "↑" : "↓";
  return rowLabel.endsWith("run " + cur.run + " " + arrow) && column === (+cur.target_deg).toString() + "°";
}

function renderLatest(latest) {
  const body = $("latest").tBodies[0];
  const env = $("environment").tBodies[0];
  const rows = [], envRows = [];
  for (const r of latest) {
    const tr = document.createElement("tr");
    const conditions = r.kind === "environment";  // the store's description of the quantity says what it is
    if (r.what) tr.title = r.what;
    const cells = conditions
      ? [r.quantity, fmtNum(r.value, 2) + " " + unitText(r.unit), r.age_s === null ? "–" : fmtNum(r.age_s, 1) + " s"]
      : [r.instrument, r.quantity, fmtNum(r.value) + " " + unitText(r.unit), r.age_s === null ? "–" : fmtNum(r.age_s, 1) + " s"];
    cells.forEach((text, i) => {
      const td = tr.insertCell();
      td.textContent = text;
      if (i >= cells.length - 2) td.className = "num";
    });
    (conditions ? envRows : rows).push(tr);
  }
  body.replaceChildren(...rows);
  if (envRows.length) env.replaceChildren(...envRows);
}

function renderEvents() {
  const list = $("events");
  const shown = S.events.slice(-300).reverse();
  list.replaceChildren(...shown.map((e) => {
    const li = document.createElement("li");
    const t = document.createElement("span"); t.className = "t"; t.textContent = fmtNum(e.t_s, 1) + " s";
    const k = document.createElement("span"); k.className = "kind " + e.kind; k.textContent = e.kind;
    const i = document.createElement("span"); i.className = "muted"; i.textContent = e.instrument || "";
    const m = document.createElement("span"); m.textContent = e.message;
    li.append(t, k, i, m);
    return li;
  }));
  if (!shown.length) {
    const li = document.createElement("li"); li.className = "muted"; li.textContent = "no event yet"; list.replaceChildren(li);
  }
}

function renderResult(result) {
  const card = $("result-card");
  if (!result) { card.hidden = true; return; }
  card.hidden = false;
  const links = $("result-links");
  links.replaceChildren(...(result.files || []).map((f) => {
    const a = document.createElement("a"); a.href = "files/" + f; a.textContent = f; a.target = "_blank"; a.rel = "noopener";
    const span = document.createElement("span"); span.append(a, "  "); return span;
  }));
  $("result-headline").textContent = result.error ? result.error : (result.headline || "");
  const departed = $("result-departures");
  departed.hidden = !result.departures;
  departed.textContent = result.departures ? "Departures from the method: " + result.departures : "";
  renderTable($("result-brief"), result.brief ? result.brief.heading + " (as on the certificate)" : "",
    result.brief ? result.brief.header : [], result.brief ? result.brief.rows : [], [1, 2]);
  const c = result.conformity;
  renderTable($("result-conformity"), c ? c.heading + ": " + c.verdict.toUpperCase() : "", c ? c.header : [],
    c ? c.rows : [], [2, 3, 4, 5], c ? c.rule : "");
  $("result-details").hidden = !!result.error || !(result.lines || []).length;
  $("result-lines").textContent = (result.lines || []).join("\n");
  const d = result.deviations;
  if (!d) { $("result-plot").replaceChildren(); return; }
  const series = new Map();
  d.target_deg.forEach((x, i) => {
    const y = d.deviation_arcsec[i];
    if (y === null) return;
    const key = "run " + d.run[i] + " " + (d.direction[i] > 0 ? "↑" : "↓");
    if (!series.has(key)) series.set(key, { label: key, run: d.run[i], dir: d.direction[i], points: [] });
    series.get(key).points.push({ x: x, y: y, err: d.U_arcsec[i], text: d.text ? d.text[i] : null });
  });
  drawPlot($("result-plot"), $("result-legend"), [...series.values()], "target (°)", "deviation (″), bars: U (k = 2)");
  $("result-note").textContent = "positioning deviations of the recommended estimate (" + d.estimator +
    "), relative to the first target of the first direction; bars ± U (k = 2)";
}

function renderTable(box, heading, header, rows, numeric, note) {  // a certificate's table, its words as they are
  if (!rows.length) { box.replaceChildren(); return; }
  const h = document.createElement("h3"); h.textContent = heading;
  const table = document.createElement("table"); table.className = "brief";
  const tr = table.createTHead().insertRow();
  for (const text of header) { const th = document.createElement("th"); th.textContent = text; tr.appendChild(th); }
  const body = table.createTBody();
  for (const row of rows) {
    const r = body.insertRow();
    row.forEach((text, i) => { const td = r.insertCell(); td.textContent = text; if (numeric.includes(i)) td.className = "num"; });
  }
  const parts = [h, table];
  if (note) { const p = document.createElement("p"); p.className = "muted small"; p.textContent = note; parts.push(p); }
  box.replaceChildren(...parts);
}

// ---- the plot of readings per target ------------------------------------------------------------
function renderPlot() {
  const q = $("plot-select").value;
  if (!q) return;
  const deg = S.quantities.get(q) === "deg";
  const series = new Map();
  const perPlan = new Map(); // plan_index -> accepted attempt's mean (a plan is done once)
  for (const a of S.attempts.values()) {
    if (a.marked) continue;
    const rows = a.rows.filter((r) => r.instrument + "." + r.quantity === q && r.value !== null);
    if (!rows.length) continue;
    const r0 = rows[0];
    let y = rows.reduce((s, r) => s + r.value, 0) / rows.length;
    const x = r0.commanded_angle_deg;
    if (x === null || x === undefined) continue;
    if (deg) y = wrap180(y - x) * 3600;
    perPlan.set(r0.plan_index, { r: r0, x: x, y: y });
  }
  for (const { r, x, y } of perPlan.values()) {
    let key, run = 0, dir = 1;
    if (r.run !== null && r.direction !== null) {
      run = r.run + 1; dir = r.direction;
      key = (r.seating ? "seating " + (r.seating + 1) + " · " : "") + "run " + run + " " + (dir > 0 ? "↑" : "↓");
    } else if (r.point !== null) {
      run = r.point + 1;
      key = (r.seating ? "mount " + (r.seating + 1) + " · " : "") + "point " + run;
    } else key = "readings";
    if (!series.has(key)) series.set(key, { label: key, run: run, dir: dir, points: [] });
    series.get(key).points.push({ x: x, y: y });
  }
  const unit = S.quantities.get(q);
  drawPlot($("plot"), $("legend"), [...series.values()], "commanded angle (°)",
    deg ? q + " − command (″)" : q + " (" + unitText(unit) + ")");
  $("plot-note").textContent = (q === "autocollimator.x_arcsec"
    ? "The autocollimator's reading of the polygon face in front: the table's deviation plus that face's error and a constant per seating. "
    : "") + "One point per planned reading (mean of its samples); rejected and skipped attempts are left out.";
}

function wrap180(d) { return ((d + 180) % 360 + 360) % 360 - 180; }

function niceTicks(lo, hi, n) {
  if (!(hi > lo)) { hi = lo + 1; lo = lo - 1; }
  const raw = (hi - lo) / n, mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 2.5, 5, 10].map((f) => f * mag).find((s) => s >= raw) || raw;
  const ticks = [];
  for (let t = Math.ceil(lo / step) * step; t <= hi + step * 1e-9; t += step) ticks.push(+t.toPrecision(12));
  return ticks;
}

function el(name, attrs, text) {
  const e = document.createElementNS(SVGNS, name);
  for (const k in attrs) e.setAttribute(k, attrs[k]);
  if (text !== undefined) e.textContent = text;
  return e;
}

function marker(x, y, dir, color) {
  const s = 5;
  if (dir > 0) return el("path", { d: `M${x},${y - s}L${x + s},${y + s * 0.8}L${x - s},${y + s * 0.8}Z`, fill: color });
  if (dir < 0) return el("path", { d: `M${x},${y + s}L${x + s},${y - s * 0.8}L${x - s},${y - s * 0.8}Z`, fill: "#fff", stroke: color, "stroke-width": 1.6 });
  return el("circle", { cx: x, cy: y, r: 4, fill: color });
}

function drawPlot(svg, legend, series, xLabel, yLabel) {
  const vb = svg.viewBox.baseVal, W = vb.width, H = vb.height;
  const m = { l: 70, r: 16, t: 14, b: 46 };
  const pts = series.flatMap((s) => s.points);
  svg.replaceChildren();
  if (!pts.length) {
    svg.appendChild(el("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, "no reading of this quantity yet"));
    legend.replaceChildren();
    return;
  }
  let x0 = Math.min(...pts.map((p) => p.x)), x1 = Math.max(...pts.map((p) => p.x));
  if (x0 >= 0 && x1 <= 360 && x1 - x0 > 45) { x0 = 0; x1 = 360; }
  if (x1 === x0) { x0 -= 1; x1 += 1; }
  let y0 = Math.min(...pts.map((p) => p.y - (p.err || 0))), y1 = Math.max(...pts.map((p) => p.y + (p.err || 0)));
  const pad = (y1 - y0) * 0.08 || Math.max(Math.abs(y0) * 0.05, 1e-3);
  y0 -= pad; y1 += pad;
  const X = (x) => m.l + (x - x0) / (x1 - x0) * (W - m.l - m.r);
  const Y = (y) => H - m.b - (y - y0) / (y1 - y0) * (H - m.t - m.b);
  for (const t of niceTicks(y0, y1, 6)) {
    svg.appendChild(el("line", { x1: m.l, x2: W - m.r, y1: Y(t), y2: Y(t), class: "gridline" }));
    svg.appendChild(el("text", { x: m.l - 6, y: Y(t) + 4, "text-anchor": "end" }, +t.toPrecision(6)));
  }
  const xt = (x0 === 0 && x1 === 360) ? [0, 45, 90, 135, 180, 225, 270, 315, 360] : niceTicks(x0, x1, 8);
  for (const t of xt) {
    svg.appendChild(el("line", { x1: X(t), x2: X(t), y1: m.t, y2: H - m.b, class: "gridline" }));
    svg.appendChild(el("text", { x: X(t), y: H - m.b + 16, "text-anchor": "middle" }, +t.toPrecision(6)));
  }
  if (y0 < 0 && y1 > 0) svg.appendChild(el("line", { x1: m.l, x2: W - m.r, y1: Y(0), y2: Y(0), class: "zero" }));
  svg.appendChild(el("line", { x1: m.l, x2: m.l, y1: m.t, y2: H - m.b, class: "axis" }));
  svg.appendChild(el("line", { x1: m.l, x2: W - m.r, y1: H - m.b, y2: H - m.b, class: "axis" }));
  svg.appendChild(el("text", { x: (m.l + W - m.r) / 2, y: H - 8, "text-anchor": "middle", class: "label" }, xLabel));
  svg.appendChild(el("text", { x: 14, y: (m.t + H - m.b) / 2, "text-anchor": "middle", class: "label",
    transform: `rotate(-90 14 ${(m.t + H - m.b) / 2})` }, yLabel));
  series.sort((a, b) => a.run - b.run || b.dir - a.dir);
  const items = [];
  series.forEach((s, k) => {
    const color = COLORS[k % COLORS.length];
    const dash = s.dir < 0 ? "5 3" : DASHES[Math.floor(k / COLORS.length) % DASHES.length];
    const p = s.points.slice().sort((a, b) => a.x - b.x);
    svg.appendChild(el("polyline", { points: p.map((q) => X(q.x) + "," + Y(q.y)).join(" "), fill: "none", stroke: color,
      "stroke-width": 1.4, "stroke-dasharray": dash, opacity: 0.85 }));
    for (const q of p) {
      if (q.err) svg.appendChild(el("line", { x1: X(q.x), x2: X(q.x), y1: Y(q.y - q.err), y2: Y(q.y + q.err), stroke: color, "stroke-width": 1.2, opacity: 0.7 }));
      const mk = marker(X(q.x), Y(q.y), s.dir, color);
      mk.appendChild(el("title", {}, s.label + ": " + q.x + "°, " + (q.text || fmtNum(q.y, 3) + (q.err ? " ± " + fmtNum(q.err, 3) : ""))));
      svg.appendChild(mk);
    }
    const span = document.createElement("span");
    const i = document.createElement("i");
    i.style.background = s.dir < 0 ? `repeating-linear-gradient(90deg, ${color} 0 5px, transparent 5px 8px)` : color;
    span.append(i, s.label + (s.dir > 0 ? " ▲" : s.dir < 0 ? " ▽" : ""));
    items.push(span);
  });
  legend.replaceChildren(...items);
}

// ---- control -----------------------------------------------------------------------------------
// A control request that got no answer is sent again (five tries, 0.25 s apart): someone flooding the
// server with connections can have it closed before it was read — never once read, so never done twice.
async function sendControl(path) {
  for (let attempt = 1; ; attempt++) {
    try {
      return await fetch(path, { method: "POST", headers: { Authorization: "Bearer " + S.token }, cache: "no-store" });
    } catch (e) {
      if (attempt >= 5) throw e;
      await new Promise((done) => setTimeout(done, 250));
    }
  }
}

async function control(command) {
  const typed = $("token").value.trim();
  if (typed) S.token = typed;
  const msg = $(command === "confirm" ? "operator-msg" : "control-msg");
  if (!S.token) {
    msg.textContent = "enter the run's control token first" + (command === "confirm" ? " (under Control)" : "");
    msg.className = "bad"; $("token").focus(); return;
  }
  msg.textContent = command + "…"; msg.className = "";
  try {
    const step = command === "confirm" && S.operatorStep ? "?step=" + S.operatorStep : "";
    const res = await sendControl("api/" + command + step);
    if (res.status === 202 && command === "confirm") { msg.textContent = "confirmed: the run goes on"; msg.className = "ok"; }
    else if (res.status === 202 && command === "abort") {
      S.abortAfter = S.events.length ? Math.max(...S.events.map((e) => e.id)) : 0; // its stops are the events after it
      msg.textContent = ABORT_SENT; msg.className = "ok";
    }
    else if (res.status === 202) { msg.textContent = REQUESTED[command]; msg.className = "ok"; }
    else if (res.status === 401) { msg.textContent = "refused: wrong control token"; msg.className = "bad"; S.token = null; }
    else { const body = await res.json().catch(() => ({})); msg.textContent = "refused (" + res.status + "): " + (body.error || ""); msg.className = "bad"; }
  } catch (e) {
    msg.textContent = "cannot reach the run: " + e; msg.className = "bad";
  }
}

const REQUESTED = {
  pause: "pause requested: the run holds at the next checkpoint (the reading in hand is stored first)",
  resume: "resume requested: the next reading approaches its targets anew",
};
const ABORT_SENT = "abort requested: the run stops at once; each machine is being watched until it is seen at rest…";

function renderAbort() {  // after the page's abort: each machine's stop as the engine saw it (stopped / moving events)
  if (S.abortAfter === undefined) return;
  const seen = S.events.filter((e) => e.id > S.abortAfter && (e.kind === "stopped" || e.kind === "moving"));
  if (!seen.length) return;
  const moving = seen.filter((e) => e.kind === "moving");
  const msg = $("control-msg");
  msg.textContent = (moving.length ? "aborted, but not every machine was seen to stop: " : "aborted: ")
    + seen.map((e) => (e.instrument ? e.instrument + " " : "") + e.message).join("; ");
  msg.className = moving.length ? "bad" : "ok";
}

function armAbort() {
  const b = $("btn-abort");
  if (b.classList.contains("armed")) { b.classList.remove("armed"); b.textContent = "Abort"; control("abort"); return; }
  b.classList.add("armed"); b.textContent = "Confirm abort";
  setTimeout(() => { b.classList.remove("armed"); b.textContent = "Abort"; }, 5000);
}

function tick() {
  if (S.lastData) {
    const s = Math.round((Date.now() - S.lastData) / 1000);
    if (S.source && S.source.readyState === EventSource.OPEN) setConn("live · last update " + s + " s ago");
  }
}

document.addEventListener("DOMContentLoaded", () => {
  readFragment();
  $("control-form").addEventListener("submit", (ev) => ev.preventDefault());
  $("btn-pause").addEventListener("click", () => control("pause"));
  $("btn-resume").addEventListener("click", () => control("resume"));
  $("btn-abort").addEventListener("click", armAbort);
  $("btn-confirm").addEventListener("click", () => control("confirm"));
  $("plot-select").addEventListener("change", () => { $("plot-select").dataset.chosen = "1"; renderPlot(); });
  $("run-dir").textContent = location.host;
  connect();
  setInterval(tick, 1000);
});
