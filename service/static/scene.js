// The 3-D view (three.js): domains as surfaces (meshes), images (2-D grids), points (point
// clouds, 3-D grids) or points and lines (graphs); colors per point or per face, pick markers,
// flow arrows, and a second domain side by side (soft maps). Picking and hovering report the
// nearest point of the domain under the cursor.

import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { viridis } from "./colormap.js";

const NEUTRAL = [0.72, 0.72, 0.70];
const PICK_COLORS = [0xff3b30, 0x0a84ff, 0xff9f0a, 0xbf5af2, 0x30d158, 0xffd60a, 0x64d2ff];

// vertex colors are linear; the ramp is sRGB
const lin = (c) => (c < 0.04045 ? c * 0.0773993808 : Math.pow(c * 0.9478672986 + 0.0521327014, 2.4));

export function pickColor(i) { return PICK_COLORS[i % PICK_COLORS.length]; }

function positions3(geom) {
  // (n, 3) Float32Array of a domain's point coordinates (2-D padded with z = 0).
  const n = geom.n, dim = geom.dim || 3;
  const out = new Float32Array(n * 3);
  if (geom.kind === "grid") {
    const [sx, sy = 1, sz = 1] = geom.shape;
    const b = geom.bounds;
    const lerp = (axis, k, s) => (s > 1 ? b[axis][0] + (b[axis][1] - b[axis][0]) * k / (s - 1)
      : b[axis][0]);
    let p = 0;
    for (let i = 0; i < sx; i++) for (let j = 0; j < sy; j++) for (let k = 0; k < sz; k++) {
      out[p++] = lerp(0, i, sx);
      out[p++] = geom.shape.length > 1 ? lerp(1, j, sy) : 0;
      out[p++] = geom.shape.length > 2 ? lerp(2, k, sz) : 0;
    }
    return out;
  }
  if (!geom.positions) { // a graph without positions: nodes on a circle
    for (let i = 0; i < n; i++) {
      out[3 * i] = Math.cos(2 * Math.PI * i / n);
      out[3 * i + 1] = Math.sin(2 * Math.PI * i / n);
    }
    return out;
  }
  for (let i = 0; i < n; i++) {
    for (let d = 0; d < Math.min(dim, 3); d++) out[3 * i + d] = geom.positions[dim * i + d];
  }
  return out;
}

class Item {
  // One drawn domain: its three.js object, how drawn vertices map to domain points, its colors.
  constructor(geom, offset) {
    this.geom = geom;
    this.points = positions3(geom);
    this.group = new THREE.Group();
    this.group.position.copy(offset);
    this.markers = new THREE.Group();
    this.group.add(this.markers);
    this.kind = geom.kind === "mesh" ? "surface"
      : (geom.kind === "grid" && geom.shape.length <= 2) ? "image" : "points";
    if (this.kind === "surface") this.buildSurface();
    else if (this.kind === "image") this.buildImage();
    else this.buildPoints();
    this.object.geometry.computeBoundingBox();
    this.object.geometry.computeBoundingSphere();
    this.setNeutral();
  }

  buildSurface() {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(this.points, 3));
    g.setIndex(this.geom.faces);
    g.computeVertexNormals();
    const flat = g.toNonIndexed(); // 3 drawn vertices per face: per-face colors are possible
    this.corner = Uint32Array.from(this.geom.faces); // drawn vertex -> domain vertex
    this.nFaces = this.corner.length / 3;
    flat.setAttribute("color", new THREE.BufferAttribute(new Float32Array(this.corner.length * 3), 3));
    const mat = new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide });
    this.object = new THREE.Mesh(flat, mat);
    this.group.add(this.object);
    let len = 0; // mean edge length (arrow and marker sizes)
    const f = this.geom.faces, p = this.points;
    const m = Math.min(f.length / 3, 5000);
    for (let t = 0; t < m; t++) {
      const a = f[3 * t], b = f[3 * t + 1];
      len += Math.hypot(p[3 * a] - p[3 * b], p[3 * a + 1] - p[3 * b + 1], p[3 * a + 2] - p[3 * b + 2]);
    }
    this.edgeLength = len / Math.max(m, 1);
  }

  buildImage() {
    const [sx, sy = 1] = this.geom.shape;
    const b = this.geom.bounds;
    const w = b[0][1] - b[0][0] || 1, h = this.geom.shape.length > 1 ? (b[1][1] - b[1][0] || 1) : w / 8;
    this.texData = new Uint8Array(sx * sy * 4);
    this.texture = new THREE.DataTexture(this.texData, sx, sy, THREE.RGBAFormat);
    this.texture.magFilter = THREE.NearestFilter;
    this.texture.colorSpace = THREE.SRGBColorSpace;
    const plane = new THREE.PlaneGeometry(w, h);
    const cx = (b[0][0] + b[0][1]) / 2, cy = this.geom.shape.length > 1 ? (b[1][0] + b[1][1]) / 2 : 0;
    plane.translate(cx, cy, 0);
    this.object = new THREE.Mesh(plane, new THREE.MeshBasicMaterial({
      map: this.texture, side: THREE.DoubleSide }));
    this.group.add(this.object);
    this.edgeLength = w / sx;
  }

  buildPoints() {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(this.points, 3));
    g.setAttribute("color", new THREE.BufferAttribute(new Float32Array(this.geom.n * 3), 3));
    g.computeBoundingSphere();
    const r = g.boundingSphere.radius || 1;
    this.edgeLength = 2 * r / Math.sqrt(Math.max(this.geom.n, 1)); // spacing of a 2-D spread
    const mat = new THREE.PointsMaterial({ size: Math.max(this.edgeLength * 0.35, r / 300),
                                           vertexColors: true });
    this.object = new THREE.Points(g, mat);
    this.group.add(this.object);
    if (this.geom.edges && this.geom.edges.length) {
      const lg = new THREE.BufferGeometry();
      lg.setAttribute("position", new THREE.BufferAttribute(this.points, 3));
      lg.setIndex(this.geom.edges);
      this.lines = new THREE.LineSegments(lg, new THREE.LineBasicMaterial({ color: 0x8a8f98 }));
      this.group.add(this.lines);
    }
  }

  setNeutral() { this.setColors(() => NEUTRAL, false); }

  // colorOf(i) -> [r, g, b] of domain point i (or face i when perFace).
  setColors(colorOf, perFace) {
    if (this.kind === "surface") {
      const attr = this.object.geometry.getAttribute("color");
      const c = attr.array;
      for (let k = 0; k < this.corner.length; k++) {
        const rgb = colorOf(perFace ? Math.floor(k / 3) : this.corner[k]);
        c[3 * k] = lin(rgb[0]); c[3 * k + 1] = lin(rgb[1]); c[3 * k + 2] = lin(rgb[2]);
      }
      attr.needsUpdate = true;
    } else if (this.kind === "image") {
      const [sx, sy = 1] = this.geom.shape;
      for (let i = 0; i < sx; i++) for (let j = 0; j < sy; j++) {
        const rgb = colorOf(i * sy + j);
        const t = 4 * (j * sx + i);
        this.texData[t] = rgb[0] * 255; this.texData[t + 1] = rgb[1] * 255;
        this.texData[t + 2] = rgb[2] * 255; this.texData[t + 3] = 255;
      }
      this.texture.needsUpdate = true;
    } else {
      const attr = this.object.geometry.getAttribute("color");
      for (let i = 0; i < this.geom.n; i++) {
        const rgb = colorOf(i);
        attr.array[3 * i] = lin(rgb[0]); attr.array[3 * i + 1] = lin(rgb[1]);
        attr.array[3 * i + 2] = lin(rgb[2]);
      }
      attr.needsUpdate = true;
    }
  }

  // The domain point nearest to a ray hit on this item.
  pointOf(hit) {
    const local = this.group.worldToLocal(hit.point.clone());
    if (this.kind === "surface") {
      const f = hit.faceIndex;
      let best = -1, bestD = Infinity;
      for (let c = 0; c < 3; c++) {
        const v = this.corner[3 * f + c];
        const d = (this.points[3 * v] - local.x) ** 2 + (this.points[3 * v + 1] - local.y) ** 2
          + (this.points[3 * v + 2] - local.z) ** 2;
        if (d < bestD) { bestD = d; best = v; }
      }
      return best;
    }
    if (this.kind === "image") {
      const [sx, sy = 1] = this.geom.shape;
      const i = Math.min(sx - 1, Math.max(0, Math.floor(hit.uv.x * sx)));
      const j = Math.min(sy - 1, Math.max(0, Math.floor(hit.uv.y * sy)));
      return i * sy + j;
    }
    return hit.index;
  }

  position(i) {
    return new THREE.Vector3(this.points[3 * i], this.points[3 * i + 1], this.points[3 * i + 2]);
  }
}

export class View {
  constructor(container) {
    this.container = container;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.renderer.setClearColor(0x1c1e22);
    container.appendChild(this.renderer.domElement);
    this.canvas = this.renderer.domElement;
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.001, 1000);
    this.camera.position.set(0, 0, 3);
    this.scene.add(new THREE.AmbientLight(0xffffff, 1.1));
    this.light = new THREE.DirectionalLight(0xffffff, 1.6);
    this.camera.add(this.light);
    this.light.position.set(0.5, 1, 1);
    this.scene.add(this.camera);
    this.controls = new OrbitControls(this.camera, this.canvas);
    this.controls.addEventListener("change", () => this.render());
    this.items = [];
    this.arrows = null;
    this.raycaster = new THREE.Raycaster();
    this.onPick = null;
    this.onHover = null;
    this._bindPointer();
    new ResizeObserver(() => this.resize()).observe(container);
    this.resize();
  }

  resize() {
    const w = this.container.clientWidth || 1, h = this.container.clientHeight || 1;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() { this.renderer.render(this.scene, this.camera); }

  clear() {
    for (const it of this.items) this.scene.remove(it.group);
    this.items = [];
    this.setArrows(null);
  }

  // Draw one domain, or several side by side (left to right).
  setDomains(geoms) {
    this.clear();
    let x = 0;
    for (const g of geoms) {
      const probe = new Item(g, new THREE.Vector3());
      const box = probe.object.geometry.boundingBox;
      const width = box.max.x - box.min.x;
      probe.group.position.set(x - box.min.x, 0, 0);
      x += width * 1.15;
      this.items.push(probe);
      this.scene.add(probe.group);
    }
    this.fit();
  }

  fit() {
    this.scene.updateMatrixWorld(true); // the items' groups were just moved side by side
    const box = new THREE.Box3();
    for (const it of this.items) box.expandByObject(it.object);
    if (box.isEmpty()) return;
    const center = box.getCenter(new THREE.Vector3());
    const radius = box.getSize(new THREE.Vector3()).length() / 2 || 1;
    const dist = radius / Math.sin((this.camera.fov * Math.PI / 180) / 2) * 1.05;
    this.camera.near = dist / 100;
    this.camera.far = dist * 100;
    // a three-quarter view for one surface; straight on for images and side-by-side pairs
    const dir = this.items.length === 1 && this.items[0].kind === "surface"
      ? new THREE.Vector3(0.55, 0.3, 1).normalize() : new THREE.Vector3(0, 0, 1);
    this.camera.position.copy(center).add(dir.multiplyScalar(dist));
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(center);
    this.controls.update();
    this.render();
  }

  // values: per point (or per face with perFace); lo/hi: the color scale.
  colorBy(itemIndex, values, lo, hi, perFace = false) {
    const it = this.items[itemIndex];
    const span = hi - lo || 1;
    it.setColors((i) => {
      const v = values[i];
      return v === null || v === undefined ? NEUTRAL : viridis((v - lo) / span);
    }, perFace);
    this.render();
  }

  neutral(itemIndex) { this.items[itemIndex].setNeutral(); this.render(); }

  // picks: [{vertex, radius|null}] drawn as dots (and the bump's support as a sphere).
  setPicks(itemIndex, picks, supports = true) {
    const it = this.items[itemIndex];
    if (!it) return;
    it.markers.clear();
    const s = it.edgeLength * (it.kind === "surface" ? 0.8 : 0.4);
    picks.forEach((p, k) => {
      const color = pickColor(k);
      const dot = new THREE.Mesh(new THREE.SphereGeometry(s, 12, 8),
                                 new THREE.MeshBasicMaterial({ color }));
      dot.position.copy(it.position(p.vertex));
      it.markers.add(dot);
      if (p.radius && supports) {
        const ball = new THREE.Mesh(new THREE.SphereGeometry(p.radius, 24, 16),
          new THREE.MeshBasicMaterial({ color, transparent: true, opacity: 0.12, depthWrite: false }));
        ball.position.copy(dot.position);
        it.markers.add(ball);
      }
    });
    this.render();
  }

  // Flow arrows: one per face from its centroid along the (F, 3) field.  Lengths are scaled
  // so the 90th percentile of the drawn magnitudes is 1.5 edges and clipped there: an optimal
  // flow concentrates near its sources, and scaling by the maximum would shrink the rest.
  setArrows(field, itemIndex = 0) {
    if (this.arrows) { this.arrows.parent.remove(this.arrows); this.arrows = null; }
    if (!field) { this.render(); return; }
    const it = this.items[itemIndex];
    const faces = it.geom.faces, p = it.points;
    const nF = faces.length / 3;
    let max = 0;
    for (const v of field) if (v) max = Math.max(max, Math.hypot(v[0], v[1], v[2]));
    if (!max) return;
    const drawn = [];
    for (const v of field) {
      const m = v ? Math.hypot(v[0], v[1], v[2]) : 0;
      if (m >= max * 0.02) drawn.push(m);
    }
    drawn.sort((a, b) => a - b);
    const reference = drawn[Math.floor(0.9 * (drawn.length - 1))] || max;
    const stride = Math.max(1, Math.ceil(nF / 15000));
    const seg = [];
    const longest = 1.5 * it.edgeLength;
    for (let f = 0; f < nF; f += stride) {
      const v = field[f];
      if (!v) continue;
      const m = Math.hypot(v[0], v[1], v[2]);
      if (m < max * 0.02) continue;
      const scale = Math.min(longest / reference, longest / m);
      const c = [0, 1, 2].map((d) => (p[3 * faces[3 * f] + d] + p[3 * faces[3 * f + 1] + d]
        + p[3 * faces[3 * f + 2] + d]) / 3);
      const tip = c.map((x, d) => x + v[d] * scale);
      seg.push(...c, ...tip);
      // arrow head: two short strokes back from the tip
      const dir = new THREE.Vector3(...v).normalize();
      const side = new THREE.Vector3().crossVectors(dir, new THREE.Vector3(0.31, 0.77, 0.56));
      if (side.lengthSq() < 1e-8) side.set(1, 0, 0);
      side.normalize();
      const h = m * scale * 0.35;
      for (const sgn of [1, -1]) {
        seg.push(...tip, tip[0] - dir.x * h + sgn * side.x * h * 0.5,
          tip[1] - dir.y * h + sgn * side.y * h * 0.5, tip[2] - dir.z * h + sgn * side.z * h * 0.5);
      }
    }
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.Float32BufferAttribute(seg, 3));
    this.arrows = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: 0xffffff }));
    it.group.add(this.arrows);
    this.render();
  }

  // Screen position (CSS pixels in the container) of a domain point, or null when behind.
  screenPosition(itemIndex, i) {
    const it = this.items[itemIndex];
    if (!it) return null;
    const v = it.group.localToWorld(it.position(i)).project(this.camera);
    if (v.z > 1) return null;
    return { x: (v.x + 1) / 2 * this.container.clientWidth,
             y: (1 - v.y) / 2 * this.container.clientHeight };
  }

  hit(event) {
    const rect = this.canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1,
                                  -((event.clientY - rect.top) / rect.height) * 2 + 1);
    this.raycaster.setFromCamera(ndc, this.camera);
    for (const it of this.items) {
      this.raycaster.params.Points.threshold = it.edgeLength * 0.7;
    }
    const hits = this.raycaster.intersectObjects(this.items.map((it) => it.object), false);
    if (!hits.length) return null;
    const h = hits[0];
    const index = this.items.findIndex((it) => it.object === h.object);
    return { item: index, point: this.items[index].pointOf(h) };
  }

  _bindPointer() {
    let down = null;
    this.canvas.addEventListener("pointerdown", (e) => { down = [e.clientX, e.clientY]; });
    this.canvas.addEventListener("pointerup", (e) => {
      if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;
      down = null;
      const h = this.hit(e);
      if (h && this.onPick) this.onPick(h);
    });
    let pending = false;
    this.canvas.addEventListener("pointermove", (e) => {
      if (!this.onHover || pending || e.buttons) return;
      pending = true;
      requestAnimationFrame(() => {
        pending = false;
        const h = this.hit(e);
        if (h) this.onHover(h);
      });
    });
  }
}
