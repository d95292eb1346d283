// HTTP client of the otgeo service: the API key (asked once, kept in sessionStorage and sent as
// X-API-Key), JSON errors ({"error": {"code", "message", "field"}}) and server-sent events read
// through fetch (EventSource cannot send headers).

const KEY = "otgeo.apiKey";

export class ApiError extends Error {
  constructor(status, body) {
    const err = (body && body.error) || {};
    super(err.message || `HTTP ${status}`);
    this.status = status;
    this.code = err.code || String(status);
    this.field = err.field || null;
  }
}

let askKey = async () => null; // set by the page: shows the key form, resolves to the key
let asking = null; // one question at a time, shared by concurrent requests

export function onKeyNeeded(fn) { askKey = fn; }
export function apiKey() { return sessionStorage.getItem(KEY); }
export function setApiKey(key) {
  if (key) sessionStorage.setItem(KEY, key); else sessionStorage.removeItem(KEY);
}

function headers(extra) {
  const h = new Headers(extra || {});
  const key = apiKey();
  if (key) h.set("X-API-Key", key);
  return h;
}

// fetch with the key; on 401 ask for a key once and retry.
export async function request(path, options = {}, retry = true) {
  const resp = await fetch(path, { ...options, headers: headers(options.headers) });
  if (resp.status === 401 && retry) {
    if (!asking) asking = askKey().finally(() => { asking = null; });
    const key = await asking;
    if (key) { setApiKey(key); return request(path, options, false); }
  }
  if (!resp.ok) {
    let body = null;
    try { body = await resp.json(); } catch (_) { /* not JSON */ }
    throw new ApiError(resp.status, body);
  }
  return resp;
}

export async function getJSON(path) { return (await request(path)).json(); }

export async function postJSON(path, body) {
  const resp = await request(path, {
    method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(body),
  });
  return resp.json();
}

let uploadPath = "/v1/domains"; // mesh files: /v1/domains/upload where the server has it
export function setUploadPath(path) { uploadPath = path; }

export async function postForm(path, form) {
  return (await request(path, { method: "POST", body: form })).json();
}

export async function upload(file) {
  const name = file.name || "upload";
  if (name.toLowerCase().endsWith(".json")) { // a JSON domain (grid, graph, point cloud, mesh)
    const text = await file.text();
    const resp = await request("/v1/domains", {
      method: "POST", headers: { "content-type": "application/json" }, body: text,
    });
    return resp.json();
  }
  const form = new FormData();
  form.append("file", file, name);
  return (await request(uploadPath, { method: "POST", body: form })).json();
}

export async function del(path) { return request(path, { method: "DELETE" }); }

// Read an SSE stream; onEvent(name, data) for each event; resolves when the stream ends.
export async function streamEvents(path, onEvent, signal) {
  const resp = await request(path, { headers: { accept: "text/event-stream" }, signal });
  const reader = resp.body.getReader();
  const decoder = new TextDecoder();
  let buffer = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) break;
    buffer += decoder.decode(value, { stream: true });
    let cut;
    while ((cut = buffer.indexOf("\n\n")) >= 0) {
      const block = buffer.slice(0, cut);
      buffer = buffer.slice(cut + 2);
      let name = "message";
      const data = [];
      for (const line of block.split("\n")) {
        if (line.startsWith("event:")) name = line.slice(6).trim();
        else if (line.startsWith("data:")) data.push(line.slice(5).trim());
      }
      if (data.length) onEvent(name, JSON.parse(data.join("\n")));
    }
  }
}

// Save a response body as a file (downloads go through fetch so the key is sent).
export async function download(path, filename) {
  const blob = await (await request(path)).blob();
  saveBlob(blob, filename);
}

export function saveBlob(blob, filename) {
  const url = URL.createObjectURL(blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}
