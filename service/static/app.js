// The otgeo viewer: domains and jobs, picks, operation forms from /openapi.json, live job
// progress (/events), results on the domain (colors + legend, frames, flows, soft maps,
// histograms, images) and downloads.

import * as api from "./api.js";
import { drawLegend, formatNumber, range } from "./colormap.js";
import { buildForm, domainLabel, listOperations, markField } from "./forms.js";
import { View, pickColor } from "./scene.js";

const $ = (id) => document.getElementById(id);

const state = {
  openapi: null, ops: [], domains: [], jobs: [], domain: null, geometry: null, picks: [],
  targetPicks: [], pairing: false,
  form: null, job: null, result: null, stream: null, second: null, listeners: [],
};
window.otgeo = state; // for debugging in the console

const view = new View($("view"));
view.controls.addEventListener("change", () => { if (state.display && state.display.hist) drawPlots(); });
state.view = view;
const geometryCache = new Map();

// -- status and errors --------------------------------------------------------------
function status(text) { $("status").textContent = text || ""; }

function showError(err) {
  const box = $("error");
  if (!err) { box.hidden = true; box.textContent = ""; markField($("op-form"), null); return; }
  const field = err.field ? ` (field: ${err.field})` : "";
  const code = err.code ? `${err.code}: ` : "";
  box.textContent = `${code}${err.message}${field}`;
  box.hidden = false;
  markField($("op-form"), err.field);
}

// -- API key ------------------------------------------------------------------------
api.onKeyNeeded(() => new Promise((resolve) => {
  const dlg = $("key-dialog");
  $("key-input").value = "";
  dlg.onclose = () => resolve(dlg.returnValue === "ok" ? $("key-input").value.trim() : null);
  dlg.showModal();
}));
$("key-button").onclick = async () => {
  const dlg = $("key-dialog");
  $("key-input").value = api.apiKey() || "";
  dlg.onclose = () => {
    if (dlg.returnValue === "ok") { api.setApiKey($("key-input").value.trim()); refreshAll(); }
  };
  dlg.showModal();
};

// -- domains ------------------------------------------------------------------------
// The names the user gave uploads, by domain id (kept across reloads of the page).
const NAMES_KEY = "otgeo.uploadNames";
function givenNames() {
  try { return JSON.parse(localStorage.getItem(NAMES_KEY)) || {}; } catch { return {}; }
}
function rememberName(id, name) {
  const names = givenNames();
  names[id] = name;
  try { localStorage.setItem(NAMES_KEY, JSON.stringify(names)); } catch { /* storage full or off */ }
}

async function refreshDomains() {
  const domains = [];
  let cursor = null;
  for (let page = 0; page < 20; page++) { // every page of the list (up to 2,000 domains)
    const out = await api.getJSON("/v1/domains?limit=100" + (cursor ? `&cursor=${encodeURIComponent(cursor)}` : ""));
    domains.push(...out.domains);
    cursor = out.next_cursor;
    if (!cursor) break;
  }
  const names = givenNames();
  for (const d of domains) if (names[d.id]) d.givenName = names[d.id];
  state.domains = domains;
  const ul = $("domains");
  ul.replaceChildren(...domains.map((d) => {
    const li = document.createElement("li");
    li.textContent = domainLabel(d);
    li.dataset.id = d.id;
    li.title = d.id + (d.warnings.length ? "\n" + d.warnings.join("\n") : "");
    if (state.domain && d.id === state.domain.id) li.classList.add("active");
    li.onclick = () => selectDomain(d.id).catch(showError);
    return li;
  }));
  state.listeners.filter((l) => l.kind === "domains").forEach((l) => l.fn());
}

async function geometry(id) {
  if (!geometryCache.has(id)) geometryCache.set(id, await api.getJSON(`/v1/domains/${id}/geometry`));
  return geometryCache.get(id);
}

// Show a domain. A change of domain closes the job shown (its panel would be stale), except
// when a job's own result asks for its domain (keepJob).
async function selectDomain(id, { keepPicks = false, keepJob = false } = {}) {
  if (!keepJob && (!state.domain || state.domain.id !== id)) closeJob();
  const meta = state.domains.find((d) => d.id === id) || await api.getJSON(`/v1/domains/${id}`);
  status(`loading ${domainLabel(meta)}…`);
  const geom = await geometry(id);
  state.domain = meta;
  state.geometry = geom;
  renderOperations();
  state.second = null;
  if (!keepPicks) state.picks = [];
  state.targetPicks = [];
  state.pairing = false;
  view.setDomains([geom]);
  $("empty").hidden = true;
  for (const li of $("domains").children) li.classList.toggle("active", li.dataset.id === id);
  clearResultView();
  renderPicks();
  state.listeners.filter((l) => l.kind === "domains").forEach((l) => l.fn());
  status(`${domainLabel(meta)}`);
}

async function uploadFiles(files) {
  showError(null);
  let last = null;
  for (const f of files) {
    status(`uploading ${f.name}…`);
    try { last = await api.upload(f); } catch (e) { showError(e); status(""); return; }
    // a mesh file is stored once: a later upload of it returns the first upload's record
    if (f.name && last.source && last.source.filename) rememberName(last.id, f.name);
  }
  await refreshDomains();
  if (last) await selectDomain(last.id);
}

const drop = $("drop");
for (const target of [drop, $("stage")]) {
  target.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  target.addEventListener("dragleave", () => drop.classList.remove("over"));
  target.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    const files = [...(e.dataTransfer ? e.dataTransfer.files : [])];
    if (files.length) uploadFiles(files);
  });
}
$("file").onchange = (e) => { uploadFiles([...e.target.files]); e.target.value = ""; };

// -- picks --------------------------------------------------------------------------
function pickMode() { return document.querySelector("input[name=pick-mode]:checked").value; }
function radius() { return Number($("radius").value); }

function renderPicks() {
  const ol = $("picks");
  ol.replaceChildren(...state.picks.map((p, i) => {
    const li = document.createElement("li");
    const sw = document.createElement("span");
    sw.className = "swatch";
    sw.style.background = "#" + pickColor(i).toString(16).padStart(6, "0");
    li.append(sw, p.radius ? `bump at vertex ${p.vertex}, r ${p.radius}` : `point mass at vertex ${p.vertex}`);
    const t = state.pairing && state.targetPicks[i];
    if (t) li.append(` → target ${t.vertex}`);
    const rm = document.createElement("button");
    rm.type = "button";
    rm.textContent = "×";
    rm.title = "remove";
    rm.onclick = () => { state.picks.splice(i, 1); renderPicks(); };
    li.appendChild(rm);
    return li;
  }));
  if (view.items.length) view.setPicks(0, state.picks, !state.result);
  if (state.pairing && view.items.length > 1) view.setPicks(1, state.targetPicks, false);
  state.listeners.filter((l) => l.kind === "picks").forEach((l) => l.fn());
  drawPlots();
}

view.onPick = ({ item, point }) => {
  if (item === 1 && state.pairing) {
    state.targetPicks.push({ vertex: point, radius: null });
    renderPicks();
    return;
  }
  if (item !== 0) return;
  state.picks.push({ vertex: point, radius: pickMode() === "bump" ? radius() : null });
  renderPicks();
};
$("radius").oninput = () => {
  $("radius-value").textContent = radius().toFixed(2);
  for (const p of state.picks) if (p.radius) p.radius = radius();
  renderPicks();
};
$("clear-picks").onclick = () => { state.picks = []; renderPicks(); };

// -- operations ---------------------------------------------------------------------
const formCtx = {
  picks: () => state.picks,
  domains: () => state.domains,
  currentDomain: () => state.domain,
  onPicksChanged: (fn) => state.listeners.push({ kind: "picks", fn }),
  onDomainsChanged: (fn) => state.listeners.push({ kind: "domains", fn }),
  uploadBlob: null,
  // landmark pairs: the i-th source pick with the i-th pick on the target
  pairs: () => state.picks.map((p, i) => [p.vertex, (state.targetPicks[i] || {}).vertex])
    .filter(([, t]) => t !== undefined),
  pickTargets: async (targetId) => {
    if (!state.geometry) return;
    const target = await geometry(targetId);
    view.setDomains([state.geometry, target]);
    state.second = target;
    state.targetPicks = [];
    state.pairing = true;
    renderPicks();
    status("click the target (right) once per source pick, in order");
  },
};

function selectOperation() {
  const op = state.ops.find((o) => o.id === $("operation").value);
  state.listeners = [];
  showError(null);
  if (!op) return;
  $("op-summary").textContent = op.summary;
  const guide = $("op-guide");
  guide.hidden = !op.guide;  // the user-guide page that explains the operation (x-guide)
  if (op.guide) {
    guide.href = op.guide;
    guide.textContent = `guide${op.thesis ? ` (thesis ${op.thesis})` : ""}`;
  }
  state.form = buildForm($("op-form"), state.openapi, op, formCtx);
  state.op = op;
}

// The operation selector: global operations, and the domain-scoped ones that run on the
// kind of domain shown (x-domain-kinds). The selection stays while offered; else distances.
const DEFAULT_OPERATION = "distances";
function renderOperations() {
  const sel = $("operation");
  const kind = state.domain ? state.domain.kind : null;
  const offered = state.ops.filter((o) => !o.scoped || !kind || !o.kinds || o.kinds.includes(kind));
  const kept = sel.value;
  sel.replaceChildren(...offered.map((o) => new Option(o.scoped ? o.name : `${o.name} (global)`, o.id)));
  const fallback = offered.find((o) => o.scoped && o.name === DEFAULT_OPERATION) || offered[0];
  sel.value = offered.some((o) => o.id === kept) ? kept : (fallback ? fallback.id : "");
  if (sel.value !== kept || !state.op) selectOperation();
}

async function runOperation() {
  showError(null);
  const op = state.op;
  try {
    if (op.scoped && !state.domain) throw new Error("choose a domain first");
    const body = await state.form.collect();
    const path = op.scoped ? op.path.replace("{domain_id}", state.domain.id) : op.path;
    $("run").disabled = true;
    if (state.job) closeJob(); // the panel shows this submission's job, or none if refused
    const job = body instanceof FormData ? await api.postForm(path, body)
      : await api.postJSON(path, body);
    state.jobRequest = body instanceof FormData ? {} : body;
    state.jobInputs = body instanceof FormData
      ? { jobId: job.id, files: [...body.values()].filter((v) => v instanceof File) } : null;
    await refreshJobs();
    await followJob(job);
  } catch (e) {
    showError(e);
  } finally {
    $("run").disabled = false;
  }
}
$("run").onclick = runOperation;
$("operation").onchange = selectOperation;
$("op-form").onsubmit = (e) => { e.preventDefault(); runOperation(); };

// -- jobs ---------------------------------------------------------------------------
async function refreshJobs() {
  const { jobs } = await api.getJSON("/v1/jobs?limit=50");
  state.jobs = jobs;
  $("jobs").replaceChildren(...jobs.map((j) => {
    const li = document.createElement("li");
    li.dataset.id = j.id;
    li.innerHTML = `<span class="state ${j.state}">${j.state}</span>`;
    li.append(`${j.operation} · ${j.id.slice(0, 8)}`);
    li.title = `${j.id}\ndomain ${j.domain_id}`;
    if (state.job && state.job.id === j.id) li.classList.add("active");
    li.onclick = () => openJob(j).catch(showError);
    return li;
  }));
}
$("refresh-jobs").onclick = () => refreshJobs().catch(showError);

async function openJob(job) {
  showError(null);
  state.jobRequest = null; // not sent by this page: the result tells what it needs
  state.jobInputs = null;
  if (state.domain === null || job.domain_id !== state.domain.id) {
    if (job.domain_id) await selectDomain(job.domain_id, { keepJob: true });
  }
  await followJob(job);
}

// A running job that reports no iterations (an exact solver: one long step) but whose
// decision estimated its run time: {seconds, elapsed} for a time-based bar, else null.
function runTimeEstimate(job) {
  const p = job.progress || {};
  const seconds = Number((job.decision || {}).estimated_seconds);
  if (job.state !== "running" || !(seconds > 0) || p.iteration || p.fraction > 0) return null;
  if (!state.runningSince) state.runningSince = performance.now(); // the page's clock only
  return { seconds, elapsed: (performance.now() - state.runningSince) / 1000 };
}

function aboutSeconds(s) {
  return s < 90 ? `about ${Math.max(1, Math.round(s))} s` : `about ${Math.round(s / 60)} min`;
}

function setProgress(job) {
  const bar = $("progress");
  bar.dataset.state = job.state;
  state.shownJob = job;
  const p = job.progress || {};
  const est = runTimeEstimate(job);
  let frac = 0.03;
  if (job.state === "succeeded") frac = 1;
  else if (["failed", "cancelled"].includes(job.state)) frac = 1;
  else if (est) {
    frac = Math.max(frac, Math.min(0.95, est.elapsed / est.seconds));
    setTimeout(() => { if (state.shownJob === job) setProgress(job); }, 500); // the bar moves
  } else if (p.fraction !== null && p.fraction !== undefined) frac = Math.max(frac, p.fraction);
  else if (p.iteration) {
    const req = state.jobRequest || {};
    if (req.max_iter) frac = Math.max(frac, p.iteration / req.max_iter);
    if (p.residual > 0 && state.firstResidual > 0) {
      const tol = req.tol || 1e-6;
      const f = Math.log(state.firstResidual / p.residual) / Math.log(state.firstResidual / tol);
      if (Number.isFinite(f)) frac = Math.max(frac, Math.min(0.97, f));
    }
  }
  bar.style.width = `${(100 * frac).toFixed(1)}%`;
  const parts = [job.state];
  if (p.stage) parts.push(p.stage); // e.g. compiling kernels before the first iteration
  if (est) parts.push(`${aboutSeconds(est.seconds)} (estimated)`);
  else if (p.iteration !== null && p.iteration !== undefined && !(p.stage && !p.iteration)) {
    parts.push(`iteration ${p.iteration}`);
  }
  if (p.residual !== null && p.residual !== undefined) parts.push(`residual ${formatNumber(p.residual)}`);
  if (p.eta_seconds) parts.push(`≈${p.eta_seconds.toFixed(1)} s left`);
  if (job.duration_seconds) parts.push(`${job.duration_seconds.toFixed(2)} s`);
  $("progress-text").textContent = parts.join(" · ");
  $("cancel").hidden = !["queued", "running"].includes(job.state); // nothing to cancel after
  if (job.error) showError(job.error);
}

// Stop following the job shown and hide its panels (not the job itself: it goes on).
function closeJob() {
  if (state.stream) state.stream.abort();
  state.stream = null;
  state.job = null;
  state.shownJob = null;
  $("job-panel").hidden = true;
  $("job-title").textContent = "";
  clearResultView();
  for (const li of $("jobs").children) li.classList.remove("active");
}

async function followJob(job) {
  if (state.stream) state.stream.abort();
  const ctrl = new AbortController();
  state.stream = ctrl;
  state.job = job;
  state.firstResidual = null;
  state.runningSince = null;
  clearResultView();
  $("job-panel").hidden = false;
  $("job-title").textContent = `${job.operation} ${job.id.slice(0, 8)}`;
  setProgress(job);
  let last = job;
  try {
    await api.streamEvents(`/v1/jobs/${job.id}/events`, (name, data) => {
      if (name !== "progress" || ctrl.signal.aborted) return;
      last = data;
      if (data.progress && data.progress.residual > 0 && !state.firstResidual) {
        state.firstResidual = data.progress.residual;
      }
      setProgress(data);
      const badge = $("jobs").querySelector(`li[data-id="${data.id}"] .state`);
      if (badge) { badge.textContent = data.state; badge.className = `state ${data.state}`; }
    }, ctrl.signal);
  } catch (e) {
    if (ctrl.signal.aborted) return;
    throw e;
  }
  if (ctrl.signal.aborted) return;
  state.stream = null;
  refreshJobs().catch(() => {});
  if (last.state === "succeeded") await showResult(last);
}

$("cancel").onclick = async () => {
  if (!state.job) return;
  try { setProgress(await (await api.del(`/v1/jobs/${state.job.id}`)).json()); }
  catch (e) { showError(e); }
};

// -- results ------------------------------------------------------------------------
function clearResultView() {
  $("result-panel").hidden = true;
  $("legend").hidden = true;
  $("frames").hidden = true;
  $("hover").hidden = true;
  $("gallery").replaceChildren();
  $("gallery").hidden = true;
  $("plots").replaceChildren();
  state.result = null;
  state.display = null;
  state.softMap = null;
  view.setArrows(null);
  view.onHover = null;
  if (state.second && state.geometry) { view.setDomains([state.geometry]); state.second = null; }
  state.pairing = false;
  if (view.items.length) { view.neutral(0); view.setPicks(0, state.picks); }
}

function shape(a) {
  const s = [];
  while (Array.isArray(a)) { s.push(a.length); a = a[0]; }
  return s;
}

// Source and target domains of a result that maps one domain to another (soft maps): the
// job's own fields (its result's source_id/target_id, else the request this page sent), never
// a guess. {} for results on one domain.
function domainPair(job, result) {
  const v = result.values || {}, req = state.jobRequest || {};
  const id = (x) => (typeof x === "string" && x ? x : undefined);
  const target = id(v.target_id) || id(req.target_id);
  if (!target) return {};
  return { source: id(v.source_id) || id(req.source_id) || id(job.domain_id), target };
}

async function showResult(job) {
  const result = await api.getJSON(`/v1/jobs/${job.id}/result`);
  const pair = domainPair(job, result);
  if (pair.target && pair.source && (!state.domain || state.domain.id !== pair.source)) {
    await selectDomain(pair.source, { keepPicks: true, keepJob: true });
  }
  if (pair.target && !job.domain_id) job = { ...job, domain_id: pair.source };
  state.result = result;
  // arrays are drawn on the shown domain only when the job is about it (global jobs, e.g. color
  // transfer, have values and files only)
  const onDomain = Boolean(state.domain && job.domain_id && job.domain_id === state.domain.id);
  state.resultOnDomain = onDomain;
  const geom = onDomain ? state.geometry : null;
  if (view.items.length) view.setPicks(0, state.picks, false); // supports hide the colors
  $("result-panel").hidden = false;
  // values
  const rows = Object.entries(result.values).filter(([, v]) => typeof v !== "object" || v === null
    || (Array.isArray(v) && v.length <= 8 && v.every((x) => typeof x !== "object")));
  $("values").replaceChildren(...rows.map(([k, v]) => {
    const tr = document.createElement("tr");
    const a = document.createElement("td"), b = document.createElement("td");
    a.textContent = k;
    b.textContent = Array.isArray(v) ? v.map(formatNumber).join(", ") : formatNumber(v);
    tr.append(a, b);
    return tr;
  }));
  // fields that can be shown on the domain
  const exp = result.export || {};
  const nFaces = geom && geom.faces ? geom.faces.length / 3 : -1;
  const names = api.arrayNames(result).filter((k) => { // large arrays are fetched when shown
    const s = api.arrayShape(result, k);
    return geom && (s[0] === geom.n || s[0] === nFaces) && (s.length === 1 || s.length === 2)
      && k !== exp.flow;
  });
  const order = [...(exp.fields || []).filter((k) => names.includes(k)),
                 ...names.filter((k) => !(exp.fields || []).includes(k))];
  const sel = $("field");
  $("field-row").hidden = !order.length;
  sel.replaceChildren(...order.map((k) => new Option(k, k)));
  if (pair.target) sel.prepend(new Option("(none: hover the source)", "")); // soft maps
  sel.value = exp.color && order.includes(exp.color) ? exp.color
    : (pair.target ? "" : (order[0] || ""));
  sel.onchange = async () => { await api.loadArrays(result, [sel.value]); showField(sel.value); };
  const hist = exp.histograms || "histograms";
  const arrays = await api.loadArrays(result, geom ? [sel.value, exp.flow, hist] : []);
  const flow = geom && exp.flow && arrays[exp.flow] && view.items.length ? arrays[exp.flow] : null;
  $("arrows-toggle").hidden = !flow;
  $("show-arrows").checked = true;
  $("show-arrows").onchange = () => view.setArrows($("show-arrows").checked ? flow : null);
  if (flow) view.setArrows(flow);
  if (geom && pair.target) await showSoftMap(result, pair.target);
  else if (typeof (result.values || {}).rows === "string") { // rows served, target unnamed
    $("hover").hidden = false;
    $("hover").textContent = "this result does not name its target domain (target_id)";
  }
  showField(sel.value);
  showFiles(result);
  showDownloads(job, result);
}

function showField(name) {
  const result = state.result;
  const geom = state.geometry;
  if (!result || !name || !view.items.length || !state.resultOnDomain) {
    $("legend").hidden = true;
    return;
  }
  const arr = result.arrays[name];
  const s = shape(arr);
  const perFace = geom.faces && s[0] === geom.faces.length / 3 && s[0] !== geom.n;
  const exp = result.export || {};
  const frames = s.length === 2 && (exp.frames || []).length === s[1];
  state.display = { name, arr, perFace, frames, hist: histogramArray(result, geom) };
  $("frames").hidden = !frames;
  $("plots").replaceChildren();
  if (s.length === 1) {
    const [lo, hi] = range(arr);
    view.colorBy(0, arr, lo, hi, perFace);
    legend(lo, hi, name);
  } else if (frames) {
    let lo = Infinity, hi = -Infinity; // one scale for all frames
    for (const row of arr) { const [a, b] = range(row); lo = Math.min(lo, a); hi = Math.max(hi, b); }
    state.display.lo = lo; state.display.hi = hi;
    const slider = $("frame");
    slider.max = String(s[1] - 1);
    slider.value = "0";
    slider.oninput = () => showFrame(Number(slider.value));
    showFrame(0);
    legend(lo, hi, name);
  } else { // (n, k) without frames: a histogram per point
    state.display.hist = { name, arr };
    view.neutral(0);
    $("legend").hidden = true;
  }
  drawPlots();
  if (state.display.hist && !state.second) {
    view.onHover = ({ item, point }) => { if (item === 0) hoverPlot(point); };
  }
}

// A (n, k) result array of histograms per point (shown as small plots at the picks and under
// the cursor): the export's "histograms", else an array named so.
function histogramArray(result, geom) {
  const exp = result.export || {};
  const name = exp.histograms || (result.arrays.histograms ? "histograms" : null);
  const arr = name && result.arrays[name];
  if (!arr || shape(arr).length !== 2 || shape(arr)[0] !== geom.n) return null;
  return { name, arr };
}

// One point's histogram; with frames (k = T * B columns) the current frame's B bins.
function histogramRow(i) {
  const d = state.display;
  const row = d.hist.arr[i];
  const T = ((state.result.export || {}).frames || []).length;
  if (d.frames && T > 1 && row.length % T === 0) {
    const B = row.length / T, t = Number($("frame").value);
    return row.slice(t * B, (t + 1) * B);
  }
  return row;
}

let playing = null;
$("play").onclick = () => {
  if (playing) { clearInterval(playing); playing = null; $("play").textContent = "▶"; return; }
  $("play").textContent = "❚❚";
  playing = setInterval(() => {
    const slider = $("frame");
    if (!state.display || !state.display.frames || $("frames").hidden) {
      clearInterval(playing); playing = null; $("play").textContent = "▶"; return;
    }
    slider.value = String((Number(slider.value) + 1) % (Number(slider.max) + 1));
    showFrame(Number(slider.value));
  }, 400);
};

function showFrame(t) {
  const d = state.display;
  const col = d.arr.map((row) => row[t]);
  view.colorBy(0, col, d.lo, d.hi, d.perFace);
  const times = (state.result.export || {}).frames || [];
  $("frame-label").textContent = `t = ${formatNumber(times[t])} (${t + 1}/${times.length})`;
  $("frame").dataset.frame = String(t);
  if (d.hist) drawPlots();
}

function legend(lo, hi, label) {
  const c = $("legend");
  c.hidden = false;
  drawLegend(c, lo, hi, label);
  c.dataset.lo = String(lo);
  c.dataset.hi = String(hi);
}

// Small plots of a (n, k) result row at each picked point.
function drawPlots() {
  const plots = $("plots");
  plots.replaceChildren();
  const d = state.display;
  if (!d || !d.hist) return;
  state.picks.forEach((p, i) => {
    const pos = view.screenPosition(0, p.vertex);
    if (!pos) return;
    plots.appendChild(plotCanvas(histogramRow(p.vertex), pos, pickColor(i)));
  });
}

function hoverPlot(i) {
  const d = state.display;
  if (!d || !d.hist) return;
  const h = $("hover");
  h.hidden = false;
  h.textContent = `point ${i}: ${d.hist.name}`;
  const old = $("plots").querySelector(".hover-plot");
  if (old) old.remove();
  const pos = view.screenPosition(0, i);
  if (!pos) return;
  const c = plotCanvas(histogramRow(i), pos, 0xffffff);
  c.classList.add("hover-plot");
  $("plots").appendChild(c);
}

function plotCanvas(row, pos, color) {
  const c = document.createElement("canvas");
  c.width = 96; c.height = 56;
  c.style.left = `${pos.x + 8}px`;
  c.style.top = `${pos.y - 60}px`;
  const ctx = c.getContext("2d");
  const hi = Math.max(...row.map((v) => v || 0)) || 1;
  const w = (c.width - 8) / row.length;
  ctx.fillStyle = "#" + color.toString(16).padStart(6, "0");
  row.forEach((v, k) => {
    const h = (c.height - 14) * (v || 0) / hi;
    ctx.fillRect(4 + k * w, c.height - 4 - h, Math.max(1, w - 1), h);
  });
  ctx.fillStyle = "#ccc";
  ctx.font = "9px sans-serif";
  ctx.fillText(`max ${formatNumber(hi)}`, 4, 9);
  return c;
}

// Soft maps: the target domain is drawn beside the source; hovering a source vertex colors the
// target with that vertex's row of the (rows, n_target) array (fetched one row at a time from
// /v1/jobs/{id}/arrays/{name}/rows/{i} unless the result carries it). A "labels" array of one
// row index per source vertex (samples of the source) maps vertices to rows.
async function showSoftMap(result, targetId) {
  const target = await geometry(targetId);
  const exp = result.export || {};
  const arrays = await api.loadArrays(result, [exp.labels || "labels"]); // rows: one at a time
  const n0 = state.geometry.n;
  const name = exp.rows || (result.values || {}).rows
    || (api.arrayShape(result, "soft_map").length ? "soft_map" : null)
    || api.arrayNames(result).find((k) => { const s = api.arrayShape(result, k); return s.length === 2 && s[1] === target.n; })
    || "soft_map";
  const labels = Array.isArray(arrays[exp.labels || "labels"]) && arrays[exp.labels || "labels"].length === n0
    ? arrays[exp.labels || "labels"] : null;
  view.setDomains([state.geometry, target]);
  view.setPicks(0, state.picks, false);
  state.second = target;
  const rowsCache = new Map();
  const rowOf = async (i) => {
    const r = labels ? labels[i] : i;
    if (Array.isArray(arrays[name]) && arrays[name][r]) return arrays[name][r];
    if (!rowsCache.has(r)) {
      const out = await api.getJSON(`/v1/jobs/${result.job_id}/arrays/${name}/rows/${r}`);
      rowsCache.set(r, Array.isArray(out) ? out : out.values);
    }
    return rowsCache.get(r);
  };
  const h = $("hover");
  h.hidden = false;
  h.textContent = "hover the source (left) to see its distribution on the target";
  let busy = false, wanted = null;
  const show = async (point) => {
    busy = true;
    try {
      const row = await rowOf(point);
      const [lo, hi] = range(row);
      view.colorBy(1, row, lo, hi);
      legend(lo, hi, `${name} of source vertex ${point}`);
      h.textContent = `source vertex ${point}`;
      view.setPicks(0, [{ vertex: point, radius: null }]);
      $("hover").dataset.vertex = String(point);
    } catch (e) { showError(e); } finally { busy = false; }
    if (wanted !== null && wanted !== point) { const w = wanted; wanted = null; show(w); }
  };
  view.onHover = ({ item, point }) => {
    if (item !== 0) return;
    if (busy) { wanted = point; return; }
    show(point);
  };
  state.softMap = { name, target, targetId };
}

// Image files of a result (color transfer) side by side over the stage, under the input images
// of the request when this page sent it.
function showFiles(result) {
  const images = normalizeFiles(result).filter((x) => /^image\//.test(x.media_type || "")
    || /\.(png|jpe?g|webp|tiff?)$/i.test(x.name));
  const box = $("gallery");
  box.replaceChildren();
  if (!images.length) { box.hidden = true; return; }
  const strip = (title, items, kind = "") => {
    const h = document.createElement("h3");
    h.textContent = title;
    const row = document.createElement("div");
    row.className = kind ? `strip ${kind}` : "strip";
    for (const [name, src] of items) {
      const fig = document.createElement("figure");
      const img = document.createElement("img");
      img.alt = name;
      Promise.resolve(src).then((url) => { img.src = url; }).catch(showError);
      const cap = document.createElement("figcaption");
      cap.textContent = name;
      fig.append(img, cap);
      row.appendChild(fig);
    }
    box.append(h, row);
  };
  const inputs = state.jobInputs && state.jobInputs.jobId === result.job_id ? state.jobInputs.files : [];
  if (inputs.length) strip("inputs", inputs.map((f) => [f.name, URL.createObjectURL(f)]));
  // color transfer: outputs, then the ab histograms (inputs', outputs', the barycenters')
  // in one row so the match can be compared at a glance
  const fetched = (f) => [f.name, api.request(`/v1/jobs/${result.job_id}/files/${f.name}`)
    .then((r) => r.blob()).then((b) => URL.createObjectURL(b))];
  const isHistogram = (f) => /^(histogram|barycenter)-/.test(f.name);
  const outputs = images.filter((f) => !isHistogram(f));
  const histograms = images.filter(isHistogram);
  if (outputs.length) strip("results", outputs.map(fetched));
  if (histograms.length) {
    strip("ab histograms (a* right, b* up)", histograms.map(fetched), "histograms");
  }
  box.hidden = false;
}

function normalizeFiles(result) {
  const f = result.files || (result.export || {}).files || [];
  if (Array.isArray(f)) return f.map((x) => (typeof x === "string" ? { name: x } : x));
  return Object.entries(f).map(([name, meta]) => ({ name, ...(typeof meta === "object" ? meta : {}) }));
}

function showDownloads(job, result) {
  const box = $("downloads");
  const link = (text, fn) => {
    const b = document.createElement("button");
    b.type = "button";
    b.textContent = text;
    b.onclick = () => fn().catch(showError);
    box.appendChild(b);
  };
  box.replaceChildren();
  const base = `${job.operation}-${job.id.slice(0, 8)}`;
  link("JSON", () => api.download(`/v1/jobs/${job.id}/result`, `${base}.json`));
  const files = normalizeFiles(result);
  if (job.domain_id || files.some((f) => f.name === "result.glb")) {
    link("GLB", () => api.download(`/v1/jobs/${job.id}/result.glb`, `${base}.glb`));
  }
  if (state.resultOnDomain) link("PNG", async () => {
    view.render();
    const blob = await new Promise((r) => view.canvas.toBlob(r, "image/png"));
    api.saveBlob(blob, `${base}.png`);
  });
  for (const f of files) {
    if (f.name === "result.glb") continue;
    link(f.name, () => api.download(`/v1/jobs/${job.id}/files/${f.name}`, `${base}-${f.name}`));
  }
}

// -- start --------------------------------------------------------------------------
async function loadOperations() {
  state.openapi = await (await fetch("/openapi.json")).json();
  state.ops = listOperations(state.openapi);
  const up = state.openapi.paths["/v1/domains/upload"];
  if (up && up.post) api.setUploadPath("/v1/domains/upload");
  const blobRoute = Object.keys(state.openapi.paths).find((p) => /^\/v1\/blobs$/.test(p)
    && state.openapi.paths[p].post);
  formCtx.uploadBlob = blobRoute ? async (file) => {
    const form = new FormData();
    form.append("file", file, file.name);
    const out = await (await api.request(blobRoute, { method: "POST", body: form })).json();
    return out.id;
  } : null;
  renderOperations();
}

async function refreshAll() {
  try {
    await refreshDomains();
    await refreshJobs();
  } catch (e) { showError(e); }
}

async function start() {
  try { await loadOperations(); } catch (e) { showError(e); }
  await refreshAll();
  const wanted = new URLSearchParams(location.search).get("domain");
  if (wanted) await selectDomain(wanted).catch(showError);
  document.body.dataset.ready = "1";
}
start();
