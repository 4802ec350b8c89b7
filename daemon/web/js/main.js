// Boot: the token (from #token=... once, else asked once per browser tab), the tabs, the views.
import { api, askToken, getToken, tokenFromUrl } from "./api.js";
import { initApply } from "./apply.js";
import { initCampaign, restoreCampaign } from "./campaign.js";
import { initCell } from "./cell.js";
import { initIdentify } from "./identify.js";
import { initWatch } from "./watch.js";
import { $, changed, loadRoutes, onChange, pageError, setText, state } from "./ui.js";

const VIEWS = ["cell", "campaign", "identify", "apply"];

function show(view) {
  state.view = view;
  for (const b of $("tabs").querySelectorAll("button")) {
    const on = b.dataset.view === view;
    b.classList.toggle("active", on);
    b.setAttribute("aria-selected", String(on));
    b.tabIndex = on ? 0 : -1; // one tab stop; the arrow keys move between the tabs
  }
  for (const v of VIEWS) $(`view-${v}`).classList.toggle("active", v === view);
  sessionStorage.setItem("cablecal-view", view);
  changed("view");
}

async function boot() {
  window.addEventListener("unhandledrejection", (ev) => {
    ev.preventDefault();
    if (ev.reason?.status === undefined) pageError(ev.reason);
  });
  window.addEventListener("error", (ev) => pageError(ev.message));
  tokenFromUrl();
  $("token-button").addEventListener("click", () => askToken("Enter a new access token."));
  for (const b of $("tabs").querySelectorAll("button")) b.addEventListener("click", () => show(b.dataset.view));
  $("tabs").addEventListener("keydown", (ev) => {
    const step = { ArrowRight: 1, ArrowLeft: -1 }[ev.key];
    if (!step) return;
    const from = ev.target.closest("[role=tab]")?.dataset.view || state.view;
    const next = VIEWS[(VIEWS.indexOf(from) + step + VIEWS.length) % VIEWS.length];
    show(next);
    $(`tab-${next}`).focus();
    ev.preventDefault();
  });
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
