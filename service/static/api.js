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

// -- result arrays -------------------------------------------------------------------------
// A job's JSON result inlines the arrays that fit its size budget (`arrays`, nested lists) and
// links every array as a NumPy .npy file (`array_files`: href, shape, dtype). These read both
// alike; arrays fetched as files are parsed here and kept on the result object.

export function arrayNames(result) {
  return [...new Set([...Object.keys(result.arrays || {}), ...Object.keys(result.array_files || {})])];
}

export function arrayShape(result, name) {
  const info = (result.array_files || {})[name];
  if (info) return info.shape.slice();
  const s = [];
  for (let a = (result.arrays || {})[name]; Array.isArray(a); a = a[0]) s.push(a.length);
  return s;
}

const loading = new WeakMap(); // result -> Map(name -> Promise), one download per array

// Make result.arrays[name] present for each of `names` that the result has (inline already,
// or downloaded as .npy and converted to nested arrays, null for non-finite values as in JSON).
export async function loadArrays(result, names) {
  if (!loading.has(result)) loading.set(result, new Map());
  const pending = loading.get(result);
  result.arrays = result.arrays || {};
  await Promise.all(names.filter((n) => n && result.arrays[n] === undefined
      && (result.array_files || {})[n]).map((name) => {
    if (!pending.has(name)) {
      const p = request(result.array_files[name].href).then((r) => r.arrayBuffer())
        .then((buf) => { result.arrays[name] = nested(parseNpy(buf)); })
        .finally(() => pending.delete(name));
      pending.set(name, p);
    }
    return pending.get(name);
  }));
  return result.arrays;
}

const NPY_TYPES = {
  "<f8": Float64Array, "<f4": Float32Array, "<i8": BigInt64Array, "<u8": BigUint64Array,
  "<i4": Int32Array, "<u4": Uint32Array, "<i2": Int16Array, "<u2": Uint16Array,
  "|i1": Int8Array, "|u1": Uint8Array, "|b1": Uint8Array,
};

// A .npy file: magic "\x93NUMPY", version, header length, a Python-literal header
// ({'descr': '<f8', 'fortran_order': False, 'shape': (n, k), }), then the raw values.
export function parseNpy(buffer) {
  const bytes = new Uint8Array(buffer);
  const magic = String.fromCharCode(...bytes.subarray(1, 6));
  if (bytes[0] !== 0x93 || magic !== "NUMPY") throw new Error("not a .npy file");
  const major = bytes[6];
  const view = new DataView(buffer);
  const start = major === 1 ? 10 : 12;
  const length = major === 1 ? view.getUint16(8, true) : view.getUint32(8, true);
  const header = new TextDecoder(major >= 3 ? "utf-8" : "latin1")
    .decode(bytes.subarray(start, start + length));
  const dtype = /'descr':\s*'([^']+)'/.exec(header)[1];
  const fortran = /'fortran_order':\s*True/.test(header);
  const shape = /'shape':\s*\(([^)]*)\)/.exec(header)[1].split(",")
    .map((x) => x.trim()).filter(Boolean).map(Number);
  const Type = NPY_TYPES[dtype];
  if (!Type) throw new Error(`unsupported .npy dtype ${dtype}`);
  const count = shape.reduce((a, b) => a * b, 1);
  const offset = start + length;
  const end = offset + count * Type.BYTES_PER_ELEMENT;
  const data = offset % Type.BYTES_PER_ELEMENT === 0 ? new Type(buffer, offset, count)
    : new Type(buffer.slice(offset, end)); // typed arrays need aligned offsets
  return { dtype, fortran, shape, data };
}

// Nested JS arrays of a parsed .npy (what the JSON result would have held).
export function nested({ dtype, fortran, shape, data }) {
  const value = dtype === "|b1" ? (v) => v !== 0
    : dtype[1] === "f" ? (v) => (Number.isFinite(v) ? v : null) : (v) => Number(v);
  const strides = shape.map((_, k) => (fortran ? shape.slice(0, k) : shape.slice(k + 1))
    .reduce((a, b) => a * b, 1));
  const build = (k, at) => (k === shape.length ? value(data[at])
    : Array.from({ length: shape[k] }, (_, i) => build(k + 1, at + i * strides[k])));
  return build(0, 0);
}
