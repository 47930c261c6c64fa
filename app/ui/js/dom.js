// A small element builder: h("div", {class: "x", dataset: {k: "v"}, onclick: fn}, child, ...).
// Text goes in as text nodes, never as HTML, so nothing the gateway sends is ever parsed as markup.

export function h(tag, props = {}, ...children) {
  const el = document.createElement(tag);
  for (const [key, value] of Object.entries(props || {})) {
    if (value === undefined || value === null || value === false) continue;
    if (key === "class") el.className = value;
    else if (key === "dataset") {
      for (const [k, v] of Object.entries(value)) if (v !== undefined && v !== null) el.dataset[k] = v;
    }
    else if (key.startsWith("on")) el.addEventListener(key.slice(2), value);
    else if (key in el && typeof value !== "string") el[key] = value;
    else el.setAttribute(key, value === true ? "" : value);
  }
  append(el, children);
  return el;
}

function append(el, children) {
  for (const child of children) {
    if (child === undefined || child === null || child === false) continue;
    if (Array.isArray(child)) append(el, child);
    else el.append(child instanceof Node ? child : String(child));
  }
}

/** Replace the children of `el`. */
export function fill(el, ...children) {
  el.replaceChildren();
  append(el, children);
  return el;
}

/** "1.2 s", "350 ms", "2 min" */
export function formatAge(ms) {
  if (!Number.isFinite(ms)) return "–";
  if (ms < 0) ms = 0;
  if (ms < 1000) return `${Math.round(ms)} ms`;
  if (ms < 60000) return `${(ms / 1000).toFixed(1)} s`;
  if (ms < 3600000) return `${Math.round(ms / 60000)} min`;
  return `${(ms / 3600000).toFixed(1)} h`;
}

export function formatBytes(n) {
  if (!Number.isFinite(n)) return "–";
  if (n < 1024) return `${n} B`;
  if (n < 1048576) return `${(n / 1024).toFixed(1)} KiB`;
  if (n < 1073741824) return `${(n / 1048576).toFixed(1)} MiB`;
  return `${(n / 1073741824).toFixed(1)} GiB`;
}

// One time format for the whole page: the browser's local time, 24-hour ("14:22:43", with
// ".123" where a line needs it), with the date in front when it is not today; the full UTC time
// is in the element's title.
const pad = (n, width = 2) => String(n).padStart(width, "0");

/** A Date from seconds since the epoch (faults), an ISO text (logs, events) or a Date. */
export function toDate(value) {
  if (value instanceof Date) return value;
  if (typeof value === "number") return new Date(value * 1000);
  return new Date(value);
}

/** "14:22:43" (today), "2026-12-03 14:22:43" (another day); withMs: "14:22:43.123". */
export function formatTime(value, { withMs = false } = {}) {
  const d = toDate(value);
  if (Number.isNaN(d.getTime())) return "–";
  const today = new Date();
  const day = d.toDateString() === today.toDateString() ? ""
    : `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} `;
  return `${day}${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}` +
    (withMs ? `.${pad(d.getMilliseconds(), 3)}` : "");
}

/** A <time> element in the page's one format, its UTC ISO time in datetime and title. */
export function timeEl(value, options) {
  const d = toDate(value);
  const iso = Number.isNaN(d.getTime()) ? "" : d.toISOString();
  return h("time", { datetime: iso, title: iso }, formatTime(d, options));
}
