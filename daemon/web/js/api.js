// REST client of the operator page: the token (asked once per browser tab, kept in
// sessionStorage), fetch with the bearer header, errors into the message area, downloads that
// carry the token (fetch + blob + object URL: a plain link would get 401).
import { changed, dismiss, showMessage, state } from "./ui.js";

export const API = "/api/v1";
const TOKEN_KEY = "cablecal-token";

export class ApiError extends Error {
  constructor(status, text, body) {
    super(text);
    this.status = status;
    this.body = body;
  }
}

/** Take ``#token=...`` from the URL once (make run prints such a link), then drop it. */
export function tokenFromUrl() {
  const m = /(?:^#|&)token=([^&]+)/.exec(location.hash);
  if (m) {
    sessionStorage.setItem(TOKEN_KEY, decodeURIComponent(m[1]));
    history.replaceState(null, "", location.pathname + location.search);
  }
}

export const getToken = () => sessionStorage.getItem(TOKEN_KEY) || "";

let asking = null;
/** Open the token dialog (once at a time); resolves when a token was entered. */
export function askToken(why) {
  if (asking) return asking;
  const dialog = document.getElementById("token-dialog");
  const input = document.getElementById("token-input");
  if (why) document.getElementById("token-why").textContent = why;
  input.value = "";
  asking = new Promise((resolve) => {
    const form = document.getElementById("token-form");
    let entered = null;
    form.onsubmit = () => { entered = input.value.trim(); };
    // Whatever closes the dialog (Use token, or Escape) ends this ask: the "token" button
    // opens it again, and the page goes on with the token it has (item 11).
    dialog.onclose = () => {
      dialog.onclose = null;
      asking = null;
      if (entered) {
        sessionStorage.setItem(TOKEN_KEY, entered);
        // A new token: polling resumes and the 401 banner goes (a new 401 brings it back).
        state.authRefused = false;
        dismiss("token");
        changed("auth");
      }
      resolve(entered || getToken());
    };
  });
  if (!dialog.open) dialog.showModal();
  return asking;
}

/** The ``detail`` of an error answer as the API gave it (string, {reason, detail}, pydantic
 * list): the technical text behind a message's "details" toggle. */
export function detailText(body) {
  if (body == null) return "";
  if (typeof body === "string") return body;
  const d = body.detail ?? body.error ?? body.message ?? body;
  if (typeof d === "string") return d;
  if (Array.isArray(d)) {
    return d.map((e) => `${(e.loc || []).filter((p) => p !== "body").join(".")}: ${e.msg}`).join("; ");
  }
  if (typeof d === "object") {
    const parts = [];
    if (d.device) parts.push(`${d.device}:`);
    if (d.reason) parts.push(String(d.reason).replaceAll("_", " "));
    if (d.row != null) parts.push(`row ${d.row}`);
    if (d.column) parts.push(`column ${d.column}`);
    if (d.detail) parts.push(`— ${typeof d.detail === "string" ? d.detail : JSON.stringify(d.detail)}`);
    if (d.message) parts.push(d.message);
    return parts.length ? parts.join(" ") : JSON.stringify(d);
  }
  return String(d);
}

//: What the operator was doing, per route (method and path with {id}): the start of the
//: sentence an error of that route gets. Routes not listed: "The page could not update".
const ACTIONS = {
  "POST /campaigns": "The campaign was not created",
  "POST /campaigns/{id}/plan": "The poses were not planned",
  "GET /campaigns/{id}/plan": "The plan could not be downloaded",
  "POST /campaigns/{id}/captures": "No sample was captured",
  "PUT /campaigns/{id}/auto-capture": "Auto capture was not switched",
  "PATCH /samples/{id}": "The sample was not changed",
  "GET /campaigns/{id}/samples": "The samples could not be read",
  "POST /campaigns/{id}/identifications": "The identification did not start",
  "DELETE /identifications/{id}": "The identification was not cancelled",
  "POST /identifications/{id}/accept": "The result was not accepted",
  "GET /identifications/{id}/report.html": "The report could not be downloaded",
  "GET /robots/{id}/calibrated-model": "The calibrated model could not be downloaded",
  "POST /robots/{id}/compensate": "The program was not compensated",
  "POST /robots/{id}/checks": "The hold check did not start",
  "POST /campaigns/{id}/sensor-moved/undo": "The sensor move was not undone",
  "POST /robots/{id}/filter": "The programs were not filtered",
};

//: Request fields in the operator's words (the form's labels), for a 422's location.
const FIELDS = {
  anchors_mm: "the sensor position", n: "the number of poses", min_z_mm: "the lowest flange z",
  seed: "the seed", name: "the name", notes: "the notes", anchor: "the anchor",
  joints_deg: "the joint angles", test_fraction: "the test fraction", method: "the method",
  robot: "the robot name", robot_model: "the robot model", robot_model_file: "the model file",
};

/** A 422 issue's location in words: ``["body", "anchors_mm", 0, 1]`` → "the sensor position
 * (y)"; the first field name the page knows, else the field's own name. */
function fieldWords(loc) {
  const parts = (loc || []).filter((p) => !["body", "query", "path"].includes(p));
  if (!parts.length) return "";
  const name = String(parts[0]);
  const words = FIELDS[name] || name.replaceAll("_", " ");
  if (name === "anchors_mm" && typeof parts[2] === "number") return `${words} ${"xyz"[parts[2]] || ""}`.trim();
  if (name === "joints_deg" && typeof parts[1] === "number") return `J${parts[1] + 1}`;
  return words;
}

/** pydantic's message as the end of a sentence: "must be at most 10000". */
function ruleWords(msg) {
  const m = /^Input should be (less than or equal to|greater than or equal to|less than|greater than) (.+)$/.exec(msg || "");
  if (m) return `must be ${{ "less than or equal to": "at most", "greater than or equal to": "at least", "less than": "below", "greater than": "above" }[m[1]]} ${m[2]}`;
  if (msg === "Field required") return "is missing";
  if (/^Input should be a valid (number|integer)/.test(msg || "")) return "must be a number";
  return (msg || "").replace(/^Value error, /, "");
}

const sentence = (t) => { const s = String(t || "").trim(); return s ? s[0].toUpperCase() + s.slice(1) + (/[.!?]$/.test(s) ? "" : ".") : ""; };

/** The operator's sentence for a failed request: what did not happen, and why in words. */
export function operatorText(what, status, body) {
  const d = body && typeof body === "object" ? body.detail : body;
  let why;
  if (status === 422 && Array.isArray(d) && d.length) {
    const first = d[0];
    const field = fieldWords(first.loc);
    why = `${field ? `${field} ${ruleWords(first.msg)}` : ruleWords(first.msg)}` + (d.length > 1 ? ` (and ${d.length - 1} more problem${d.length > 2 ? "s" : ""})` : "");
  } else if (status === 404) why = `the daemon does not know it (${detailText(body) || "not found"}); reload the page`;
  else if (status === 413) why = "the request is too large for the daemon";
  else if (status >= 500 && status !== 503) why = `the daemon failed (error ${status}); its log says why`;
  else why = d && typeof d === "object" && d.detail ? String(d.detail) : detailText(body);
  return `${what}: ${sentence(why)}`;
}


/** One banner per source: the method and the path with its ids as {id}. */
export const sourceKey = (method, path) => `${method} ${path.split("?")[0].replace(/\/\d+/g, "/{id}")}`;

/**
 * Call the REST API. ``opts``: ``json`` (a body to send as JSON), ``form`` (FormData, sent
 * as multipart/form-data), ``body`` + ``type`` (raw),
 * ``quiet`` (no message on error; the caller handles it), ``raw`` (return the Response),
 * ``what`` (the start of the error sentence, when the route's own one does not fit).
 * Throws ApiError on a non-2xx answer (after putting it in the message area unless quiet):
 * its ``message`` is the operator's sentence, its ``detail`` the API's own text.
 */
export async function api(method, path, opts = {}) {
  const used = getToken();
  const source = sourceKey(method, path);
  const what = opts.what || ACTIONS[source] || "The page could not update";
  const headers = { Authorization: `Bearer ${used}` };
  if (opts.accept) headers.Accept = opts.accept;
  let body;
  if (opts.form !== undefined) {
    body = opts.form; // FormData: the browser sets the multipart boundary
  } else if (opts.json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(opts.json);
  } else if (opts.body !== undefined) {
    headers["Content-Type"] = opts.type || "text/plain";
    body = opts.body;
  }
  let response;
  try {
    response = await fetch(API + path, { method, headers, body });
  } catch (exc) {
    const err = new ApiError(0, "The daemon does not answer. Check that it is running and that this PC reaches it.");
    err.detail = `${method} ${API}${path}: ${exc.message}`;
    if (!opts.quiet) showMessage("error", err.message, "offline", err.detail);
    throw err;
  }
  dismiss("offline");
  if (response.status === 401) {
    const err = new ApiError(401, "The daemon refused the access token. Enter the access token again.");
    // Only for the token in use: answers to requests sent with an older token change nothing.
    if (used === getToken()) {
      showMessage("error", "The daemon refused the access token: updates are paused until the right token is entered (button “token” at the top).", "token", "401 Unauthorized");
      if (!state.authRefused) { state.authRefused = true; changed("auth"); }
      askToken("The token was refused (401). Enter the token printed by make run / cablecal serve.");
    }
    throw err;
  }
  if (!response.ok) {
    const text = await response.text();
    let parsed = text;
    try { parsed = JSON.parse(text); } catch { /* plain text */ }
    const err = new ApiError(response.status, operatorText(what, response.status, parsed), parsed);
    err.detail = `${method} ${API}${path} — ${response.status}: ${detailText(parsed) || response.statusText}`;
    if (!opts.quiet) showMessage("error", err.message, source, err.detail);
    throw err;
  }
  dismiss(source); // the same action succeeded: its old error is no longer true
  if (opts.raw) return response;
  if (response.status === 204) return null;
  const type = response.headers.get("Content-Type") || "";
  return type.includes("json") ? response.json() : response.text();
}

/** Save a file fetched with the token (``fetch`` + blob + object URL). */
export async function download(path, filename) {
  const response = await api("GET", path, { raw: true });
  saveBlob(await response.blob(), filename);
}

/** Offer ``blob`` as a download named ``filename``. */
export function saveBlob(blob, filename) {
  const url = URL.createObjectURL(blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}
