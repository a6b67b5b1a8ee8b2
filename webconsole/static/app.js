// SecUAV console page: the fleet table, one vehicle's live view, and the controls.
// Everything comes from the console's JSON API and its server-sent event stream;
// buffers are trimmed by time so a long session stays smooth.
"use strict";

const PLOT_WINDOW_S = 60;   // seconds of readings on the plots
const TRAIL_S = 15;         // seconds of trail on the top view
const MAX_PLOTS = 6;        // sensor plots ticked at first when the target names no sensor group
const NO_PROFILE = "";      // the library drop-down's entry for "no attack in force"
// The switches the panel has controls of its own for; every other declared vehicle switch (the row's
// `switches`) is listed generically under "Other switches", with a field to send it a JSON request.
const OWN_CONTROLS = new Set(["attack", "attack/mode", "secure"]);
const BOOKKEEPING = new Set(["sysid", "since", "request_id", "ok", "error", "warnings"]);
const $ = (id) => document.getElementById(id);

const state = {
  selected: null,           // sysid shown in the vehicle panel
  source: null,             // EventSource
  world: null,              // scenario geometry of the selected vehicle
  library: [],
  estimators: [],           // GET /api/estimators/params: name, dist, version, summary, params
  trails: { truth: [], ground: [], secure: [] },   // [t, north, east]
  sensors: new Map(),       // id -> {t: [], original: [], forwarded: [], secure: [], truth: []}
  flagged: new Set(),
  picked: new Set(),        // sensor ids plotted
  plots: new Map(),         // id -> uPlot
  formsFor: null,           // the vehicle whose state the forms were last filled from
  formsProfile: null,       // the profile in force they were filled from ("" none)
  secureFormsFor: null,     // the vehicle whose secure stage the estimator form was filled from
  switchItems: new Map(),   // kind -> its <li> under "Other switches" (kept, so a half-typed request survives)
  dirty: false,
};

// ---------------------------------------------------------------- API helpers
async function api(path, body) {
  const init = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  };
  const response = await fetch(path, init);
  let data = null;
  try { data = await response.json(); } catch (e) { data = { ok: false, error: response.statusText }; }
  return { status: response.status, data };
}

function showAck(what, result) {
  const box = $("ack");
  const d = result.data || {};
  const verdict = result.status === 200 ? "ok" : result.status === 422 ? "not sent" :
    result.status === 504 ? "no answer" : "rejected";
  box.className = "ack " + (result.status === 200 ? "ok" : "rejected");
  const lines = [`${what}: ${verdict}`];
  if (d.error) lines.push(d.error);
  if (d.profile !== undefined) lines.push(`profile: ${d.profile || "none"}${d.hash ? " (hash " + d.hash.slice(0, 12) + ")" : ""}`);
  if (d.mode) lines.push(`mode: ${d.mode}`);
  if (d.estimator !== undefined && what.startsWith("secure")) {
    const given = d.params && Object.keys(d.params).length ? ` ${JSON.stringify(d.params)}` : "";
    lines.push(`estimator: ${d.estimator || "off"}${given}`);
  }
  box.textContent = lines.join("\n");
  if (result.status === 200) {   // a later success: an old profile error no longer describes what is in force
    $("yaml-error").hidden = true;
    $("yaml-error").textContent = "";
    $("yaml").classList.remove("invalid");
  }
}

// ---------------------------------------------------------------- fleet table
function fmt(value, digits = 0) {
  return typeof value === "number" ? value.toFixed(digits) : "-";
}

// The table is rebuilt with every update (12.5 a second): a row that was pressed may be gone by the time the
// button comes up, so a click on it would never arrive. A row is selected on the press itself, by one
// listener on the table body that outlives the rows.
function pickRow(event) {
  const tr = event.target.closest("tr[data-sysid]");
  if (tr && event.button === 0) select(Number(tr.dataset.sysid));
}

// Whether the console itself reaches the broker: without it the page shows nothing live, and says so.
function renderBroker(broker) {
  if (!broker) return;
  const badge = $("link-state");
  if (broker.connected) {
    badge.textContent = "live";
    badge.className = "badge on";
    badge.title = `broker ${broker.url}`;
  } else {
    badge.textContent = "no broker";
    badge.className = "badge off";
    badge.title = `the console cannot reach the broker at ${broker.url}`;
  }
  $("fleet-empty").textContent = broker.connected ? "No vehicle yet: start secuav-proxy on this broker."
    : `Not connected to the broker at ${broker.url}: nothing on this page is live until it is reachable.`;
}

function renderFleet(rows) {
  const body = document.querySelector("#fleet tbody");
  $("fleet-empty").hidden = rows.length > 0;
  body.replaceChildren(...rows.map((r) => {
    const tr = document.createElement("tr");
    tr.dataset.sysid = r.sysid;
    if (r.sysid === state.selected) tr.className = "selected";
    const cells = [
      `v${r.sysid}`, r.instances.join(", ") || "?", null, r.profile || "none", r.mode || "-",
      r.secure_available ? (r.secure || "off") : "n/a", fmt(r.frames_in_per_s), fmt(r.frames_out_per_s),
      r.rewritten, r.dropped, r.bad, fmt(r.latency_p50_ms, 3), fmt(r.latency_p99_ms, 3),
    ];
    for (const c of cells) {
      const td = document.createElement("td");
      if (c === null) {
        const badge = document.createElement("span");
        badge.className = "badge " + (r.online ? "online" : "offline");
        badge.textContent = r.online ? "online" : "offline";
        td.append(badge);
        if ((r.warnings || []).length) {   // a stage that cannot work: the state says why (vehicle panel)
          const warn = document.createElement("span");
          warn.className = "badge warning";
          warn.textContent = r.warnings.length === 1 ? "warning" : `${r.warnings.length} warnings`;
          warn.title = r.warnings.join("\n");
          td.append(warn);
        }
      } else {
        td.textContent = String(c);
      }
      tr.append(td);
    }
    return tr;   // selected on pointerdown, by one listener on the table body (init)
  }));
  const mine = rows.find((r) => r.sysid === state.selected);
  if (mine && (state.formsFor !== mine.sysid || state.formsProfile !== (mine.profile || NO_PROFILE))) {
    // the controls start from what is in force, and follow it when it changes (a Clear, another operator)
    state.formsFor = mine.sysid;
    state.formsProfile = mine.profile || NO_PROFILE;
    const fromLibrary = mine.profile && state.library.some((p) => p.name === mine.profile);
    // a pasted profile in force leaves the drop-down and the text as they are (the text is the operator's)
    if ((fromLibrary || !mine.profile) && $("library").value !== (mine.profile || NO_PROFILE)) {
      $("library").value = mine.profile || NO_PROFILE;
      renderParams();
    }
  }
  if (mine && state.formsFor === mine.sysid && state.secureFormsFor !== mine.sysid) {
    state.secureFormsFor = mine.sysid;
    if (mine.secure_available) {
      $("estimator").value = mine.secure || "off";
      renderEstimatorParams(mine.secure_params || {});
    }
  }
  if (mine) {
    $("mode-now").textContent = mine.mode || "-";
    $("mode-now").className = "badge " + (mine.mode === "bypass" ? "bypass" : "on");
    $("secure-now").textContent = mine.secure_available ? (mine.secure || "off") +
      (mine.secure && mine.secure_direction ? ` ${SECURE_ON[mine.secure_direction] || ""}` : "") : "not available";
    const since = mine.since ? new Date(mine.since * 1000).toLocaleTimeString() : "";
    $("vehicle-title").textContent = `Vehicle v${mine.sysid}: ` + (mine.profile
      ? `${mine.profile} (hash ${String(mine.hash).slice(0, 12)}, since ${since}), changing frames ` +
        toward(mine.directions || []) : "no attack") +
      (mine.mode === "bypass" ? ", attack stage bypassed" : "") +
      (mine.attack_ok ? "" : ` (last request rejected: ${mine.attack_error})`);
    renderWarnings(mine.warnings || []);
    renderSwitches(mine.switches || {});
  }
  if (state.selected === null && rows.length > 0) select(rows[0].sysid);
}

// Which way the active profile changes frames (attack/state "directions"), in words.
const TOWARD = { downlink: "toward the ground", uplink: "toward the vehicle" };
const SECURE_ON = { downlink: "(toward the ground)", uplink: "(toward the vehicle)", both: "(both directions)" };
function toward(directions) {
  const words = ["downlink", "uplink"].filter((d) => directions.includes(d)).map((d) => TOWARD[d]);
  return words.length ? words.join(" and ") : "nothing";
}

// What keeps the attack or the secure stage from working (a signed stream and no key, a scenario whose
// rangefinders are not the vehicle's): each "code: text", shown until the proxy's state drops it.
function renderWarnings(warnings) {
  const box = $("vehicle-warnings");
  box.hidden = warnings.length === 0;
  box.replaceChildren(...warnings.map((w) => {
    const li = document.createElement("li");
    const cut = w.indexOf(": ");
    const code = document.createElement("strong");
    code.textContent = cut > 0 ? w.slice(0, cut) : "warning";
    li.append(code, cut > 0 ? w.slice(cut) : `: ${w}`);
    return li;
  }));
}

// Every declared vehicle switch the panel has no controls of its own for: its kind, what its state holds
// (compact JSON, without ids, times and the verdict), the last refusal and its warnings; a JSON request
// typed next to it goes to POST /api/vehicles/N/switches/KIND.
function renderSwitches(all) {
  const kinds = Object.keys(all).filter((k) => !OWN_CONTROLS.has(k)).sort();
  $("switches-panel").hidden = kinds.length === 0;
  for (const [kind, item] of state.switchItems) {
    if (!kinds.includes(kind)) { item.remove(); state.switchItems.delete(kind); }
  }
  for (const kind of kinds) {
    let item = state.switchItems.get(kind);
    if (!item) {
      item = switchItem(kind);
      state.switchItems.set(kind, item);
      $("switches").append(item);
    }
    const st = all[kind];
    const held = {};
    for (const [k, v] of Object.entries(st || {})) if (!BOOKKEEPING.has(k)) held[k] = v;
    item.querySelector(".switch-state").textContent = st ? JSON.stringify(held) : "no state yet";
    item.querySelector(".switch-error").textContent = st && st.ok === false ? `last request rejected: ${st.error}` : "";
    const warnings = st && Array.isArray(st.warnings) ? st.warnings : [];
    const list = item.querySelector(".warnings");
    list.hidden = warnings.length === 0;
    if (list.dataset.shown !== JSON.stringify(warnings)) {
      list.dataset.shown = JSON.stringify(warnings);
      list.replaceChildren(...warnings.map((w) => { const li = document.createElement("li"); li.textContent = w; return li; }));
    }
  }
}

function switchItem(kind) {
  const item = document.createElement("li");
  item.dataset.kind = kind;
  const name = document.createElement("strong");
  name.textContent = kind;
  const held = document.createElement("code");
  held.className = "switch-state";
  const error = document.createElement("span");
  error.className = "switch-error error";
  const warnings = document.createElement("ul");
  warnings.className = "warnings";
  warnings.hidden = true;
  const row = document.createElement("div");
  row.className = "row";
  const input = document.createElement("input");
  input.className = "switch-request";
  input.placeholder = '{"field": value} or null';
  input.spellcheck = false;
  const button = document.createElement("button");
  button.textContent = "Set";
  button.addEventListener("click", () => setSwitch(kind, input));
  row.append(input, button);
  item.append(name, " ", held, " ", error, warnings, row);
  return item;
}

async function setSwitch(kind, input) {
  if (state.selected === null) return;
  let body;
  try { body = JSON.parse(input.value.trim() || "null"); } catch (e) {
    input.classList.add("invalid");
    showAck(kind, { status: 422, data: { error: `not JSON: ${e.message}` } });
    return;
  }
  input.classList.remove("invalid");
  const result = await api(`/api/vehicles/${state.selected}/switches/${kind}`, body);
  input.classList.toggle("invalid", result.status === 422);
  showAck(kind, result);
  if (result.status === 200 || result.status === 409) {   // the proxy's state: what the switch now holds
    const held = {};
    for (const [k, v] of Object.entries(result.data || {})) if (!BOOKKEEPING.has(k)) held[k] = v;
    $("ack").textContent += `\n${kind}: ${JSON.stringify(held)}`;
  }
}

// ---------------------------------------------------------------- live stream
function connect() {
  if (state.source) state.source.close();
  const source = new EventSource(`/api/stream?vehicle=${state.selected || 0}`);
  state.source = source;
  source.addEventListener("open", () => { $("link-state").textContent = "connected"; $("link-state").className = "badge off"; });
  source.addEventListener("error", () => { $("link-state").textContent = "reconnecting…"; $("link-state").className = "badge off"; });
  source.addEventListener("update", (event) => {
    const update = JSON.parse(event.data);
    renderBroker(update.broker);
    renderFleet(update.fleet);
    if (update.vehicle === state.selected) {
      for (const sample of update.samples) ingest(sample);
      state.dirty = true;
    }
  });
}

function push(trail, t, pos) {
  if (Array.isArray(pos) && pos.length >= 2) trail.push([t, pos[0], pos[1]]);
}

function ingest(s) {
  if (s.kind === "truth") push(state.trails.truth, s.t, s.pos);
  else if (s.kind === "estimate") {
    push(state.trails.secure, s.t, s.pos);
    state.flagged = new Set(s.attacked || []);
  } else if (s.kind === "readings") {
    push(state.trails.ground, s.t, s.ground_pos);
    for (const [id, r] of Object.entries(s.sensors || {})) {
      let series = state.sensors.get(id);
      if (!series) {
        series = { t: [], original: [], attacked: [], forwarded: [], secure: [], truth: [] };
        state.sensors.set(id, series);
        if (pickedByDefault(id)) state.picked.add(id);
        renderPicker();
      }
      series.t.push(s.t);
      series.original.push(r.original_m ?? null);
      series.attacked.push(r.attacked_m ?? null);
      series.forwarded.push(r.forwarded_m ?? null);
      series.secure.push(r.secure_m ?? null);
      series.truth.push(r.truth_m ?? null);
    }
  }
}

function trim(now) {
  for (const trail of Object.values(state.trails)) {
    let drop = 0;
    while (drop < trail.length && trail[drop][0] < now - TRAIL_S) drop++;
    if (drop) trail.splice(0, drop);
  }
  for (const series of state.sensors.values()) {
    let drop = 0;
    while (drop < series.t.length && series.t[drop] < now - PLOT_WINDOW_S) drop++;
    if (drop) for (const key of Object.keys(series)) series[key].splice(0, drop);
  }
}

// ---------------------------------------------------------------- the vehicle panel
async function select(sysid) {
  if (state.selected === sysid) return;
  state.selected = sysid;
  state.trails = { truth: [], ground: [], secure: [] };
  state.sensors = new Map();
  state.picked = new Set();
  for (const plot of state.plots.values()) plot.destroy();
  state.plots = new Map();
  $("plots").replaceChildren();
  $("sensor-picker").replaceChildren();
  $("vehicle-panel").hidden = false;
  state.switchItems = new Map();
  $("switches").replaceChildren();
  const { data } = await api(`/api/vehicles/${sysid}`);
  state.world = data && data.world ? data.world : null;
  connect();
}

// A sensor is plotted from the start when the vehicle's target holds on it (wall_hover's five forward sensors,
// the radar among them), or, when the target names no group, while fewer than MAX_PLOTS are.
function pickedByDefault(id) {
  const v = state.world && state.world.vehicles[String(state.selected)];
  const held = v && v.target && Array.isArray(v.target.sensor_ids) ? v.target.sensor_ids.map(String) : [];
  return held.length ? held.includes(id) : state.picked.size < MAX_PLOTS;
}

function renderPicker() {
  const names = state.world && state.world.vehicles[String(state.selected)]
    ? state.world.vehicles[String(state.selected)].sensors : {};
  const ids = [...state.sensors.keys()].sort((a, b) => Number(a) - Number(b));
  $("sensor-picker").replaceChildren(...ids.map((id) => {
    const label = document.createElement("label");
    const box = document.createElement("input");
    box.type = "checkbox";
    box.checked = state.picked.has(id);
    box.dataset.sensor = id;
    box.addEventListener("change", () => {
      if (box.checked) state.picked.add(id); else state.picked.delete(id);
      state.dirty = true;
    });
    label.append(box, ` ${id}${names[id] ? " (" + names[id] + ")" : ""}`);
    return label;
  }));
}

function plotFor(id) {
  let plot = state.plots.get(id);
  if (plot) return plot;
  const holder = document.createElement("div");
  holder.className = "plot";
  holder.dataset.sensor = id;
  $("plots").append(holder);
  const opts = {
    title: `sensor ${id} (m)`, width: 460, height: 220,
    scales: { x: { time: true } },
    series: [
      {},
      { label: "original", stroke: "#888", spanGaps: true },
      { label: "attacked", stroke: "#ff7f0e", spanGaps: false },
      { label: "forwarded", stroke: "#d62728", spanGaps: true },
      { label: "secure", stroke: "#1f77b4", spanGaps: true },
      { label: "truth", stroke: "#2e8b57", dash: [4, 4], spanGaps: true },
    ],
  };
  plot = new uPlot(opts, [[], [], [], [], [], []], holder);
  state.plots.set(id, plot);
  return plot;
}

function renderPlots() {
  for (const [id, plot] of state.plots) {
    if (!state.picked.has(id)) {
      plot.destroy();
      state.plots.delete(id);
      const holder = document.querySelector(`#plots .plot[data-sensor="${id}"]`);
      if (holder) holder.remove();
    }
  }
  for (const id of state.picked) {
    const s = state.sensors.get(id);
    if (s) plotFor(id).setData([s.t, s.original, s.attacked, s.forwarded, s.secure, s.truth]);
  }
}

function renderFlags() {
  const ids = [...state.sensors.keys()].sort((a, b) => Number(a) - Number(b));
  $("flags").replaceChildren(...ids.map((id) => {
    const chip = document.createElement("span");
    chip.textContent = id;
    chip.dataset.sensor = id;
    if (state.flagged.has(Number(id))) chip.className = "flagged";
    return chip;
  }));
}

function drawTopView() {
  const canvas = $("topview");
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  // What to fit: anchors, starts, walls' points and every trail point; north is up, east to the right.
  const pts = [];
  const world = state.world;
  if (world) {
    for (const a of world.anchors) pts.push([a.pos_ned_m[0], a.pos_ned_m[1]]);
    for (const w of world.walls) pts.push([w.point_ned_m[0], w.point_ned_m[1]]);
    for (const v of Object.values(world.vehicles)) pts.push([v.start_ned_m[0], v.start_ned_m[1]]);
  }
  for (const trail of Object.values(state.trails)) for (const p of trail) pts.push([p[1], p[2]]);
  if (pts.length === 0) pts.push([0, 0]);
  let [nMin, nMax, eMin, eMax] = [Infinity, -Infinity, Infinity, -Infinity];
  for (const [n, e] of pts) { nMin = Math.min(nMin, n); nMax = Math.max(nMax, n); eMin = Math.min(eMin, e); eMax = Math.max(eMax, e); }
  const span = Math.max(nMax - nMin, eMax - eMin, 4) * 1.2;
  const cn = (nMin + nMax) / 2, ce = (eMin + eMax) / 2;
  const scale = Math.min(canvas.width, canvas.height) / span;
  const xy = (n, e) => [canvas.width / 2 + (e - ce) * scale, canvas.height / 2 - (n - cn) * scale];

  ctx.font = "12px sans-serif";
  if (world) {
    ctx.strokeStyle = "#444"; ctx.lineWidth = 4;
    for (const w of world.walls) {        // the wall's trace: through its point, across its normal
      const [pn, pe] = w.point_ned_m, [nn, ne] = w.normal_ned;
      const [dn, de] = [-ne, nn];
      ctx.beginPath();
      ctx.moveTo(...xy(pn - dn * span, pe - de * span));
      ctx.lineTo(...xy(pn + dn * span, pe + de * span));
      ctx.stroke();
    }
    ctx.fillStyle = "#555";
    for (const a of world.anchors) {
      const [x, y] = xy(a.pos_ned_m[0], a.pos_ned_m[1]);
      ctx.fillRect(x - 4, y - 4, 8, 8);
      ctx.fillText(`A${a.id}`, x + 6, y - 6);
    }
    drawTargets(ctx, world, xy, span);
    ctx.strokeStyle = "#999"; ctx.lineWidth = 1;
    for (const v of Object.values(world.vehicles)) {
      const [x, y] = xy(v.start_ned_m[0], v.start_ned_m[1]);
      ctx.beginPath(); ctx.moveTo(x - 5, y - 5); ctx.lineTo(x + 5, y + 5); ctx.moveTo(x + 5, y - 5); ctx.lineTo(x - 5, y + 5); ctx.stroke();
    }
  }
  const colours = { truth: "#2e8b57", ground: "#d62728", secure: "#1f77b4" };
  for (const [name, trail] of Object.entries(state.trails)) {
    if (trail.length === 0) continue;
    ctx.strokeStyle = colours[name]; ctx.lineWidth = 2;
    ctx.beginPath();
    trail.forEach((p, i) => { const [x, y] = xy(p[1], p[2]); if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
    ctx.stroke();
    const last = trail[trail.length - 1];
    const [x, y] = xy(last[1], last[2]);
    ctx.fillStyle = colours[name];
    ctx.beginPath(); ctx.arc(x, y, 6, 0, 2 * Math.PI); ctx.fill();
  }
  ctx.fillStyle = "#333";
  ctx.fillText(`N ↑   ${(1 / scale * 50).toFixed(2)} m per 50 px`, 8, canvas.height - 8);
}

// The vehicles' targets: a hold point, or the line at the held distance from a wall.
function drawTargets(ctx, world, xy, span) {
  ctx.save();
  ctx.strokeStyle = "#8a2be2"; ctx.fillStyle = "#8a2be2"; ctx.lineWidth = 1.5; ctx.setLineDash([6, 4]);
  for (const [sysid, v] of Object.entries(world.vehicles)) {
    const t = v.target;
    if (!t) continue;
    if (t.kind === "hold") {
      const [x, y] = xy(t.pos_ned_m[0], t.pos_ned_m[1]);
      ctx.beginPath(); ctx.arc(x, y, 7, 0, 2 * Math.PI); ctx.stroke();
      ctx.fillText(`target v${sysid}`, x + 9, y + 4);
    } else if (t.kind === "wall_distance") {
      const wall = world.walls.find((w) => w.name === t.wall);
      if (!wall) continue;
      const [nn, ne] = wall.normal_ned, [dn, de] = [-ne, nn];
      const pn = wall.point_ned_m[0] + nn * t.distance_m, pe = wall.point_ned_m[1] + ne * t.distance_m;
      ctx.beginPath();
      ctx.moveTo(...xy(pn - dn * span, pe - de * span));
      ctx.lineTo(...xy(pn + dn * span, pe + de * span));
      ctx.stroke();
      const [x, y] = xy(pn, pe);
      ctx.fillText(`target v${sysid}: ${t.distance_m} m from ${t.wall}`, x + 6, y - 6);
    }  // keep_range: the range to the peer is a sensor (id 50+n) and has its own plot
  }
  ctx.restore();
}

function frame() {
  if (state.dirty && state.selected !== null) {
    state.dirty = false;
    trim(Date.now() / 1000);
    renderPlots();
    renderFlags();
    drawTopView();
  }
  requestAnimationFrame(frame);
}

// ---------------------------------------------------------------- controls
function parseValue(text) {
  try { return JSON.parse(text); } catch (e) { return text; }
}

function renderParams() {
  const entry = state.library.find((p) => p.name === $("library").value);
  $("library-description").textContent = entry ? entry.description : "";
  const form = $("params");
  form.replaceChildren(...Object.entries(entry ? entry.parameters : {}).map(([name, spec]) => {
    const label = document.createElement("label");
    const input = document.createElement("input");
    input.name = name;
    input.value = JSON.stringify(spec.default);
    input.title = spec.description || "";
    label.append(name, input);
    return label;
  }));
  $("yaml").value = entry ? entry.text : "";
}

function params() {
  const out = {};
  const entry = state.library.find((p) => p.name === $("library").value);
  for (const input of $("params").querySelectorAll("input")) {
    input.classList.remove("invalid");
    const given = parseValue(input.value);
    const declared = entry && entry.parameters[input.name] ? entry.parameters[input.name].default : undefined;
    if (JSON.stringify(given) !== JSON.stringify(declared)) out[input.name] = given;
  }
  return out;
}

// The secure stage's estimator: its declared parameters, each with its default and range.
function renderEstimatorParams(inForce = {}) {
  const entry = state.estimators.find((e) => e.name === $("estimator").value);
  $("estimator-summary").textContent = entry ? `${entry.summary} (${entry.dist} ${entry.version})` : "";
  $("estimator-params").replaceChildren(...Object.entries(entry ? entry.params : {}).map(([name, spec]) => {
    const label = document.createElement("label");
    const input = document.createElement("input");
    const range = document.createElement("span");
    input.name = name;
    input.value = JSON.stringify(name in inForce ? inForce[name] : spec.default);
    input.title = `default ${JSON.stringify(spec.default)}`;
    range.className = "range";
    range.textContent = spec.low === null && spec.high === null ? "" :
      `in [${spec.low ?? "-inf"}, ${spec.high ?? "inf"}]`;
    label.append(name, input, range);
    return label;
  }));
}

function estimatorParams() {
  const out = {};
  const entry = state.estimators.find((e) => e.name === $("estimator").value);
  for (const input of $("estimator-params").querySelectorAll("input")) {
    input.classList.remove("invalid");
    const given = parseValue(input.value);
    const declared = entry && entry.params[input.name] ? entry.params[input.name].default : undefined;
    if (JSON.stringify(given) !== JSON.stringify(declared)) out[input.name] = given;
  }
  return out;
}

async function applySecure() {
  if (state.selected === null) return;
  const name = $("estimator").value;
  const body = name === "off" ? { estimator: name } : { estimator: name, params: estimatorParams() };
  const result = await api(`/api/vehicles/${state.selected}/secure`, body);
  if (result.status !== 200 && result.data && result.data.error) {
    for (const input of $("estimator-params").querySelectorAll("input")) {
      if (result.data.error.includes(input.name)) input.classList.add("invalid");
    }
  }
  showAck(`secure ${name}`, result);
}

async function applyLibrary() {
  if (state.selected === null) return;
  if ($("library").value === NO_PROFILE) {
    showAck("attack", { status: 422, data: { error: "choose a profile to apply (Clear removes the one in force)" } });
    return;
  }
  const result = await api(`/api/vehicles/${state.selected}/attack`, { profile: $("library").value, params: params() });
  if (result.status === 422 && result.data.field) {
    for (const input of $("params").querySelectorAll("input")) {
      if (result.data.error.includes(input.name)) input.classList.add("invalid");
    }
  }
  showAck(`attack ${$("library").value}`, result);
}

async function applyYaml() {
  if (state.selected === null) return;
  const error = $("yaml-error");
  const result = await api(`/api/vehicles/${state.selected}/attack`, { profile: $("yaml").value });
  const invalid = result.status === 422;
  $("yaml").classList.toggle("invalid", invalid);
  error.hidden = !invalid;
  error.textContent = invalid ? result.data.error : "";   // the error already names the field
  error.dataset.field = invalid && result.data.field ? result.data.field : "";
  showAck("attack (pasted profile)", result);
}

async function post(path, body, what) {
  if (state.selected === null) return;
  showAck(what, await api(`/api/vehicles/${state.selected}/${path}`, body));
}

async function init() {
  const [library, estimators] = await Promise.all([api("/api/library"), api("/api/estimators/params")]);
  state.library = library.data || [];
  state.estimators = Array.isArray(estimators.data) ? estimators.data : [];
  $("library").replaceChildren(new Option("(no profile)", NO_PROFILE), ...state.library.map((p) => new Option(p.name, p.name)));
  $("estimator").replaceChildren(new Option("off", "off"), ...state.estimators.map((e) => new Option(e.name, e.name)));
  $("estimator").addEventListener("change", () => renderEstimatorParams());
  renderEstimatorParams();
  $("library").addEventListener("change", renderParams);
  renderParams();
  $("apply-library").addEventListener("click", applyLibrary);
  $("clear-attack").addEventListener("click", async () => {
    if (state.selected === null) return;
    const result = await api(`/api/vehicles/${state.selected}/attack`, { profile: null });
    if (result.status === 200) {   // nothing in force now: the drop-down says so (the fleet row follows)
      $("library").value = NO_PROFILE;
      state.formsProfile = NO_PROFILE;
      renderParams();
    }
    showAck("attack cleared", result);
  });
  $("apply-yaml").addEventListener("click", applyYaml);
  $("upload").addEventListener("change", async (event) => {
    const file = event.target.files[0];
    if (file) $("yaml").value = await file.text();
  });
  $("mode-on").addEventListener("click", () => post("attack/mode", { mode: "on" }, "attack stage on"));
  $("mode-bypass").addEventListener("click", () => post("attack/mode", { mode: "bypass" }, "attack stage bypass"));
  $("apply-secure").addEventListener("click", applySecure);
  document.querySelector("#fleet tbody").addEventListener("pointerdown", pickRow);
  connect();
  requestAnimationFrame(frame);
}

init();
