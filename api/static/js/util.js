// Small helpers shared by the dashboard's modules. Every value from the daemon reaches the page
// through textContent, never as HTML.

export const $ = (id) => document.getElementById(id);

// natural order: node 2 before node 16, region "node-2" before "node-16"
export const naturally = new Intl.Collator(undefined, { numeric: true, sensitivity: "base" })
  .compare;

export function num(value) {
  return value === null || value === undefined || value === "" ? null : Number(value);
}

export function scaled(value, factor) {
  const n = num(value);
  return n === null ? null : n * factor;
}

export function norm(...values) {
  const numbers = values.map(num);
  return numbers.some((v) => v === null) ? null : Math.hypot(...numbers);
}

export function parsed(text) {
  try {
    const value = text ? JSON.parse(text) : {};
    return value && typeof value === "object" ? value : {};
  } catch { return {}; }
}

export function element(tag, className, text) {
  const node = document.createElement(tag);
  if (className) node.className = className;
  if (text !== undefined) node.textContent = text;
  return node;
}

export function fixed(value, digits) {
  return value === undefined || value === null ? null : Number(value).toFixed(digits);
}

// --- palette: every series its own colour ----------------------------------------------
// Colours are picked greedily from a grid of hues and lightnesses, each the one farthest
// (CIELAB distance) from those already chosen, so 17 model nodes and the IR regions stay
// distinguishable; the nodes are also dashed and thin, the IR regions solid and thick.

function hslToRgb(h, s, l) {
  const k = (n) => (n + h / 30) % 12;
  const a = s * Math.min(l, 1 - l);
  const f = (n) => l - a * Math.max(-1, Math.min(k(n) - 3, Math.min(9 - k(n), 1)));
  return [f(0), f(8), f(4)].map((v) => Math.round(v * 255));
}

function rgbToLab([r, g, b]) {
  const lin = (c) => {
    const v = c / 255;
    return v <= 0.04045 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4;
  };
  const [R, G, B] = [lin(r), lin(g), lin(b)];
  const x = (0.4124 * R + 0.3576 * G + 0.1805 * B) / 0.95047;
  const y = 0.2126 * R + 0.7152 * G + 0.0722 * B;
  const z = (0.0193 * R + 0.1192 * G + 0.9505 * B) / 1.08883;
  const f = (t) => (t > 0.008856 ? Math.cbrt(t) : 7.787 * t + 16 / 116);
  return [116 * f(y) - 16, 500 * (f(x) - f(y)), 200 * (f(y) - f(z))];
}

const hex = (rgb) => `#${rgb.map((v) => v.toString(16).padStart(2, "0")).join("")}`;

const CANDIDATES = (() => {
  const list = [];
  for (let h = 0; h < 360; h += 6) {
    for (const [sat, light] of [[0.9, 0.32], [0.8, 0.42], [0.85, 0.52], [0.6, 0.25]]) {
      const rgb = hslToRgb(h, sat, light);
      const lab = rgbToLab(rgb);
      if (lab[0] >= 25 && lab[0] <= 68) list.push({ colour: hex(rgb), lab }); // on white
    }
  }
  return list;
})();

const distance = (p, q) => Math.hypot(p[0] - q[0], p[1] - q[1], p[2] - q[2]);

export function palette(n) {
  const first = rgbToLab([31, 111, 235]); // the page's blue starts every palette
  const chosen = [];
  const taken = new Set();
  let nearest = CANDIDATES.map(() => Infinity); // distance to the closest chosen colour
  let pick = CANDIDATES.reduce((best, c, i) =>
    (distance(c.lab, first) < distance(CANDIDATES[best].lab, first) ? i : best), 0);
  while (chosen.length < n && chosen.length < CANDIDATES.length) {
    chosen.push(CANDIDATES[pick].colour);
    taken.add(pick);
    const lab = CANDIDATES[pick].lab;
    nearest = nearest.map((d, i) => Math.min(d, distance(CANDIDATES[i].lab, lab)));
    pick = -1;
    nearest.forEach((d, i) => { if (!taken.has(i) && (pick < 0 || d > nearest[pick])) pick = i; });
  }
  return chosen;
}
