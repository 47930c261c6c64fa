// A small time plot of the last WINDOW_MS of up to MAX_SERIES numeric fields, on one canvas.
//
// Each series keeps its points in a fixed ring (CAPACITY points: 60 s at the fastest interval,
// with room to spare), so memory stays bounded however long the view is open.  Points are
// added for every frame (cheap); the canvas is drawn at most once per animation frame, by the
// caller.  Non-finite values (NaN, ±Infinity) break the line instead of squashing the axis.
// The gateway's frame timestamps are the time axis, so the browser's clock does not matter.

import { h } from "./dom.js";

export const WINDOW_MS = 60000;
const MIN_SPAN_MS = 10000;
const CAPACITY = 1600;
const MAX_SERIES = 4;
const COLORS = ["#1f6feb", "#d9480f", "#2b8a3e", "#ae3ec9"];

class Series {
  constructor(key, path, color) {
    this.key = key;
    this.path = path;
    this.color = color;
    this.t = new Float64Array(CAPACITY);
    this.v = new Float64Array(CAPACITY);
    this.start = 0;
    this.count = 0;
  }

  push(t, v) {
    const i = (this.start + this.count) % CAPACITY;
    this.t[i] = t;
    this.v[i] = v;
    if (this.count < CAPACITY) this.count += 1;
    else this.start = (this.start + 1) % CAPACITY;
    while (this.count > 0 && this.t[this.start] < t - WINDOW_MS) {
      this.start = (this.start + 1) % CAPACITY;
      this.count -= 1;
    }
  }

  *points() {
    for (let n = 0; n < this.count; n += 1) {
      const i = (this.start + n) % CAPACITY;
      yield [this.t[i], this.v[i]];
    }
  }

  get last() {
    return this.count ? this.v[(this.start + this.count - 1) % CAPACITY] : undefined;
  }
}

function format(v) {
  if (!Number.isFinite(v)) return String(v);
  const a = Math.abs(v);
  if (a !== 0 && (a >= 1e9 || a < 1e-3)) return v.toExponential(3);
  return String(Number(v.toPrecision(6)));
}

export class TimePlot {
  /** `extract(path, data)` gives the number at path (NaN/±Infinity included) or undefined. */
  constructor(container, extract) {
    this.extract = extract;
    this.series = new Map();
    this.latest = 0;
    this.canvas = h("canvas", { class: "plot-canvas", width: 600, height: 180 });
    this.legend = h("div", { class: "legend" });
    this.el = h("div", { class: "plot", hidden: true }, this.canvas, this.legend);
    container.append(this.el);
  }

  has(key) {
    return this.series.has(key);
  }

  /** Add or remove the field at `path` ("key" is its text form). */
  toggle(key, path) {
    if (this.series.has(key)) {
      this.series.delete(key);
    } else {
      if (this.series.size >= MAX_SERIES) this.series.delete(this.series.keys().next().value);
      const used = new Set([...this.series.values()].map((s) => s.color));
      const color = COLORS.find((c) => !used.has(c)) || COLORS[0];
      this.series.set(key, new Series(key, path, color));
    }
    this.el.hidden = this.series.size === 0;
  }

  /** One frame's value (`data`, the message) at gateway time `t` (ms). */
  push(t, data) {
    this.latest = t;
    for (const s of this.series.values()) {
      const v = this.extract(s.path, data);
      s.push(t, v === undefined ? NaN : v);
    }
  }

  draw() {
    if (this.el.hidden) return;
    const canvas = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const width = Math.max(200, canvas.clientWidth || 600);
    const height = Math.max(100, canvas.clientHeight || 180);
    if (canvas.width !== Math.round(width * dpr) || canvas.height !== Math.round(height * dpr)) {
      canvas.width = Math.round(width * dpr);
      canvas.height = Math.round(height * dpr);
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, width, height);
    let lo = Infinity;
    let hi = -Infinity;
    let points = 0;
    let first = Infinity;
    for (const s of this.series.values()) {
      for (const [t, v] of s.points()) {
        points += 1;
        first = Math.min(first, t);
        if (Number.isFinite(v)) {
          lo = Math.min(lo, v);
          hi = Math.max(hi, v);
        }
      }
    }
    canvas.dataset.points = String(points);
    canvas.dataset.spanMs = String(points ? Math.round(this.latest - first) : 0);
    if (lo > hi) {
      lo = -1;
      hi = 1;
    } else if (lo === hi) {
      const pad = Math.abs(lo) * 0.01 || 1;
      lo -= pad;
      hi += pad;
    }
    const left = 64;
    const right = width - 8;
    const top = 8;
    const bottom = height - 20;
    // The time axis spans the data held, from MIN_SPAN_MS up to WINDOW_MS.
    const span = points ? Math.min(WINDOW_MS, Math.max(MIN_SPAN_MS, this.latest - first)) : MIN_SPAN_MS;
    const x = (t) => right - ((this.latest - t) / span) * (right - left);
    const y = (v) => bottom - ((v - lo) / (hi - lo)) * (bottom - top);

    ctx.strokeStyle = "#d0d7de";
    ctx.lineWidth = 1;
    ctx.fillStyle = "#57606a";
    ctx.font = "11px system-ui, sans-serif";
    ctx.textBaseline = "middle";
    ctx.textAlign = "right";
    for (const v of [lo, (lo + hi) / 2, hi]) {
      ctx.beginPath();
      ctx.moveTo(left, Math.round(y(v)) + 0.5);
      ctx.lineTo(right, Math.round(y(v)) + 0.5);
      ctx.stroke();
      ctx.fillText(format(v), left - 6, y(v));
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "alphabetic";
    const step = span <= 10000 ? 2 : span <= 30000 ? 5 : 15;
    for (let s = 0; s * 1000 <= span + 1; s += step) {
      ctx.fillText(s ? `−${s} s` : "now", Math.min(right - 12, x(this.latest - s * 1000)), height - 4);
    }

    ctx.lineWidth = 1.5;
    ctx.save();
    ctx.beginPath();
    ctx.rect(left, top - 2, right - left, bottom - top + 4);
    ctx.clip();
    for (const s of this.series.values()) {
      ctx.strokeStyle = s.color;
      ctx.beginPath();
      let drawing = false;
      for (const [t, v] of s.points()) {
        if (!Number.isFinite(v)) {
          drawing = false;
          continue;
        }
        if (drawing) ctx.lineTo(x(t), y(v));
        else ctx.moveTo(x(t), y(v));
        drawing = true;
      }
      ctx.stroke();
    }
    ctx.restore();
    this._legend();
  }

  /** One entry per series; rebuilt when the series change, otherwise only the values are written. */
  _legend() {
    const keys = [...this.series.keys()].join("\u0000");
    if (keys !== this.legendKeys) {
      this.legendKeys = keys;
      this.legendValues = new Map();
      this.legend.replaceChildren(...[...this.series.values()].map((s) => {
        const value = h("span", { class: "muted" });
        this.legendValues.set(s.key, value);
        return h("span", { class: "legend-item" }, h("span", { class: `swatch c${COLORS.indexOf(s.color)}` }),
                 `${s.key} `, value);
      }));
    }
    for (const s of this.series.values()) {
      const text = s.last === undefined ? "" : format(s.last);
      const el = this.legendValues.get(s.key);
      if (el.textContent !== text) el.textContent = text;
    }
  }
}
