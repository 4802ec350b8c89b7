"""The operator page served at ``/``: plain HTML and JavaScript over the REST API (no build
step, no external assets, works offline on the shop floor)."""

OPERATOR_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>cablecal</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
<style>
 body{font-family:system-ui,sans-serif;margin:1rem 2rem;max-width:70rem;color:#222}
 h1{font-size:1.4rem} h2{font-size:1.1rem;margin-top:1.5rem}
 table{border-collapse:collapse} td,th{border:1px solid #ccc;padding:.2rem .5rem;text-align:left}
 .ok{color:#060} .error{color:#b00} .muted{color:#777}
 input,select,button{font-size:1rem;margin:.1rem}
 pre{background:#f4f4f4;padding:.5rem;overflow:auto;max-height:20rem}
</style></head><body>
<h1>cablecal <span class="muted">drawstring robot calibration</span></h1>
<p>Token <input id="token" type="password" size="32" placeholder="CABLECAL_API_TOKEN">
 <button onclick="saveToken()">Save</button> <span id="msg" class="muted"></span></p>
<h2>Devices</h2><table id="devices"><tr><td class="muted">loading…</td></tr></table>
<p id="sampler" class="muted"></p>
<h2>Campaigns</h2>
<p><input id="cname" placeholder="name"> <input id="crobot" value="hsr-jr680" size="12">
 <button onclick="createCampaign()">Create</button></p>
<table id="campaigns"></table>
<h2>Campaign <span id="cid">–</span></h2>
<p><button onclick="capture()">Capture now</button>
 <button onclick="auto(true)">Auto capture on</button>
 <button onclick="auto(false)">Auto capture off</button>
 <select id="method"><option>ukf-vslm</option><option>lm</option><option>vslm</option>
 <option>ukf</option><option>ekf</option><option>de</option></select>
 <button onclick="identify()">Identify</button>
 <a id="csv" href="#">samples.csv</a></p>
<pre id="out"></pre>
<script>
const api = "/api/v1";
let campaign = null, job = null;
const $ = id => document.getElementById(id);
$("token").value = localStorage.getItem("cablecal-token") || "";
function saveToken(){ localStorage.setItem("cablecal-token", $("token").value); refresh(); }
async function call(method, path, body){
  const h = {"Authorization": "Bearer " + $("token").value};
  if (body !== undefined) h["Content-Type"] = "application/json";
  const r = await fetch(api + path, {method, headers: h,
    body: body === undefined ? undefined : JSON.stringify(body)});
  const t = await r.text(); let j; try { j = JSON.parse(t); } catch(e) { j = t; }
  if (!r.ok) { $("msg").textContent = r.status + " " + JSON.stringify(j.detail ?? j); throw j; }
  $("msg").textContent = ""; return j;
}
function esc(s){ return String(s).replace(/[&<>"]/g, c => ({"&":"&amp;","<":"&lt;",">":"&gt;",'"':"&quot;"}[c])); }
async function refresh(){
  try {
    const s = await call("GET", "/status");
    const devs = Object.values(s.devices || {});
    $("devices").innerHTML = "<tr><th>device</th><th>role</th><th>state</th><th>last value</th>" +
      "<th>age s</th><th>rate Hz</th><th>last error</th></tr>" + devs.map(d =>
      `<tr><td>${esc(d.name)}</td><td>${esc(d.role)}</td><td class="${d.state==="ok"?"ok":"error"}">${esc(d.state)}</td>` +
      `<td>${esc(d.last_reading ? JSON.stringify(d.last_reading.value) : "")}</td>` +
      `<td>${esc(d.last_reading ? d.last_reading.age_s.toFixed(2) : "")}</td>` +
      `<td>${esc((d.poll_rate_hz ?? 0).toFixed(1))}</td><td>${esc(d.last_error ? d.last_error.message : "")}</td></tr>`).join("");
    $("sampler").textContent = "sampler: " + JSON.stringify(s.sampler) + "  jobs: " + JSON.stringify(s.jobs);
    const cs = await call("GET", "/campaigns");
    $("campaigns").innerHTML = "<tr><th>id</th><th>name</th><th>robot</th><th>samples</th><th>auto</th></tr>" +
      cs.map(c => `<tr><td><a href="#" onclick="pick(${c.id})">${c.id}</a></td><td>${esc(c.name)}</td>` +
      `<td>${esc(c.robot_id)}</td><td>${esc(c.n_samples ?? "")}</td><td>${c.auto_capture ? "on" : ""}</td></tr>`).join("");
    if (job) {
      const j = await call("GET", "/identifications/" + job);
      $("out").textContent = JSON.stringify({id: j.id, status: j.status, progress: j.progress,
        message: j.message, error: j.error, metrics: j.result && j.result.metrics}, null, 1);
      if (["succeeded","failed","cancelled"].includes(j.status)) job = null;
    }
  } catch(e) {}
}
function pick(id){ campaign = id; $("cid").textContent = id; $("csv").href = api + "/campaigns/" + id + "/samples?format=csv"; }
async function createCampaign(){ const c = await call("POST", "/campaigns",
  {name: $("cname").value || "campaign", robot_model: $("crobot").value}); pick(c.id); refresh(); }
async function capture(){ if (!campaign) return; const s = await call("POST", `/campaigns/${campaign}/captures`, {});
  $("out").textContent = JSON.stringify(s, null, 1); refresh(); }
async function auto(on){ if (!campaign) return; await call("PUT", `/campaigns/${campaign}/auto-capture`, {enabled: on}); refresh(); }
async function identify(){ if (!campaign) return;
  const j = await call("POST", `/campaigns/${campaign}/identifications`, {method: $("method").value}); job = j.id; refresh(); }
refresh(); setInterval(refresh, 2000);
</script></body></html>
"""
