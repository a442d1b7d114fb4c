// ptfarm dashboard: plain script, no build step, nothing from elsewhere.
"use strict";
const $ = (id) => document.getElementById(id);
function esc(s) {
  return String(s).replace(/[&<>"']/g, (c) => "&#" + c.charCodeAt(0) + ";");
}
function dur(s) {
  if (!(s >= 0) || !isFinite(s)) return "-";
  s = Math.round(s);
  if (s < 60) return s + "s";
  if (s < 3600) return Math.floor(s / 60) + "m" + String(s % 60).padStart(2, "0") + "s";
  return Math.floor(s / 3600) + "h" + String(Math.floor(s / 60) % 60).padStart(2, "0") + "m";
}
function rate(r) {
  if (!(r > 0)) return "-";
  if (r >= 1e6) return (r / 1e6).toFixed(2) + " M";
  if (r >= 1e3) return (r / 1e3).toFixed(1) + " k";
  return r.toFixed(0);
}
function eta(j) {
  if (j.state !== "running" || !(j.samples_per_second > 0)) return "-";
  return dur((j.samples_total - j.samples_done) / j.samples_per_second);
}
function active(j) { return j.state === "queued" || j.state === "running"; }
async function post(url, body) {
  const r = await fetch(url, { method: "POST", body: body || "",
    headers: { "Content-Type": "application/x-www-form-urlencoded" } });
  if (!r.ok) alert((await r.json()).error);
}
async function getJSON(url) {
  const r = await fetch(url);
  if (r.status === 401) { location.href = "/login"; throw new Error("login"); }
  return r.json();
}

async function queuePage() {
  const jobs = await getJSON("/api/jobs");
  const rows = jobs.map((j) => {
    const pct = (100 * j.progress).toFixed(1);
    const acts = active(j)
      ? `<button data-cancel="${j.id}">cancel</button>
         <input class="prio" data-prio="${j.id}" value="${j.priority}">`
      : "";
    return `<tr><td class="num">${j.id}</td><td><a href="/job?id=${j.id}">${esc(j.name || "(unnamed)")}</a></td>
      <td>${esc(j.state)}</td><td class="num">${j.priority}</td>
      <td><span class="bar"><i style="width:${pct}%"></i></span> ${pct}%</td>
      <td class="num">${rate(j.samples_per_second)}</td><td>${eta(j)}</td>
      <td class="num">${j.error === null ? "-" : (100 * j.error).toFixed(2) + "%"}</td>
      <td>${esc(j.owner)}</td><td>${acts}</td></tr>`;
  });
  $("jobs").tBodies[0].innerHTML = rows.join("");
  $("status").textContent = jobs.length + " jobs, updated " + new Date().toLocaleTimeString();
}

async function workersPage() {
  const ws = await getJSON("/api/workers");
  $("workers").tBodies[0].innerHTML = ws.map((w) => w.state === "blocked" ?
    `<tr class="err"><td class="num">-</td><td>${esc(w.name)}</td><td>${esc(w.address)}</td>
     <td colspan="7">blocked: ${esc(w.reason)}</td></tr>` :
    `<tr><td class="num">${w.id}</td><td>${esc(w.name)}</td><td>${esc(w.address)}</td>
     <td class="num">${w.threads}</td><td class="num">${w.tasks_done}</td>
     <td class="num">${(w.samples_per_second / 1e3).toFixed(1)} k</td>
     <td>${w.last_result_seconds_ago === null ? "-" : dur(w.last_result_seconds_ago) + " ago"}</td>
     <td class="num">${w.slots_wanted}</td><td class="num">${w.deadline_misses}</td>
     <td>${dur(w.connected_seconds)}</td></tr>`).join("");
}

function jobPage() {
  const id = Number(new URLSearchParams(location.search).get("id"));
  let images = -1, lastSamples = -1;
  $("exr").href = `/api/jobs/${id}/image.exr`;
  const loadImage = () => {
    const v = $("view").value, e = $("exposure").value;
    $("ev").textContent = e;
    $("image").src = `/api/jobs/${id}/image.png?view=${v}&exposure=${e}&n=${images}.${lastSamples}`;
  };
  const show = (msg) => {
    const j = msg.job;
    if (!j) { $("summary").textContent = "no such job"; return; }
    $("title").textContent = `Job ${j.id}: ${j.name || "(unnamed)"}`;
    $("summary").textContent = `${j.state}, ${(100 * j.progress).toFixed(1)}% ` +
      `(${j.samples_done} of ${j.samples_total} samples), ${rate(j.samples_per_second)} samples/s, ` +
      `ETA ${eta(j)}, error ${j.error === null ? "-" : (100 * j.error).toFixed(2) + "%"}, by ${j.owner}` +
      (j.guiding && j.state === "running" ? `, guiding pass ${j.guiding.pass}` +
        (j.guiding.pass ? ` (learned from ${j.guiding.learned_spp} spp)` : " (learning)") : "") +
      (j.contributions_clamped ? `, ${j.contributions_clamped} contributions clamped` : "") +
      (j.integrator === "bidirectional" ? ", bidirectional" : "");
    $("info").textContent = JSON.stringify(j, null, 1);
    document.body.dataset.samples = j.samples_done;
    // A new image only when the coordinator has saved one (--save-interval).
    if (msg.images !== images) {
      images = msg.images; lastSamples = j.samples_done;
      loadImage();
    }
  };
  $("view").onchange = loadImage;
  $("exposure").oninput = loadImage;
  $("image").onload = () => { document.body.dataset.loaded = $("image").src; };
  loadImage(); // at once, so the page's load event waits for the first image
  if (window.EventSource) {
    const es = new EventSource(`/api/jobs/${id}/events`);
    es.onmessage = (ev) => show(JSON.parse(ev.data));
  } else {
    setInterval(async () => show({ job: await getJSON(`/api/jobs/${id}`), images: -2 }), 2000);
  }
}

document.addEventListener("click", (ev) => {
  const c = ev.target.dataset && ev.target.dataset.cancel;
  if (c && confirm("Cancel job " + c + "?")) post(`/api/jobs/${c}/cancel`).then(queuePage);
});
document.addEventListener("change", (ev) => {
  const p = ev.target.dataset && ev.target.dataset.prio;
  if (p) post(`/api/jobs/${p}/priority`, "priority=" + encodeURIComponent(ev.target.value)).then(queuePage);
});
const page = document.body.dataset.page;
if (page === "queue") { queuePage(); setInterval(queuePage, 2000); }
if (page === "workers") { workersPage(); setInterval(workersPage, 2000); }
if (page === "job") jobPage();
