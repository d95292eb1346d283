// Viridis (as in service/export.py's ramp, here in sRGB 0..1) and value scaling for legends.

const VIRIDIS = [
  [0.267, 0.005, 0.329], [0.283, 0.141, 0.458], [0.254, 0.265, 0.530], [0.207, 0.372, 0.553],
  [0.164, 0.471, 0.558], [0.128, 0.567, 0.551], [0.135, 0.659, 0.518], [0.267, 0.749, 0.441],
  [0.478, 0.821, 0.318], [0.741, 0.873, 0.150], [0.993, 0.906, 0.144],
];

export function viridis(t) {
  if (!Number.isFinite(t)) return [0.55, 0.55, 0.55];
  const x = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1);
  const i = Math.min(Math.floor(x), VIRIDIS.length - 2);
  const f = x - i;
  const a = VIRIDIS[i], b = VIRIDIS[i + 1];
  return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])];
}

// Finite min/max of a list (nulls stand for non-finite values), for a color scale.
export function range(values) {
  let lo = Infinity, hi = -Infinity;
  for (const v of values) {
    if (v === null || !Number.isFinite(v)) continue;
    if (v < lo) lo = v;
    if (v > hi) hi = v;
  }
  if (lo === Infinity) return [0, 1];
  // a minimum that is round-off next to the maximum (a density's empty part) is 0
  if (hi > 0 && Math.abs(lo) <= 1e-9 * hi) lo = 0;
  if (hi === lo) return [lo, lo + (Math.abs(lo) || 1) * 1e-9];
  return [lo, hi];
}

export function formatNumber(v) {
  if (v === null || v === undefined) return "–";
  if (typeof v !== "number") return String(v);
  if (v === 0) return "0";
  if (Number.isInteger(v) && Math.abs(v) < 1e9) return String(v);
  const a = Math.abs(v);
  if (a >= 1e4 || a < 1e-3) return v.toExponential(3);
  const s = v.toPrecision(4);
  return s.includes(".") ? s.replace(/0+$/, "").replace(/\.$/, "") : s;
}

// Draw the legend: a gradient bar with its scale's numbers.
export function drawLegend(canvas, lo, hi, label) {
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  const bar = { x: 8, y: 18, w: w - 16, h: 14 };
  for (let i = 0; i < bar.w; i++) {
    const [r, g, b] = viridis(i / (bar.w - 1));
    ctx.fillStyle = `rgb(${r * 255 | 0},${g * 255 | 0},${b * 255 | 0})`;
    ctx.fillRect(bar.x + i, bar.y, 1, bar.h);
  }
  ctx.fillStyle = "#ddd";
  ctx.font = "11px sans-serif";
  ctx.textBaseline = "top";
  ctx.textAlign = "left";
  ctx.fillText(label || "", bar.x, 2);
  for (const [t, align] of [[0, "left"], [0.5, "center"], [1, "right"]]) {
    ctx.textAlign = align;
    ctx.fillText(formatNumber(lo + t * (hi - lo)), bar.x + t * bar.w, bar.y + bar.h + 3);
  }
}
