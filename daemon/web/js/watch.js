// The live sensor watch's banner: a moved sensor (the ``watch`` block of /status): what the
// watch did, what happens next and how many samples Identify needs now (the campaign's
// counts, from the API), with an Undo button.
import { api } from "./api.js";
import { $, changed, dismiss, el, fix, onChange, showMessage, state } from "./ui.js";

const CAMPAIGN_MS = 5000; // how often a moved campaign's counts are re-read while shown
let shown = "";
const campaigns = new Map(); // campaign id -> {row: GET /campaigns/{id}, at: ms}
let reading = false;

/** The moved campaigns' rows (their sample counts), re-read every few seconds. */
async function readCampaigns(moves) {
  const due = moves.filter((m) => !campaigns.has(m.campaign_id) || performance.now() - campaigns.get(m.campaign_id).at >= CAMPAIGN_MS);
  if (reading || !due.length) return;
  reading = true;
  try {
    for (const m of due) {
      const row = await api("GET", `/campaigns/${m.campaign_id}`, { quiet: true });
      campaigns.set(m.campaign_id, { row, at: performance.now() });
    }
  } finally {
    reading = false;
  }
  render(); // with the counts read (a row only re-read after CAMPAIGN_MS: no loop)
}

function needWords(m) {
  const c = campaigns.get(m.campaign_id)?.row;
  if (!c) return "";
  return ` With ${c.anchors.length} anchor sessions Identify needs ${c.min_samples_to_identify} included samples `
    + `(${c.min_training_samples} to train on; the campaign has ${c.n_included}): each session adds its own sensor position to fit.`;
}

// Moves the operator kept (the stand did move: the new session stays), per browser tab.
const KEPT_KEY = "cablecal-moves-kept";
const kept = new Set(JSON.parse(sessionStorage.getItem(KEPT_KEY) || "[]"));
const moveKey = (m) => `${m.campaign_id}:${m.sample_id}`;

function keep(m) {
  kept.add(moveKey(m));
  sessionStorage.setItem(KEPT_KEY, JSON.stringify([...kept]));
  showMessage("info", `Campaign #${m.campaign_id}: the new anchor session ${m.new_anchor} is kept (the sensor stand moved); captures go on there.`, "watch-kept");
  render();
}

function render() {
  const moves = (state.status?.watch?.moves || []).filter((m) => !kept.has(moveKey(m)));
  const key = JSON.stringify(moves.map((m) => [m.campaign_id, m.sample_id, needWords(m)]));
  if (moves.length) readCampaigns(moves).catch(() => {});
  if (key === shown) return;
  shown = key;
  $("watch-banner")?.remove();
  if (!moves.length) return;
  const banner = el("div", { id: "watch-banner", class: "message warn", role: "alert" },
    el("div", { class: "text" }, ...moves.map((m) => el("div", { dataset: { campaign: m.campaign_id } },
      el("b", {}, "Sensor moved? "),
      `Campaign #${m.campaign_id}: from sample #${m.sample_id}${m.row ? ` (row ${m.row})` : ""} the cable lengths `
      + `changed by ${m.step_mm >= 0 ? "+" : ""}${fix(m.step_mm, 2)} mm. Those samples and the next `
      + `captures are in a new anchor session ${m.new_anchor} (was ${m.previous_anchor}).`,
      el("p", { class: "next" }, el("b", {}, "Next: "),
        "check the sensor stand. If it moved, keep capturing: the new session is fitted as a second sensor position."
        + needWords(m) + ` If it did not move, undo: the samples go back to anchor ${m.previous_anchor}.`),
      el("div", { class: "actions" },
        el("button", { type: "button", class: "undo", onclick: () => undo(m) },
          `Undo: back to anchor ${m.previous_anchor}`), " ",
        el("button", { type: "button", class: "secondary keep-move", onclick: () => keep(m) },
          `Keep: the stand moved (session ${m.new_anchor})`))))));
  $("messages").prepend(banner);
}

async function undo(m) {
  try {
    const r = await api("POST", `/campaigns/${m.campaign_id}/sensor-moved/undo`, { quiet: true });
    dismiss("watch");
    showMessage("info", `${r.sample_ids.length} sample(s) of campaign #${m.campaign_id} are back in anchor ${r.anchor}.`, "watch-undone");
    state.status.watch.moves = state.status.watch.moves.filter((x) => x.campaign_id !== m.campaign_id);
    campaigns.delete(m.campaign_id);
    render();
    changed("campaign-data");
  } catch (exc) {
    showMessage("error", exc.message, "watch", exc.detail);
  }
}

export function initWatch() {
  onChange((kind) => { if (kind === "status") render(); });
}
