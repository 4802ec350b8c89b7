// Boot: the token (from #token=... once, else asked once per browser tab), the tabs, the views.
import { api, askToken, getToken, tokenFromUrl } from "./api.js";
import { initApply } from "./apply.js";
import { initCampaign, restoreCampaign } from "./campaign.js";
import { initCell } from "./cell.js";
import { initIdentify } from "./identify.js";
import { initWatch } from "./watch.js";
import { $, changed, loadRoutes, onChange, setText, showMessage, state } from "./ui.js";

const VIEWS = ["cell", "campaign", "identify", "apply"];

function show(view) {
  state.view = view;
  for (const b of $("tabs").querySelectorAll("button")) b.classList.toggle("active", b.dataset.view === view);
  for (const v of VIEWS) $(`view-${v}`).classList.toggle("active", v === view);
  sessionStorage.setItem("cablecal-view", view);
  changed("view");
}

async function boot() {
  window.addEventListener("unhandledrejection", (ev) => {
    ev.preventDefault();
    if (ev.reason?.status === undefined) showMessage("error", `page: ${ev.reason?.message || ev.reason}`);
  });
  window.addEventListener("error", (ev) => showMessage("error", `page: ${ev.message}`));
  tokenFromUrl();
  $("token-button").addEventListener("click", () => askToken("Enter a new access token."));
  for (const b of $("tabs").querySelectorAll("button")) b.addEventListener("click", () => show(b.dataset.view));
  onChange((kind) => {
    if (kind === "campaign" || kind === "campaign-data") {
      const c = state.campaign;
      const pill = $("top-campaign");
      pill.className = c ? "pill" : "pill muted";
      setText(pill, c ? `campaign #${c.id} ${c.name} · ${c.n_included} samples` : "no campaign selected");
    }
  });
  await loadRoutes();
  if (!getToken()) await askToken();
  const saved = sessionStorage.getItem("cablecal-view");
  show(VIEWS.includes(saved) ? saved : "cell");
  initCell();
  initCampaign();
  initIdentify();
  initApply();
  initWatch();
  changed("campaign");
  await api("GET", "/health");
  await restoreCampaign();
}

boot().catch(() => {});
