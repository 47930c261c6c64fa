// The health panel and the badge in the header: GET health every POLL_MS, drawn as it comes.
//
// States: "healthy", "degraded" (a ROS task ran past the watchdog threshold), "unavailable"
// (the ROS worker is down or being restarted: /health still answers, with worker_alive false),
// and "unreachable" (the gateway itself does not answer).  Each change of state is dispatched as
// a "sovd-health" event on window ({detail: {state, previous, body}}), and an outage of the ROS
// worker is remembered and shown ("was unavailable for 3.2 s") once it is over.
//
// The panel says what an operator wants to know, in words: is the ROS worker up, are reads
// answered from memory, is anybody waiting, are streams dropping frames, faults and log lines.
// "Raw counters" opens every counter of /health, section by section, as the gateway names them.
// When the faults left by absent nodes change, "sovd-faults-left" is dispatched (faults.js).

import { describe, get } from "./api.js";
import { fill, formatAge, formatBytes, formatTime, h } from "./dom.js";

const POLL_MS = 1000;
const TIMEOUT_MS = 3000;
const MIN_LOOKUPS = 10;   // reads before the share answered from memory means something
// Why pooled topics were let go (x-medkit-data-provider.evictions), in an operator's words.
const EVICTIONS = {
  graph: "whose publishers left",
  type_change: "whose type changed",
  lru: "to make room for others",
  idle: "unread for a while",
  manual: "on request (sovd-probe evict)",
  shutdown: "at a shutdown",
  bytes: "to stay within the memory budget",
};

const plural = (n, one, many = `${one}s`) => `${n} ${n === 1 ? one : many}`;

/** The operator's lines for one /health answer: [key, text, tone] ("ok", "warn", "bad" or ""). */
export function healthLines(body) {
  const p = body["x-medkit-data-provider"] || {};
  const e = body["x-medkit-subscription-executor"] || {};
  const s = body["x-medkit-streams"] || {};
  const f = body["x-medkit-faults"] || {};
  const l = body["x-medkit-logs"] || {};
  const lines = [];
  const lookups = (p.pool_hits || 0) + (p.pool_misses || 0);
  lines.push(["topics", `Reading ${plural(p.pool_size || 0, "topic")} (up to ${p.pool_cap}), `
    + `${formatBytes(p.pool_bytes || 0)} of ${formatBytes(p.pool_bytes_cap)} held`, ""]);
  if (lookups >= MIN_LOOKUPS) {
    const hits = Math.round((100 * (p.pool_hits || 0)) / lookups);
    lines.push(["reads", `${hits} % of ${lookups} reads answered from memory; the others waited for a `
      + "topic's first message", ""]);
  }
  const waiting = p.concurrent_cold_waits || 0;
  lines.push(["waiting", waiting ? `${plural(waiting, "reader")} waiting for a topic's first message `
    + `(at most ${p.cold_wait_cap} at once)` : "Nobody is waiting for a topic's first message",
    waiting && waiting >= p.cold_wait_cap ? "warn" : ""]);
  const causes = Object.entries(p.evictions || {}).filter(([, n]) => n > 0);
  if (causes.length) {
    lines.push(["dropped", `Let go of ${plural(p.evictions_total || 0, "topic")}: `
      + causes.map(([cause, n]) => `${n} ${EVICTIONS[cause] || cause}`).join(", "), ""]);
  }
  const dropped = s.frames_dropped || 0;
  lines.push(["streams", `${plural(s.open_streams || 0, "live stream")}, ${plural(s.active_subscriptions || 0,
    "subscription")} (up to ${s.max_subscriptions}), ${plural(s.active_triggers || 0, "trigger")}; `
    + (dropped ? `${plural(dropped, "frame")} dropped for slow clients` : "no frame dropped"), dropped ? "warn" : ""]);
  const queue = e.queue_depth || 0;
  lines.push(["work", (queue ? `${plural(queue, "command")} waiting for the ROS worker`
    : "No command waiting for the ROS worker")
    + (e.watchdog_trips ? `; it was stuck ${plural(e.watchdog_trips, "time")}` : ""),
    e.watchdog_trips ? "warn" : ""]);
  lines.push(["faults", (f.active ? `${plural(f.active, "active fault")} (${f.confirmed || 0} confirmed)`
    : "No active fault")
    + (f.store_write_errors ? `; the fault store failed ${plural(f.store_write_errors, "write")}` : ""),
    f.store_write_errors ? "bad" : f.active ? "warn" : "ok"]);
  lines.push(["logs", `${plural(l.logs_buffered || 0, "log line")} kept from ${plural(l.logs_nodes || 0, "node")}`
    + (l.logs_dropped ? `; ${l.logs_dropped} dropped past the node cap` : ""), ""]);
  return lines;
}

export class HealthPanel {
  constructor(body, badge) {
    this.body = body;
    this.badge = badge;
    this.state = "unknown";
    this.downSince = null;
    this.lastOutage = null;
    this.timer = null;
    this.last = null;          // the last /health answer
    this.leftKey = "";
    this.rawOpen = false;
  }

  start() {
    this._poll();
  }

  async _poll() {
    let body = null;
    let error = null;
    try {
      body = await get("health", { timeout: TIMEOUT_MS });
    } catch (e) {
      error = e;
    }
    this._show(body, error);
    this.timer = setTimeout(() => this._poll(), POLL_MS);
  }

  _stateOf(body) {
    if (!body) return "unreachable";
    const executor = body["x-medkit-subscription-executor"] || {};
    if (!executor.worker_alive) return "unavailable";
    return executor.degraded ? "degraded" : "healthy";
  }

  _show(body, error) {
    const state = this._stateOf(body);
    const previous = this.state;
    const now = Date.now();
    const down = state === "unavailable" || state === "unreachable";
    if (down && this.downSince === null) this.downSince = now;
    if (!down && this.downSince !== null) {
      this.lastOutage = { from: this.downSince, ms: now - this.downSince, kind: previous };
      this.downSince = null;
    }
    this.state = state;
    if (body) this.last = body;
    const labels = {
      healthy: "ROS worker alive",
      degraded: "ROS worker degraded",
      unavailable: "ROS worker unavailable",
      unreachable: "gateway unreachable",
    };
    this.badge.dataset.state = state;
    this.badge.textContent = labels[state];
    this.badge.title = error ? describe(error) : "";
    document.body.dataset.health = state;

    const rows = [];
    if (down) {
      rows.push(h("p", { class: "alert", role: "alert" },
        state === "unavailable"
          ? `The ROS worker is down or being restarted (${formatAge(now - this.downSince)} so far). ` +
            "The gateway restarts it by itself; live values resume when it is back."
          : `The gateway does not answer (${describe(error)}). Retrying every second.`));
    } else if (this.lastOutage) {
      rows.push(h("p", { class: "note" },
        `Recovered: ${this.lastOutage.kind === "unreachable" ? "the gateway" : "the ROS worker"} was ` +
        `unavailable for ${formatAge(this.lastOutage.ms)} (from ${formatTime(new Date(this.lastOutage.from))}).`));
    }
    if (state === "degraded") {
      rows.push(h("p", { class: "alert" }, "A task of the ROS worker is taking too long: answers may be late. "
        + "The gateway restarts the worker if it stays stuck."));
    }
    if (body) rows.push(this._words(body), this._raw(body));
    fill(this.body, rows);
    this.body.classList.remove("muted");
    if (state !== previous) {
      window.dispatchEvent(new CustomEvent("sovd-health", { detail: { state, previous, body } }));
    }
    const left = (body && body["x-medkit-faults"]) || {};
    const leftKey = `${left.left_by_absent_nodes || 0}:${(left.absent_nodes || []).join(",")}`;
    if (body && leftKey !== this.leftKey) {
      this.leftKey = leftKey;
      window.dispatchEvent(new CustomEvent("sovd-faults-left", { detail: left }));
    }
  }

  _words(body) {
    return h("ul", { class: "health-lines" }, healthLines(body).map(([key, text, tone]) =>
      h("li", { dataset: { key, tone: tone || null } }, text)));
  }

  /** Every counter of /health, by section, behind one click (kept open across polls). */
  _raw(body) {
    const sections = Object.entries(body).filter(([, v]) => v && typeof v === "object" && !Array.isArray(v));
    const raw = h("details", { class: "raw-counters", open: this.rawOpen },
      h("summary", {}, "Raw counters"),
      sections.map(([name, section]) => h("table", { class: "counters", dataset: { section: name } },
        h("caption", {}, name),
        Object.entries(section).flatMap(([key, value]) => (value && typeof value === "object" && !Array.isArray(value)
          ? Object.entries(value).map(([k, v]) => [`${key}.${k}`, v]) : [[key, value]]))
          .map(([key, value]) => h("tr", { dataset: { key } }, h("th", {}, key),
            h("td", {}, Array.isArray(value) ? value.join(", ") : String(value)))))));
    raw.addEventListener("toggle", () => { this.rawOpen = raw.open; });
    return raw;
  }
}
