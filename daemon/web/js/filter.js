// View 4, Apply: filter the plant's robot programs with the robot's accepted calibration.
// The robot and its calibration are named before the drop; the dropped files are checked on
// the page first (two files of one name, a Fanuc frames .toml among them); a dry run then
// gives per file what happened and the left targets' reasons grouped with counts and the
// next step; the download is exactly what the dry run showed (the API refuses otherwise).
import { api, saveBlob } from "./api.js";
import { $, dismiss, el, fillTable, fix, hasRoute, setText, showMessage, state } from "./ui.js";

/** One filter request's files: ``label`` (the dropped folder, "" for loose files), the
 * program ``files`` and the Fanuc ``frames`` file (or null). */
let sets = [];
/** Per set, the shown dry run (its calibration_id and digest go with the download). */
let previews = [];
/** The frames file chosen with the frames picker (for every set without its own). */
let pickedFrames = null;
/** Per-file answers of the page itself (two files of one name): {file, why}. */
let refused = [];

const FRAMES_EXT = /\.toml$/i;
const CONFIG_DAT = "$config.dat";

function filterForm(set) {
  const form = new FormData();
  for (const f of set.files) form.append("files", f, f.name);
  const frames = set.frames || pickedFrames;
  if (frames) form.append("frames", frames, frames.name);
  return form;
}

function filterQuery(preview) {
  const q = [];
  if (!preview) q.push("dry_run=true");
  if ($("filter-keep-joints").checked) q.push("keep_joint_targets=true");
  // the download must be what the preview showed: the API refuses (409) otherwise
  if (preview) q.push(`calibration_id=${preview.calibration_id}`, `digest=${preview.digest}`);
  return q.length ? `?${q.join("&")}` : "";
}

/** Whose programs these are, said before the drop: the robot (its own name and model) and
 * its current calibration (identification id and date), from GET /robots/{id}/calibrated-model. */
export async function renderFilterTarget() {
  const c = state.campaign;
  if (!c) { setText("filter-target", "Select the campaign of the robot first (tab 2)."); return; }
  try {
    const m = await api("GET", `/robots/${c.robot_id}/calibrated-model`, { quiet: true });
    setText("filter-target", `Programs of robot ${c.robot_name} (model ${c.robot_model_name}), corrected with its current calibration: identification #${m.job_id} of ${new Date(m.created_at * 1000).toLocaleString()}.`);
  } catch (exc) {
    if (exc.status !== 404) throw exc;
    setText("filter-target", `Robot ${c.robot_name} (model ${c.robot_model_name}) has no accepted calibration yet: accept one in tab 3 before filtering its programs.`);
  }
}

/** A left target's reason in the operator's words, with the next step. ``reason`` is the
 * API's group (``left_by_reason``'s key: "status: reason", line numbers taken out). */
export function reasonWords(reason) {
  const r = String(reason || "").replace(/^(skipped|left|unused|failed): /, "");
  if (/keep-joint-targets|keep_joint_targets/.test(r)) return "joint targets kept: points taught on the robot stay as taught (untick “Keep joint targets” to correct them too)";
  if (/^ambiguous/.test(r)) return "several arm configurations reach the target and the program gives none: give the target its configuration, then filter again";
  if (/not in --frames/.test(r)) {
    const which = [...r.matchAll(/(UF|UT) (\d+) is not in --frames/g)].map((m) => `${m[1] === "UF" ? "user frame" : "tool"} ${m[2]}`);
    return `${which.join(" and ")} not in the frames file: add ${which.length > 1 ? "them" : "it"} (the controller's values, [uframe.N] / [utool.N]) to the frames .toml and drop it with the programs`;
  }
  if (/read only: \$config\.dat/i.test(r) || /\$config\.dat \(its XHOME/.test(r)) return "in $config.dat, the controller's own file: read for its tools and bases, never written (XHOME stays as taught)";
  if (/^not used by any move/.test(r)) return "not used by any move of the given files: drop the programs that use it together with it";
  return r.replaceAll("--frames", "the frames file");
}

/** The files of a drop: a folder's files with their folder (``path``), loose files without. */
async function droppedFiles(dt) {
  const entries = [...(dt.items || [])].map((i) => i.webkitGetAsEntry?.()).filter(Boolean);
  if (!entries.some((e) => e.isDirectory)) return [...dt.files].map((file) => ({ file, top: "" }));
  const out = [];
  const walk = async (entry, top) => {
    if (entry.isFile) {
      out.push({ file: await new Promise((ok, ko) => entry.file(ok, ko)), top });
      return;
    }
    const reader = entry.createReader();
    for (;;) {
      const batch = await new Promise((ok, ko) => reader.readEntries(ok, ko));
      if (!batch.length) break;
      for (const e of batch) await walk(e, top);
    }
  };
  for (const e of entries) await walk(e, e.isDirectory ? e.name : "");
  return out;
}

const sizeWords = (f) => `${f.size.toLocaleString()} bytes${f.lastModified ? `, modified ${new Date(f.lastModified).toLocaleString()}` : ""}`;

/** Group the dropped files into filter requests: one per dropped folder (a controller backup
 * keeps its own $config.dat and frames), loose files together. Within a set a name given
 * twice is answered on the page, naming both files; a .toml is the set's frames file. */
function makeSets(items) {
  const byTop = new Map();
  for (const { file, top } of items) {
    if (!byTop.has(top)) byTop.set(top, []);
    byTop.get(top).push(file);
  }
  const out = [];
  const answers = [];
  for (const [label, files] of byTop) {
    const where = (f) => (label ? `${label}/${f.name}` : f.name);
    const tomls = files.filter((f) => FRAMES_EXT.test(f.name));
    const programs = files.filter((f) => !FRAMES_EXT.test(f.name));
    const byName = new Map();
    for (const f of programs) {
      const k = f.name.toLowerCase();
      byName.set(k, [...(byName.get(k) || []), f]);
    }
    const kept = [];
    for (const same of byName.values()) {
      if (same.length === 1) { kept.push(same[0]); continue; }
      const both = same.map((f) => `${f.name} (${sizeWords(f)})`).join(" and ");
      const why = same[0].name.toLowerCase() === CONFIG_DAT
        ? `two controller backups? ${both} were dropped together, and each backup's $config.dat belongs to its own programs. Drop each backup's folder (each is filtered with its own $config.dat), or one backup's files at a time`
        : `two files of this name: ${both}. Drop one of them (or each in its own folder)`;
      for (const f of same) answers.push({ file: where(f), why });
    }
    if (tomls.length > 1) {
      for (const f of tomls) answers.push({ file: where(f), why: `one frames file per drop: ${tomls.map((t) => t.name).join(" and ")} were given; drop the one of this robot` });
    }
    if (kept.length) out.push({ label, files: kept, frames: tomls.length === 1 ? tomls[0] : null });
    else if (tomls.length === 1 && !pickedFrames) pickedFrames = tomls[0]; // frames dropped alone
  }
  return { sets: out, answers };
}

function clearResult() {
  $("filter-download").hidden = true;
  for (const b of $("filter-downloads").querySelectorAll("button.per-set")) b.remove();
  previews = [];
  fillTable($("filter-files-result"), [], []);
  fillTable($("filter-result"), [], []);
  $("filter-reasons").replaceChildren();
  $("filter-details").hidden = true;
  $("filter-warnings").hidden = true;
  setText("filter-warnings", "");
}

/** The per-file answers of a failed request: a 422 names each file (``loc`` body.files.NAME)
 * or the frames part; anything else is one line for the whole set. */
function failureRows(set, exc) {
  const d = exc.body?.detail;
  const prefix = set.label ? `${set.label}/` : "";
  if (exc.status === 422 && Array.isArray(d)) {
    return d.map((e) => {
      const loc = (e.loc || []).filter((p) => p !== "body");
      const name = loc[0] === "frames" ? (set.frames || pickedFrames)?.name || "frames" : typeof loc[1] === "string" ? loc[1] : loc[0] === "files" && typeof loc[1] === "number" ? set.files[loc[1]]?.name : null;
      const why = String(e.msg || "").replace(/^files\[\d+\]: /, "").replace(new RegExp(`^${(name || "").replace(/[.*+?^${}()|[\]\\$]/g, "\\$&")}(:\\d+)?: `), "");
      return { file: name ? prefix + name : `${prefix}(all files)`, why: loc[0] === "frames" ? `frames file: ${why.replace(/^frames: /, "")}` : why };
    });
  }
  return [{ file: `${prefix}(all files)`, why: exc.status === 409 ? `robot ${state.campaign.robot_name} has no accepted calibration yet (accept one in tab 3)` : exc.message }];
}

const isKept = (r) => /keep-joint-targets|keep_joint_targets/.test(r.reason || "");

/** Filter the chosen files with a dry run per set: per file what happened, the reasons
 * grouped with counts, every target below; a download per set fetches exactly that.
 * ``items``: [{file, top}] (``top``: the dropped folder, "" for a loose file); exported for
 * the folder-drop walk (a browser test cannot drop a folder). */
export async function filterPrograms(items) {
  const c = state.campaign;
  if (!hasRoute("POST", "/robots/{}/filter")) {
    showMessage("error", "Filter: this daemon has no filter route (POST /robots/{id}/filter).");
    return;
  }
  if (!c) { showMessage("error", "Filter: select the campaign of the robot first (tab 2)."); return; }
  if (!items.length) return;
  const made = makeSets(items);
  // a frames file dropped alone applies to the files dropped before
  if (made.sets.length || made.answers.length || !sets.length) ({ sets, answers: refused } = made);
  renderFrames();
  await runFilter();
}

let runs = 0; // the latest run renders; an older one still answering is dropped

async function runFilter() {
  const c = state.campaign;
  const run = ++runs;
  clearResult();
  const failed = [...refused];
  const shown = [];
  setText("filter-state", `Filtering ${sets.reduce((n, s) => n + s.files.length, 0)} file(s) for robot ${c.robot_name} …`);
  for (const set of sets) {
    try {
      const summary = await api("POST", `/robots/${c.robot_id}/filter${filterQuery(null)}`, { form: filterForm(set), quiet: true });
      shown.push({ set, summary });
    } catch (exc) {
      if (exc.status === 401) throw exc;
      failed.push(...failureRows(set, exc));
    }
    if (run !== runs) return;
  }
  previews = shown;
  dismiss("filter");
  renderResult(failed);
}

function renderResult(failed) {
  const c = state.campaign;
  const rows = [];
  const perFile = [];
  const groups = new Map();
  const warnings = new Map(); // the API's warning -> the files it is about
  let corrected = 0;
  let targets = 0;
  let kept = 0;
  for (const { set, summary } of previews) {
    const prefix = set.label ? `${set.label}/` : "";
    const mine = summary.targets || [];
    targets += mine.length;
    for (const r of mine) {
      rows.push({ ...r, file: prefix + r.file });
      if (r.status === "corrected") corrected += 1;
      else if (isKept(r)) kept += 1;
    }
    for (const [reason, n] of Object.entries(summary.left_by_reason || {})) {
      const words = reasonWords(reason);
      groups.set(words, (groups.get(words) || 0) + n);
    }
    const unread = new Set((summary.errors || []).map((e) => e.file));
    for (const f of (summary.files || []).filter((x) => !unread.has(x.file))) {
      const t = mine.filter((r) => r.file === f.file);
      const done = t.filter((r) => r.status === "corrected").length;
      let result;
      if (f.read_only) result = el("span", {}, "read only: the controller's own file, read for its tools and bases, never written (not in the download)");
      else if (done) result = el("span", { class: "ok" }, `filtered: ${done} of ${t.length} corrected`);
      else result = el("span", {}, t.length ? "unchanged: nothing corrected (reasons below)" : "unchanged: no targets in this file");
      if (f.warning) {
        warnings.set(f.warning, [...(warnings.get(f.warning) || []), prefix + f.file]);
        result = el("span", {}, result, " ", el("span", { class: "bad" }, "Check: another maker's language (above)."));
      }
      perFile.push([prefix + f.file, f.dialect || "–", String(t.length), String(done), String(t.length - done), result]);
    }
    for (const e of summary.errors || []) failed.push({ file: prefix + e.file, why: e.reason ? `${e.line ? `line ${e.line}: ` : ""}${e.reason}` : e.message });
  }
  for (const f of failed) perFile.push([f.file, "–", "–", "–", "–", el("span", { class: "bad" }, `not read: ${f.why}`)]);
  fillTable($("filter-files-result"), [{ label: "file" }, { label: "language", class: "wide-only" }, { label: "targets", num: true, class: "wide-only" },
    { label: "corrected", num: true }, { label: "unchanged", num: true, class: "wide-only" }, { label: "result", class: "keep" }], perFile);
  $("filter-reasons").replaceChildren(...[...groups].sort((a, b) => b[1] - a[1]).map(([w, n]) => el("li", {}, el("b", {}, `${n} ×`), ` ${w}`)));
  $("filter-reasons-title").hidden = !groups.size;
  $("filter-warnings").hidden = !warnings.size;
  setText("filter-warnings", warnings.size ? `Not this robot's language? ${[...warnings].map(([w, files]) =>
    `${files.length === 1 ? files[0] : `${files.length} files (${files.join(", ")})`}: ${w}`).join(". ")}.` : "");
  fillTable($("filter-result"), [{ label: "target (file:line)" }, { label: "status" }, { label: "shift [mm]", num: true },
    { label: "reason", class: "keep" }, { label: "shift [deg]", num: true, class: "wide-only" }, { label: "configuration", class: "wide-only" },
    { label: "σ at the tool [mm]", num: true, class: "wide-only" }],
  rows.map((r) => [`${r.name} (${r.file}:${r.line})`,
    el("span", { class: r.status === "corrected" ? "ok" : r.status === "skipped" || r.status === "unused" ? "" : "bad" }, r.status),
    fix(r.shift_mm, 3), r.status === "corrected" ? "" : reasonWords(r.reason), fix(r.shift_deg, 4),
    r.configuration_kept == null ? "–" : r.configuration_kept ? "kept" : "changed", fix(r.sigma_at_tool_mm, 3)]));
  $("filter-details").hidden = !rows.length;
  setText("filter-details-count", `Every target (${rows.length})`);
  const first = previews[0]?.summary;
  const left = targets - corrected - kept;
  const head = previews.length
    ? `${targets} targets in ${perFile.length - failed.length} file(s): ${corrected} corrected, ${kept} joint target(s) kept, ${left} left unchanged (why: below)` +
      `${failed.length ? `; ${failed.length} file(s) not read (named below)` : ""}; robot ${first.robot}, calibration #${first.calibration_id} of ${first.calibration_date}.`
    : `Nothing was filtered: ${failed.length} file(s) not read (named below). Robot ${c.robot_name}.`;
  setText("filter-state", corrected ? head : `${head} Nothing was corrected, so there is nothing to download.`);
  $("filter-state").classList.toggle("bad", !previews.length);
  renderDownloads();
}

/** One Download per set that corrected something (a backup goes back to its own controller). */
function renderDownloads() {
  const useful = previews.filter((p) => (p.summary.counts?.corrected || 0) > 0);
  $("filter-download").hidden = !(useful.length === 1 && previews.length === 1);
  const box = $("filter-downloads");
  for (const b of box.querySelectorAll("button.per-set")) b.remove();
  if (previews.length < 2) return;
  box.append(...useful.map((p) => {
    const b = el("button", { type: "button", class: "secondary small per-set" }, `Download ${p.set.label || "the loose files"}: filtered`);
    b.addEventListener("click", () => downloadFiltered(p).catch((e) => showMessage("error", `filter: ${e.message}`)));
    return b;
  }));
}

async function downloadFiltered(p) {
  const c = state.campaign;
  let response;
  try {
    response = await api("POST", `/robots/${c.robot_id}/filter${filterQuery(p.summary)}`, { form: filterForm(p.set), raw: true, quiet: true });
  } catch (exc) {
    if (exc.status === 409) {
      $("filter-download").hidden = true;
      for (const b of $("filter-downloads").querySelectorAll("button.per-set")) b.remove();
      setText("filter-state", `Not downloaded: ${exc.body?.detail || exc.message}`);
      showMessage("error", `Filter: not downloaded: ${exc.body?.detail || exc.message}`, "filter");
      await renderFilterTarget(); // the calibration the next preview uses
      return;
    }
    throw exc;
  }
  const disposition = response.headers.get("Content-Disposition") || "";
  const m = /filename="?([^";]+)"?/.exec(disposition);
  saveBlob(await response.blob(), m ? m[1] : `robot-${c.robot_id}-filtered.zip`);
}

function renderFrames() {
  const own = sets.filter((s) => s.frames).map((s) => `${s.label ? `${s.label}/` : ""}${s.frames.name}`);
  const names = [...own, ...(pickedFrames ? [pickedFrames.name] : [])];
  setText("filter-frames-state", names.length ? `Fanuc frames from ${names.join(", ")}.` : "No frames file: Fanuc targets in a user frame or tool other than 0 are left.");
  $("filter-frames-clear").hidden = !pickedFrames;
}

export function initFilter() {
  // The languages and their files: the program registry's one list (GET /programs/languages).
  api("GET", "/programs/languages").then((l) => setText("filter-languages", l.filter_files)).catch(() => {});
  const drop = $("filter-drop");
  const run = (items) => filterPrograms(items).catch((e) => showMessage("error", `filter: ${e.message}`));
  $("filter-files").addEventListener("change", (ev) => run([...ev.target.files].map((file) => ({ file, top: "" }))));
  drop.addEventListener("dragover", (ev) => { ev.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (ev) => {
    ev.preventDefault();
    drop.classList.remove("over");
    droppedFiles(ev.dataTransfer).then(run).catch((e) => showMessage("error", `filter: ${e.message}`));
  });
  $("filter-frames").addEventListener("change", (ev) => {
    pickedFrames = ev.target.files[0] || null;
    renderFrames();
    if (sets.length) runFilter().catch((e) => showMessage("error", `filter: ${e.message}`));
  });
  $("filter-frames-clear").addEventListener("click", () => {
    pickedFrames = null;
    $("filter-frames").value = "";
    renderFrames();
    if (sets.length) runFilter().catch((e) => showMessage("error", `filter: ${e.message}`));
  });
  $("filter-keep-joints").addEventListener("change", () => { if (sets.length) runFilter().catch((e) => showMessage("error", `filter: ${e.message}`)); });
  $("filter-download").addEventListener("click", () => downloadFiltered(previews[0]).catch((e) => showMessage("error", `filter: ${e.message}`)));
  renderFrames();
}
