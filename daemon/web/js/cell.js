// View 1, Cell: the live cable-length trace (last 60 s, polled at 5 Hz), joint readings,
// devices and the sampler in words, device errors kept until dismissed.
import { api } from "./api.js";
import { traceChart } from "./charts.js";
import { $, age, changed, clock, el, every, fillTable, fix, onChange, setText, state } from "./ui.js";

const WINDOW_S = 60;
const TRACE_MS = 150; // about 6.7 Hz nominal: at least 5 Hz on a busy cell PC
const STATUS_MS = 1000;
const STALE_FIGURE_S = 1.0; // a length reading older than this [s] is shown as old

const trace = { t: [], length: [], last: 0, offset: 0, plot: null, updates: 0, readings: 0 };
/** Counters the bench reads (bench/web_bench.py): chart updates and readings received. */
window.__cablecal = { trace };

const SETTLE_WORDS = {
  settled: "The robot is still and the cable length is steady: ready to capture.",
  moving: "The robot or the cable is moving.",
  stale: "The readings are late (a device is slow or down).",
  over_range: "The indicator is over range (cable outside the sensor's stroke).",
  no_data: "No readings yet.",
  frozen: "NOT ready: the robot controller's joint angles stopped changing while the cable moved, so a sample would pair the wrong pose with the length. No sample is taken until the controller reports new joints.",
};

/** The sampler's readiness in words (``settle_state`` of GET /status), one home for views. */
export function readinessWords(sampler) {
  const key = sampler?.settle_state;
  return SETTLE_WORDS[key] || `Not settled: ${String(key).replaceAll("_", " ")}.`;
}

export function isManualRobot() {
  return state.status?.devices?.robot?.driver === "ManualRobot";
}

async function pollTrace() {
  const r = await api("GET", `/readings?since_wall_s=${trace.last}&limit=2000`, { quiet: true });
  const nowLocal = Date.now() / 1000;
  trace.offset = r.now_wall_s - nowLocal;
  for (let i = 0; i < r.t_wall_s.length; i++) {
    trace.t.push(r.t_wall_s[i]);
    trace.length.push(r.length_mm[i]);
  }
  trace.readings += r.t_wall_s.length;
  if (r.t_wall_s.length) trace.last = r.t_wall_s[r.t_wall_s.length - 1];
  const horizon = r.now_wall_s - WINDOW_S;
  let drop = 0;
  while (drop < trace.t.length && trace.t[drop] < horizon) drop++;
  if (drop) { trace.t.splice(0, drop); trace.length.splice(0, drop); }
  const x = trace.t.map((t) => t - r.now_wall_s);
  trace.plot ||= traceChart($("trace"));
  trace.plot.setData([x, trace.length.slice()]);
  trace.updates += 1;
  const lastL = trace.length[trace.length.length - 1];
  setText("cell-length", lastL == null ? "over range" : fix(lastL, 3));
}

function rateText() {
  let prev = { updates: trace.updates, readings: trace.readings, at: performance.now() };
  setInterval(() => {
    const dt = (performance.now() - prev.at) / 1000;
    const hz = (trace.updates - prev.updates) / dt;
    const rps = (trace.readings - prev.readings) / dt;
    prev = { updates: trace.updates, readings: trace.readings, at: performance.now() };
    if (!document.hidden && state.view === "cell") {
      setText("trace-rate", `Chart updates ${hz.toFixed(1)} per s; ${rps.toFixed(0)} paired readings per s; ${trace.t.length} points shown.`);
    }
  }, 2000);
}

/** The sampler's settle detail without its configuration keys (item 21): "gap of 0.62 s
 * between readings (stale_s)" → "... (longer than the sampler allows)". */
export function detailWords(detail) {
  return String(detail || "")
    .replace(/ \(stale_s\)/g, " (longer than the sampler allows: a device answers late)")
    .replace(/fewer than min_readings (\d+)/g, "fewer than the $1 a still pose needs");
}

function samplerWords(s) {
  if (!s) return ["The sampler is not running.", ""];
  let mode;
  if (s.mode === "auto") {
    mode = `Auto capture is ON for campaign #${s.auto_campaign_id} (anchor ${s.auto_anchor}): one sample at each new still pose; ${s.auto_known_poses} poses already in the campaign.`;
  } else {
    mode = "Manual mode: a sample is taken when you press Capture (tab 2).";
  }
  const settle = readinessWords(s);
  return [`${mode} ${settle}`, s.settled ? "" : detailWords(s.settle_detail)];
}

// What each counted error class means on the floor, and what to do about it.
const ERROR_WORDS = {
  IndicatorOverRange: "over range: the indicator reads beyond the sensor's range (cable pulled past its end, or hanging slack below zero). Move the robot back inside the cable's reach and check the hook; readings during over-range are discarded, never stored",
  IndicatorNoReply: "no reply: the indicator did not answer. Check its power, the RS-485 wiring and the Modbus address",
  IndicatorTimeout: "timeout: an incomplete answer. Check the RS-485 wiring and termination, and the baud rate",
  IndicatorCRCError: "CRC errors: a garbled answer, discarded. Check the cable shield and termination; a few per hour are harmless",
  IndicatorProtocolError: "protocol errors: an answer the driver cannot decode. Check the indicator's mode and register map",
  IndicatorLinkDown: "link down: the serial port is gone. Check the USB-RS485 adapter",
  RobotLinkDown: "link down: the controller connection was lost. Check the network cable and the controller",
  RobotTimeout: "timeout: the controller answered late",
  RobotProtocolError: "protocol errors: the controller answered with an error code",
};

function errorsExplained(devices) {
  const parts = [];
  for (const d of Object.values(devices)) {
    for (const [cls, n] of Object.entries(d.errors_by_class || {})) {
      if (n) parts.push(`${d.name}: ${n} × ${ERROR_WORDS[cls] || cls}.`);
    }
  }
  return parts.length
    ? `The errors column counts failed polls since the daemon started, by kind — ${parts.join(" ")}`
    : "The errors column counts failed polls since the daemon started (none so far).";
}

function renderDevices(devices) {
  const rows = Object.values(devices).map((d) => {
    const reading = d.last_reading;
    let value = "–";
    if (reading) {
      value = Array.isArray(reading.value) ? "6 joints (see above)" : `${fix(reading.value, 3)} mm`;
      if (reading.over_range) value = "over range";
    } else if (d.waiting_for) {
      value = `waiting for ${d.waiting_for}`;
    }
    const stateWords = d.state === "ok" ? "connected"
      : d.state === "late" ? `late: no reply for ${age(d.late_age_s)}` : d.state;
    const stateCell = el("span", { class: d.state === "ok" ? "ok" : "bad" }, stateWords);
    return [d.name, d.role, d.driver, stateCell, value, reading ? age(reading.age_s) : "–",
      fix(d.poll_rate_hz, 1), String(d.polls),
      el("span", { title: Object.entries(d.errors_by_class || {}).map(([c, n]) => `${c}: ${n}`).join(", ") }, String(d.errors))];
  });
  fillTable($("cell-devices"), [
    { label: "device" }, { label: "role" }, { label: "driver" }, { label: "state" },
    { label: "last reading" }, { label: "age", num: true }, { label: "poll rate [Hz]", num: true },
    { label: "polls", num: true }, { label: "errors", num: true },
  ], rows);
  setText("cell-errors-note", errorsExplained(devices));
}

function renderJoints(robot) {
  const q = robot?.last_reading?.value;
  const rows = [0, 1, 2, 3, 4, 5].map((j) => [`J${j + 1}`, el("span", { class: "num" }, Array.isArray(q) ? `${fix(q[j], 3)} deg` : "–")]);
  fillTable($("cell-joints"), [{ label: "joint" }, { label: "angle" }], rows, Array.isArray(q) ? q.join() : "none");
  $("cell-joints").querySelector("thead").hidden = true;
  setText("cell-joints-note", isManualRobot()
    ? "Manual robot: the angles are typed in at each capture (tab 2)."
    : robot?.last_reading ? `Read ${age(robot.last_reading.age_s)} ago.` : "No joint reading yet.");
}

// Device errors: one entry per device and kind (the newest message), kept until dismissed.
// An error of a device that works again is marked as earlier, with its age (item 21).
const deviceErrors = new Map();

/** A device error's message for the operator: no temporary folder (an emulated cell's
 * socket path), no reconnect countdown. */
export function errorText(message) {
  return String(message || "")
    .replace(/(?:\/var)?\/tmp\/[^\s'",:;)]*\/([^\s'",:;)/]+)/g, "…/$1")
    .replace(/;? ?next reconnect in [0-9.]+ s/, "");
}

function collectErrors(devices) {
  for (const d of Object.values(devices)) {
    const e = d.last_error;
    if (!e || e.t_wall == null) continue;
    const key = `${d.name}|${e.class}`;
    if (dismissedBefore(key, e.t_wall)) continue;
    const known = deviceErrors.get(key);
    if (known) {
      if (known.t_wall !== e.t_wall) Object.assign(known, { t_wall: e.t_wall, message: e.message, frames: e.frames_hex, count: known.count + 1 });
      continue;
    }
    deviceErrors.set(key, { device: d.name, ...e, frames: e.frames_hex, count: 1 });
  }
  renderErrors(devices);
}

const dismissedAt = new Map();
const dismissedBefore = (key, t) => dismissedAt.has(key) && t <= dismissedAt.get(key);

function renderErrors(devices) {
  const box = $("device-errors");
  const now = Date.now() / 1000 + trace.offset;
  const list = [...deviceErrors.entries()].map(([key, e]) => ({ key, e, current: devices?.[e.device]?.state !== "ok" }))
    .sort((a, b) => Number(b.current) - Number(a.current) || b.e.t_wall - a.e.t_wall);
  const shown = JSON.stringify(list.map(({ key, e, current }) => [key, current, e.count, e.message, current ? 0 : Math.round((now - e.t_wall) / 30)]));
  $("device-errors-card").hidden = deviceErrors.size === 0;
  if (box.dataset.key === shown) return;
  box.dataset.key = shown;
  box.replaceChildren(...list.map(({ key, e, current }) => el("div", { class: `device-error${current ? "" : " past"}` },
    el("div", { class: "row" },
      el("b", {}, `${e.device}: ${(ERROR_WORDS[e.class] || e.class).split(":")[0]}`),
      el("span", { class: current ? "bad" : "muted" }, current
        ? `now: the ${e.device} is not working${e.count > 1 ? ` (${e.count} errors)` : ""}`
        : `earlier: last at ${clock(e.t_wall)}, ${age(Math.max(0, now - e.t_wall))} ago${e.count > 1 ? `, ${e.count} times` : ""}; the ${e.device} works again`),
      el("button", { class: "secondary small", "aria-label": `Dismiss the ${e.device} error`, onclick: () => { dismissedAt.set(key, e.t_wall); deviceErrors.delete(key); renderErrors(state.status?.devices); } }, "Dismiss")),
    el("div", {}, errorText(e.message)),
    e.frames?.length ? el("details", {}, el("summary", {}, "last frames (hex), for a technician"),
      el("pre", {}, e.frames.map(errorText).join("\n"))) : null)));
}

async function pollStatus() {
  const s = await api("GET", "/status");
  state.status = s;
  const devices = s.devices || {};
  const down = Object.values(devices).filter((d) => d.state !== "ok");
  const pill = $("top-devices");
  // a frozen controller answers, yet is not ready: the header says so on every view (item 2)
  const frozen = s.sampler?.settle_state === "frozen";
  // an indicator over range answers, yet reads nothing usable: not green (item 19)
  const over = Object.values(devices).find((d) => d.last_reading?.over_range);
  pill.className = `pill ${down.length || frozen ? "bad" : over ? "warn" : "ok"}`;
  setText(pill, down.length ? `${down.map((d) => d.name).join(", ")}: ${down[0].state}`
    : frozen ? `${devices.robot?.name ?? "robot"}: joints frozen, no capture`
      : over ? `${over.name}: over range, no capture` : "devices connected");
  renderHoldCheckPill(s.hold_check);
  renderLengthAge(devices);
  changed("status");
  collectErrors(devices);
  if (state.view !== "cell") return;
  renderDevices(devices);
  renderJoints(devices.robot);
  const [words, detail] = samplerWords(s.sampler);
  setText("cell-sampler", words);
  $("cell-sampler").classList.toggle("bad", s.sampler?.settle_state === "frozen");
  setText("cell-sampler-detail", detail);
}

/** The big length figure is marked as old while the indicator gives no new reading (a
 * link-down): the last value stays, greyed, with its age (item 27). */
function renderLengthAge(devices) {
  const ind = Object.values(devices).find((d) => d.role === "indicator");
  const ageS = ind?.last_reading?.age_s;
  const stale = !!ind && (ind.state !== "ok" || !(ageS <= STALE_FIGURE_S));
  $("cell-length").classList.toggle("stale", stale);
  setText("cell-length-stale", stale ? `old: no new reading for ${age(ageS)} (indicator ${ind.state})` : "");
}

/** The header's hold-check state (item 22): hidden while the last check is OK or absent. */
function renderHoldCheckPill(hold) {
  const pill = $("top-hold-check");
  const bad = hold && (hold.state === "not_held" || hold.state === "failed");
  pill.hidden = !bad;
  if (!bad) return;
  const kind = hold.state === "failed" ? "hold check failed" : { sensor: "sensor moved", robot: "robot changed" }[hold.cause?.kind] || "calibration not held";
  setText(pill, `${kind} (check #${hold.check_id}, tab 4)`);
}

export function initCell() {
  onChange((kind) => {
    if (kind !== "auth") return;
    const pill = $("top-devices");
    if (state.authRefused) {
      pill.className = "pill muted";
      setText(pill, "device state unknown: token refused");
    } else {
      // A token accepted: the pill is brought up to date now, not at the next status tick.
      pollStatus().catch(() => {});
    }
  });
  $("device-errors-clear").addEventListener("click", () => {
    for (const [key, e] of deviceErrors) dismissedAt.set(key, e.t_wall);
    deviceErrors.clear();
    renderErrors(state.status?.devices);
  });
  every(STATUS_MS, pollStatus);
  every(TRACE_MS, pollTrace, () => state.view === "cell");
  rateText();
}
