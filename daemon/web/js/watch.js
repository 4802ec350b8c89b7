// The live sensor watch's banner: a moved sensor (the ``watch`` block of /status), with undo.
import { api } from "./api.js";
import { $, changed, el, fix, onChange, showMessage, state } from "./ui.js";

let shown = "";

function render() {
  const moves = state.status?.watch?.moves || [];
  const key = JSON.stringify(moves.map((m) => [m.campaign_id, m.sample_id]));
  if (key === shown) return;
  shown = key;
  $("watch-banner")?.remove();
  if (!moves.length) return;
  const banner = el("div", { id: "watch-banner", class: "message warn", role: "alert" },
    el("div", { class: "text" }, ...moves.map((m) => el("div", {},
      el("b", {}, "Sensor moved? "),
      `Campaign #${m.campaign_id}: from sample #${m.sample_id} (row ${m.row}) the cable lengths `
      + `changed by ${m.step_mm >= 0 ? "+" : ""}${fix(m.step_mm, 2)} mm. Those samples and the next `
      + `captures are in a new anchor session ${m.new_anchor} (was ${m.previous_anchor}). `
      + "Check the sensor stand; if it did not move, undo. ",
      el("button", { class: "secondary small", onclick: () => undo(m) },
        `Undo: back to anchor ${m.previous_anchor}`)))));
  $("messages").prepend(banner);
}

async function undo(m) {
  try {
    const r = await api("POST", `/campaigns/${m.campaign_id}/sensor-moved/undo`);
    showMessage("info", `${r.sample_ids.length} sample(s) of campaign #${m.campaign_id} are back in anchor ${r.anchor}.`, "watch");
    state.status.watch.moves = state.status.watch.moves.filter((x) => x.campaign_id !== m.campaign_id);
    render();
    changed("campaign-data");
  } catch (exc) {
    showMessage("error", `undo: ${exc.message}`, "watch");
  }
}

export function initWatch() {
  onChange((kind) => { if (kind === "status") render(); });
}
