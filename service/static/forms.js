// Operation forms generated from the service's OpenAPI schema: every POST route tagged
// "operations" (domain-scoped /v1/domains/{domain_id}/<name>, or global /v1/<name>) gets a form
// built from its request body's JSON schema, so operations added to the service appear here
// without new code. Distribution fields are filled from the vertices picked on the domain.
// A request carries only what the user set (required fields, picks, fields edited or filled
// "from picks"): everything left alone takes the server's default, as an API call would.

export function listOperations(openapi) {
  const ops = [];
  for (const [path, methods] of Object.entries(openapi.paths || {})) {
    const op = methods.post;
    if (!op || !(op.tags || []).includes("operations")) continue;
    const contents = (op.requestBody && op.requestBody.content) || {};
    const json = contents["application/json"];
    const multipart = contents["multipart/form-data"];
    if (!json && !multipart) continue;
    const scoped = path.includes("{domain_id}");
    ops.push({
      path, scoped, id: op.operationId, summary: op.summary || op.operationId,
      guide: op["x-guide"] || null, thesis: op["x-thesis"] || null,
      kinds: op["x-domain-kinds"] || null, // the domain kinds it runs on (null: any)
      name: path.split("/").pop(), schema: (json || multipart).schema, multipart: !json,
    });
  }
  ops.sort((a, b) => (a.scoped === b.scoped ? a.name.localeCompare(b.name) : a.scoped ? -1 : 1));
  return ops;
}

function deref(root, s) {
  let guard = 0;
  while (s && s.$ref && guard++ < 20) {
    const name = s.$ref.split("/").pop();
    s = root.components.schemas[name];
  }
  return s || {};
}

function isBinary(root, s) {
  s = deref(root, s);
  return s.type === "string" && (s.format === "binary" || Boolean(s.contentMediaType));
}

function refName(s) { return s && s.$ref ? s.$ref.split("/").pop() : ""; }

// {schema, nullable}: strips anyOf [X, null].
function unwrap(root, s) {
  s = deref(root, s);
  const alts = s.anyOf || s.oneOf;
  if (alts) {
    const rest = alts.filter((a) => a.type !== "null");
    if (rest.length === 1) {
      return { schema: { ...deref(root, rest[0]), description: s.description,
                         default: s.default, title: s.title }, nullable: rest.length < alts.length };
    }
  }
  return { schema: s, nullable: false };
}

export function isDistribution(root, s) {
  const alts = (deref(root, s).anyOf || deref(root, s).oneOf || []);
  return alts.some((a) => /Distribution$/.test(refName(a)));
}

function label(name, s, required) {
  const el = document.createElement("label");
  el.textContent = name + (required ? " *" : "");
  if (s.description) el.title = s.description;
  return el;
}

// pick -> distribution JSON: a bump {vertex, radius}, or a point mass (sparse).
export function pickToDistribution(p) {
  return p.radius ? { vertex: p.vertex, radius: p.radius }
    : { indices: [p.vertex], masses: [1] };
}

// Build the form of one operation into `container`; returns {collect} (async: the request body).
export function buildForm(container, root, op, ctx) {
  container.replaceChildren();
  const body = deref(root, op.schema);
  const props = body.properties || {};
  const required = new Set(body.required || []);
  const main = document.createElement("div");
  const more = document.createElement("details");
  const moreSummary = document.createElement("summary");
  moreSummary.textContent = "options";
  more.appendChild(moreSummary);
  container.append(main, more);
  const readers = [];
  let distIndex = 0;
  let binsField = null; // a {lo, hi, count} / edges object field (histogram bins), if any
  // The value range of the form's bins field ([lo, hi]); filled with DEFAULT_BINS when empty.
  const binsOf = () => {
    if (!binsField) return null;
    const area = binsField.row.querySelector("textarea");
    let spec = null;
    try { spec = area && area.value.trim() ? JSON.parse(area.value) : null; } catch (_) { spec = null; }
    if (!spec && area) {
      spec = DEFAULT_BINS;
      area.value = JSON.stringify(spec);
      area.dispatchEvent(new Event("input", { bubbles: true }));
    }
    if (spec && Array.isArray(spec.edges) && spec.edges.length > 1) {
      return [spec.edges[0], spec.edges[spec.edges.length - 1]];
    }
    return spec && Number.isFinite(spec.lo) && Number.isFinite(spec.hi) ? [spec.lo, spec.hi] : null;
  };

  for (const [name, raw] of Object.entries(props)) {
    const isReq = required.has(name);
    const row = document.createElement("div");
    row.className = "field";
    row.dataset.field = name;
    const { schema: s, nullable } = unwrap(root, raw);
    const desc = raw.description || s.description || "";
    const info = { ...s, description: desc };
    row.appendChild(label(name, info, isReq));
    let read;
    let always = isReq; // sent even when left alone (required, or filled from the picks)
    let touched = false; // the user edited it (or filled it with a button)
    row.addEventListener("input", () => { touched = true; });
    row.addEventListener("change", () => { touched = true; });

    if (isDistribution(root, raw)) {
      const k = distIndex++;
      const sel = document.createElement("select");
      sel.name = name;
      // the k-th distribution field takes the k-th pick (another pick only when chosen):
      // with fewer picks than fields the request is refused here, never sent with mu0 = mu1
      const fill = () => {
        const picks = ctx.picks();
        const keep = sel.dataset.chosen === "1" && Number(sel.value) < picks.length
          ? sel.value : null;
        sel.replaceChildren(new Option(`(pick ${k + 1}: click the domain)`, ""),
          ...picks.map((p, i) => new Option(`pick ${i + 1} (vertex ${p.vertex})`, String(i))));
        sel.value = keep !== null ? keep : (k < picks.length ? String(k) : "");
        if (keep === null) sel.dataset.chosen = "";
      };
      sel.addEventListener("change", () => { sel.dataset.chosen = "1"; });
      fill();
      ctx.onPicksChanged(fill);
      row.appendChild(sel);
      read = () => {
        const p = sel.value === "" ? undefined : ctx.picks()[Number(sel.value)];
        if (!p) {
          const n = ctx.picks().length;
          throw fieldError(name, `${name} needs pick ${k + 1} but ${n} vertex${n === 1 ? " is" : "es are"} `
            + "picked: click the domain once per distribution");
        }
        return pickToDistribution(p);
      };
      always = true;
    } else if (s.type === "array" && isDistribution(root, s.items)) {
      const note = document.createElement("span");
      note.className = "note";
      const fill = () => { note.textContent = `all ${ctx.picks().length} picks`; };
      fill();
      ctx.onPicksChanged(fill);
      row.appendChild(note);
      read = () => {
        const picks = ctx.picks();
        if (!picks.length && isReq) throw fieldError(name, `pick vertices for ${name}`);
        return picks.length || isReq ? picks.map(pickToDistribution) : undefined;
      };
      always = true;
    } else if (s.enum) {
      const sel = document.createElement("select");
      sel.name = name;
      if (!isReq && s.default === undefined) sel.appendChild(new Option("(default)", ""));
      for (const v of s.enum) sel.appendChild(new Option(String(v), String(v)));
      if (s.default !== undefined) sel.value = String(s.default);
      row.appendChild(sel);
      read = () => (sel.value === "" ? undefined : s.enum.find((v) => String(v) === sel.value));
    } else if (s.type === "boolean" && (nullable || s.default === undefined)) {
      // no fixed default (the server decides): "(default)", true or false
      const sel = document.createElement("select");
      sel.name = name;
      sel.append(new Option("(default)", ""), new Option("true", "true"), new Option("false", "false"));
      row.appendChild(sel);
      read = () => (sel.value === "" ? undefined : sel.value === "true");
    } else if (s.type === "boolean") {
      const box = document.createElement("input");
      box.type = "checkbox";
      box.name = name;
      box.checked = Boolean(s.default);
      row.appendChild(box);
      read = () => box.checked;
    } else if (s.type === "integer" || s.type === "number") {
      const input = document.createElement("input");
      input.type = "text";
      input.inputMode = "decimal";
      input.name = name;
      const vertexLike = s.type === "integer" && /vertex|source|target point/i.test(desc + name)
        && !/size|count|number of/i.test(desc);
      if (s.default !== undefined && s.default !== null) input.value = String(s.default);
      else if (vertexLike) input.placeholder = "first pick";
      else input.placeholder = nullable ? "default" : "";
      row.appendChild(input);
      read = () => {
        const t = input.value.trim();
        if (t === "") {
          if (vertexLike && ctx.picks().length) { touched = true; return ctx.picks()[0].vertex; }
          if (isReq) throw fieldError(name, `${name} is required`);
          return undefined;
        }
        const v = Number(t);
        if (!Number.isFinite(v)) throw fieldError(name, `${name} must be a number`);
        return v;
      };
    } else if (s.type === "string" && !s.enum && (/domain/i.test(name) || /domain id/i.test(desc))) {
      const sel = document.createElement("select");
      sel.name = name;
      const fill = () => {
        const keep = sel.value;
        sel.replaceChildren(...ctx.domains().map((d) => new Option(domainLabel(d), d.id)));
        sel.value = keep || (ctx.currentDomain() || {}).id || "";
      };
      fill();
      ctx.onDomainsChanged(fill);
      row.appendChild(sel);
      read = () => sel.value || undefined;
    } else if (isBinary(root, s) || (s.type === "array" && isBinary(root, s.items))) {
      const input = document.createElement("input");
      input.type = "file";
      input.name = name;
      input.multiple = s.type === "array";
      row.appendChild(input);
      read = () => {
        const files = [...(input.files || [])];
        if (!files.length && isReq) throw fieldError(name, `choose file(s) for ${name}`);
        return files.length ? { files } : undefined;
      };
    } else if (s.type === "string" && /blob|image|file/i.test(name) && ctx.uploadBlob) {
      const input = document.createElement("input");
      input.type = "file";
      input.name = name;
      row.appendChild(input);
      read = async () => {
        const f = input.files && input.files[0];
        if (!f) { if (isReq) throw fieldError(name, `choose a file for ${name}`); return undefined; }
        return ctx.uploadBlob(f);
      };
    } else if (s.type === "array" && ["number", "integer"].includes(deref(root, s.items).type)) {
      const input = document.createElement("input");
      input.type = "text";
      input.name = name;
      if (Array.isArray(s.default)) input.value = s.default.join(", ");
      else if (name === "times" && isReq) input.value = "0, 0.25, 0.5, 0.75, 1";
      input.placeholder = "comma-separated" + (nullable ? " (default)" : "");
      row.appendChild(input);
      read = () => {
        const t = input.value.trim();
        if (!t) { if (isReq) throw fieldError(name, `${name} is required`); return undefined; }
        const vals = t.split(/[\s,;]+/).filter(Boolean).map(Number);
        if (vals.some((v) => !Number.isFinite(v))) throw fieldError(name, `${name}: numbers please`);
        return vals;
      };
    } else if (s.type === "string") {
      const input = document.createElement("input");
      input.type = "text";
      input.name = name;
      if (s.default) input.value = s.default;
      row.appendChild(input);
      read = () => input.value.trim() || undefined;
    } else { // objects, arrays of objects, tuples: JSON
      const area = document.createElement("textarea");
      area.name = name;
      area.rows = 2;
      area.placeholder = "JSON" + (s.type ? ` (${s.type})` : "");
      if (s.default !== undefined && s.default !== null) area.value = JSON.stringify(s.default);
      row.appendChild(area);
      const template = pickTemplate(root, s);
      if (template === "pairs" && ctx.pickTargets) { // landmark pairs: picks on source and target
        const show = document.createElement("button");
        show.type = "button";
        show.className = "small";
        show.textContent = "pick on target";
        show.title = "show the target beside the source; click it once per source pick";
        show.onclick = () => {
          const sel = container.querySelector("select[name*=target]");
          if (sel && sel.value) ctx.pickTargets(sel.value);
        };
        const b = document.createElement("button");
        b.type = "button";
        b.className = "small";
        b.textContent = "from picks";
        b.onclick = () => {
          area.value = JSON.stringify(ctx.pairs().map(([a, t]) => ({ source: a, target: t })));
          area.dispatchEvent(new Event("input", { bubbles: true }));
        };
        row.append(show, b);
      } else if (template && template !== "pairs") { // e.g. labeled nodes, fixed nodes: one complete item per pick
        const b = document.createElement("button");
        b.type = "button";
        b.className = "small";
        b.textContent = "from picks";
        b.onclick = () => {
          const picks = ctx.picks();
          area.value = JSON.stringify(picks.map((p, i) => template(p, i, picks.length, binsOf)));
          area.dispatchEvent(new Event("input", { bubbles: true }));
        };
        row.appendChild(b);
      }
      read = () => {
        const t = area.value.trim();
        if (!t) { if (isReq) throw fieldError(name, `${name} is required (JSON)`); return undefined; }
        try { return JSON.parse(t); } catch (_) { throw fieldError(name, `${name}: invalid JSON`); }
      };
    }
    if (desc) {
      const help = document.createElement("div");
      help.className = "help";
      help.textContent = desc;
      row.appendChild(help);
    }
    (isReq || isDistribution(root, raw) || name === "weights" ? main : more).appendChild(row);
    readers.push([name, read, () => always || touched]);
    if (isBinsSpec(root, s)) binsField = { row, read };
  }

  // The request body: a JSON object, or FormData for multipart operations (files as parts,
  // other values as text: JSON for lists and objects).
  async function collect() {
    const out = {};
    for (const [name, read, isSet] of readers) {
      const v = await read();
      if (v !== undefined && isSet()) out[name] = v;
    }
    if (!op.multipart) return out;
    const form = new FormData();
    for (const [name, v] of Object.entries(out)) {
      if (v && v.files) for (const f of v.files) form.append(name, f, f.name);
      else form.append(name, typeof v === "object" ? JSON.stringify(v) : String(v));
    }
    return form;
  }
  return { collect };
}

const DEFAULT_BINS = { lo: 0, hi: 1, count: 16 };

// An object schema of histogram bins: lo/hi (and count) or edges.
function isBinsSpec(root, s) {
  const props = deref(root, s).properties || {};
  return Boolean((props.lo && props.hi) || props.edges);
}

// For an array of objects naming a point ("node"/"vertex"), a function (pick, i, n, binsOf)
// -> a complete item: items with a distribution property get it from the pick (and their
// index as the node); items labeled by samples on the form's bins (histogram propagation)
// get the picked vertex and one sample, spread over the bins' range from the first pick to
// the last; others the picked vertex alone.
function pickTemplate(root, s) {
  if (s.type !== "array") return null;
  const item = deref(root, s.items);
  const props = item.properties || {};
  const int = (k) => props[k] && deref(root, props[k]).type === "integer";
  if (int("source") && int("target")) return "pairs";
  const key = ["node", "vertex"].find((k) => props[k] && deref(root, props[k]).type === "integer");
  if (!key) return null;
  const dist = Object.keys(props).find((k) => isDistribution(root, props[k]));
  if (dist) return (p, i) => ({ [key]: i, [dist]: pickToDistribution(p) });
  const numbers = (k) => {
    const { schema } = unwrap(root, props[k] || {});
    return schema.type === "array" && ["number", "integer"].includes(deref(root, schema.items).type);
  };
  if (numbers("samples")) {
    return (p, i, n, binsOf) => {
      const range = binsOf() || [DEFAULT_BINS.lo, DEFAULT_BINS.hi];
      const at = range[0] + (range[1] - range[0]) * (i + 0.5) / Math.max(n, 1);
      return { [key]: p.vertex, samples: [at] };
    };
  }
  return (p) => ({ [key]: p.vertex });
}

// givenName: the name this browser uploaded the domain under (an upload of an already
// stored mesh is the same domain, recorded under its first file's name)
export function domainLabel(d) {
  const name = d.givenName || (d.source && d.source.filename) || d.kind;
  return `${name} · ${d.kind} · ${d.n} · ${d.id.slice(0, 8)}`;
}

function fieldError(field, message) {
  const e = new Error(message);
  e.field = field;
  return e;
}

// Mark the form row named by an error's field ("times[1]" -> row "times").
export function markField(container, field) {
  for (const el of container.querySelectorAll(".field.bad")) el.classList.remove("bad");
  if (!field) return;
  const head = String(field).split(/[.[]/)[0];
  const row = container.querySelector(`.field[data-field="${CSS.escape(head)}"]`);
  if (row) row.classList.add("bad");
}
