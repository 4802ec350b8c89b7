// Small DOM helpers, number formats, the message area and the page's shared state.

export const $ = (id) => document.getElementById(id);

/** Element ``tag`` with attributes/properties ``props`` and children (strings or nodes). */
export function el(tag, props = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(props)) {
    if (v == null || v === false) continue;
    if (k === "class") node.className = v;
    else if (k === "dataset") Object.assign(node.dataset, v);
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else if (k in node && typeof v !== "string") node[k] = v;
    else node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) {
    if (c != null && c !== false) node.append(c instanceof Node ? c : String(c));
  }
  return node;
}

/** Set a node's text only when it changed (no layout work on every poll). */
export function setText(node, text) {
  if (typeof node === "string") node = $(node);
  if (node.textContent !== text) node.textContent = text;
}

/** ``x`` with ``digits`` decimals, "–" when not a finite number. */
export function fix(x, digits) {
  return typeof x === "number" && Number.isFinite(x) ? x.toFixed(digits) : "–";
}

/** A duration ``x`` [s] as a person reads it: "35 ms" below a second, else "2.4 s"; "–" when
 * not finite. */
export function duration(x) {
  if (typeof x !== "number" || !Number.isFinite(x)) return "–";
  return x < 1 ? `${Math.max(1, Math.round(1000 * x))} ms` : `${x.toFixed(1)} s`;
}

/** ``x`` to ``n`` significant digits (no 18-digit floats), "–" when not finite. */
export function sig(x, n = 3) {
  if (typeof x !== "number" || !Number.isFinite(x)) return "–";
  if (x === 0) return "0";
  const a = Math.abs(x);
  if (a >= 1e5 || a < 1e-3) return x.toExponential(n - 1);
  return x.toPrecision(n).replace(/(\.\d*?)0+$/, "$1").replace(/\.$/, "");
}

/** A duration [s] in words: "850 ms", "12.3 s", "4 min". */
export function age(s) {
  if (typeof s !== "number" || !Number.isFinite(s)) return "–";
  if (s < 1) return `${Math.round(s * 1000)} ms`;
  if (s < 120) return `${s.toFixed(1)} s`;
  if (s < 7200) return `${Math.round(s / 60)} min`;
  return `${Math.round(s / 3600)} h`;
}

/** A Unix time [s] as local "HH:MM:SS" (with the date when not today). */
export function clock(t) {
  if (typeof t !== "number") return "–";
  const d = new Date(t * 1000);
  const time = d.toLocaleTimeString([], { hour12: false });
  return d.toDateString() === new Date().toDateString() ? time : `${d.toLocaleDateString()} ${time}`;
}

/**
 * Fill ``table`` with a header and rows. ``columns``: [{label, num}], ``rows``: arrays of
 * cells (string, number or node) or {cells, class, onclick}. Skips the work when ``key`` is
 * the same as last time.
 */
export function fillTable(table, columns, rows, key) {
  if (key !== undefined && table.dataset.key === key) return;
  if (key !== undefined) table.dataset.key = key;
  const head = el("thead", {}, el("tr", {}, columns.map((c) => el("th", { class: [c.num ? "num" : "", c.class || ""].join(" ").trim() }, c.label))));
  // A row that can be selected (it has an onclick) is a row of a grid: focusable, Enter or
  // Space selects it, and the selected one says so (aria-selected), for the keyboard and a
  // screen reader as for the mouse.
  const selectable = rows.some((r) => !Array.isArray(r) && r.onclick);
  const body = el("tbody", {}, rows.map((r) => {
    const spec = Array.isArray(r) ? { cells: r } : r;
    const attrs = { class: spec.class, onclick: spec.onclick, dataset: spec.dataset };
    if (spec.onclick) {
      Object.assign(attrs, { tabindex: "0", "aria-selected": String(/\bselected\b/.test(spec.class || "")),
        onkeydown: (ev) => { if (ev.target === ev.currentTarget && (ev.key === "Enter" || ev.key === " ")) { ev.preventDefault(); spec.onclick(ev); } } });
    }
    return el("tr", attrs,
      spec.cells.map((cell, i) => el("td", { class: [columns[i]?.num ? "num" : "", columns[i]?.class || ""].join(" ").trim(), "data-label": columns[i]?.label }, cell)));
  }));
  if (selectable) table.setAttribute("role", "grid"); else table.removeAttribute("role");
  // A redraw keeps the keyboard where it was: the row with the same first cell gets the focus.
  const focused = document.activeElement;
  const focusKey = focused?.tagName === "TR" && table.contains(focused) ? focused.cells[0]?.textContent : null;
  table.replaceChildren(head, body);
  if (focusKey != null) [...body.rows].find((tr) => tr.cells[0]?.textContent === focusKey)?.focus();
}

// ------------------------------------------------------------------ messages
const messages = new Map(); // key -> {node, count}

/**
 * Show a message (kind: error, warn, info) with its time; it stays until dismissed or until
 * its owner (the code that showed it, under ``key``) clears it when its cause is gone. The
 * same text (or ``key``) again updates the time and a repeat count instead of stacking.
 * ``detail``: the technical text behind it (the API's answer), shown behind a "details"
 * toggle, never as the headline.
 */
export function showMessage(kind, text, key, detail) {
  const k = key || `${kind}:${text}`;
  const now = new Date().toLocaleTimeString([], { hour12: false });
  const known = messages.get(k);
  if (known) {
    known.count += 1;
    known.node.className = `message ${kind}`;
    known.node.querySelector("time").textContent = `${now} (×${known.count})`;
    known.node.querySelector(".text").replaceChildren(...messageBody(text, detail));
    return;
  }
  const node = el("div", { class: `message ${kind}`, role: kind === "error" ? "alert" : "status", dataset: { key: k } },
    el("time", {}, now),
    el("div", { class: "text" }, ...messageBody(text, detail)),
    el("button", { class: "dismiss", title: "Dismiss", "aria-label": "Dismiss", onclick: () => dismiss(k) }, "×"));
  messages.set(k, { node, count: 1 });
  $("messages").append(node);
  if (kind === "info") {
    setTimeout(() => { if (messages.get(k)?.node === node) dismiss(k); }, INFO_MS);
  }
}

function messageBody(text, detail) {
  const head = el("span", { class: "headline" }, text);
  return detail ? [head, el("details", {}, el("summary", {}, "details"), el("code", {}, detail))] : [head];
}

/** An error of the page itself (a bug, not the daemon's answer): one banner, the JS error
 * behind "details". */
export function pageError(exc) {
  showMessage("error", "The page hit an internal error; reload it. If it comes back, report it with the details.", "page", String(exc?.message || exc));
}

/** Info messages go by themselves after this long [ms]: they report a done action. */
const INFO_MS = 20000;

/** Remove the message of ``key`` (or of ``kind:text``). */
export function dismiss(key) {
  const m = messages.get(key);
  if (m) {
    m.node.remove();
    messages.delete(key);
  }
}

// ------------------------------------------------------------------ shared state
/** What the views share: the selected campaign, its robot, the latest /status. */
export const state = {
  campaign: null, // the campaign row
  status: null, // the latest GET /status
  listeners: [],
  view: "cell",
  routes: new Set(), // "METHOD /path/{}" of every route in /openapi.json
  authRefused: false, // the daemon refused the token (401): polling pauses until a new one
  downloadFormats: [], // the plan's download formats (csv, robot programs): the REST enum
  schemas: {}, // components.schemas of /openapi.json (request bounds)
};

const norm = (path) => path.replace(/\{[^}]*\}/g, "{}");

/** Load the daemon's routes from /openapi.json (open), so views of routes this daemon does
 * not have say so instead of calling them. */
export async function loadRoutes() {
  const r = await fetch("/openapi.json");
  const spec = await r.json();
  for (const [path, ops] of Object.entries(spec.paths || {})) {
    for (const method of Object.keys(ops)) state.routes.add(`${method.toUpperCase()} ${norm(path)}`);
  }
  state.downloadFormats = spec.components?.schemas?.DownloadFormat?.enum || [];
  state.schemas = spec.components?.schemas || {};
}

/** The JSON schema of request body ``name`` in /openapi.json (its fields' bounds), or null. */
export const requestSchema = (name) => state.schemas?.[name] || null;

/** True when the daemon has route ``method path`` (path under /api/v1, ids as {name}). */
export const hasRoute = (method, path) => state.routes.has(`${method} ${norm(`/api/v1${path}`)}`);

/** Call ``fn(kind)`` on every ``changed(kind)``. */
export function onChange(fn) {
  state.listeners.push(fn);
}

export function changed(kind) {
  for (const fn of state.listeners) {
    try { fn(kind); } catch (exc) { pageError(exc); }
  }
}

/** Run ``fn`` now and then every ``ms`` while ``active()`` and the tab is visible (errors go to
 * the message area). The next run is timed from the start of this one, so a slow answer
 * shortens the pause instead of skipping a beat; never two runs at once. */
export function every(ms, fn, active = () => true) {
  const tick = async () => {
    const t0 = performance.now();
    if (active() && !document.hidden && !state.authRefused) {
      try { await fn(); } catch (exc) { if (!exc.status && exc.status !== 0) pageError(exc); }
    }
    setTimeout(tick, Math.max(0, ms - (performance.now() - t0)));
  };
  tick();
}
