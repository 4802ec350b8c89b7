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
    form.onsubmit = () => {
      const value = input.value.trim();
      if (value) sessionStorage.setItem(TOKEN_KEY, value);
      asking = null;
      // A new token: polling resumes and the 401 banner goes (a new 401 brings it back).
      if (value) { state.authRefused = false; dismiss("token"); changed("auth"); }
      resolve(value);
    };
  });
  if (!dialog.open) dialog.showModal();
  return asking;
}

/** The ``detail`` of an error answer in words (string, {reason, detail}, pydantic list). */
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

/**
 * Call the REST API. ``opts``: ``json`` (a body to send as JSON), ``form`` (FormData, sent
 * as multipart/form-data), ``body`` + ``type`` (raw),
 * ``quiet`` (no message on error; the caller handles it), ``raw`` (return the Response).
 * Throws ApiError on a non-2xx answer (after putting it in the message area unless quiet).
 */
/** One banner per source: the method and the path with its ids as {id}. */
export const sourceKey = (method, path) => `${method} ${path.split("?")[0].replace(/\/\d+/g, "/{id}")}`;

export async function api(method, path, opts = {}) {
  const used = getToken();
  const source = sourceKey(method, path);
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
    const err = new ApiError(0, `${method} ${path}: the daemon does not answer (${exc.message})`);
    if (!opts.quiet) showMessage("error", err.message, "offline");
    throw err;
  }
  dismiss("offline");
  if (response.status === 401) {
    const err = new ApiError(401, "401: the daemon refused the token. Enter the access token again.");
    // Only for the token in use: answers to requests sent with an older token change nothing.
    if (used === getToken()) {
      showMessage("error", "The daemon refused the access token (401): updates are paused until the right token is entered (button “token” at the top).", "token");
      if (!state.authRefused) { state.authRefused = true; changed("auth"); }
      askToken("The token was refused (401). Enter the token printed by make run / cablecal serve.");
    }
    throw err;
  }
  if (!response.ok) {
    const text = await response.text();
    let parsed = text;
    try { parsed = JSON.parse(text); } catch { /* plain text */ }
    const err = new ApiError(response.status, `${response.status}: ${detailText(parsed) || response.statusText}`, parsed);
    if (!opts.quiet) showMessage("error", `${method} ${path} — ${err.message}`, source);
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
