// The health panel and the badge in the header: GET health every POLL_MS, drawn as it comes.
//
// States: "healthy", "degraded" (a ROS task ran past the watchdog threshold), "unavailable"
// (the ROS worker is down or being restarted: /health still answers, with worker_alive false),
// and "unreachable" (the gateway itself does not answer).  Each change of state is dispatched as
// a "sovd-health" event on window ({detail: {state, previous, body}}), and an outage of the ROS
// worker is remembered and shown ("was unavailable for 3.2 s") once it is over.

import { describe, get } from "./api.js";
import { fill, formatAge, formatBytes, h } from "./dom.js";

const POLL_MS = 1000;
const TIMEOUT_MS = 3000;

export class HealthPanel {
  constructor(body, badge) {
    this.body = body;
    this.badge = badge;
    this.state = "unknown";
    this.downSince = null;
    this.lastOutage = null;
    this.timer = null;
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
      const at = new Date(this.lastOutage.from).toLocaleTimeString();
      rows.push(h("p", { class: "note" },
        `Recovered: ${this.lastOutage.kind === "unreachable" ? "the gateway" : "the ROS worker"} was ` +
        `unavailable for ${formatAge(this.lastOutage.ms)} (from ${at}).`));
    }
    if (body) rows.push(this._counters(body));
    fill(this.body, rows);
    this.body.classList.remove("muted");
    if (state !== previous) {
      window.dispatchEvent(new CustomEvent("sovd-health", { detail: { state, previous, body } }));
    }
  }

  _counters(body) {
    const p = body["x-medkit-data-provider"] || {};
    const e = body["x-medkit-subscription-executor"] || {};
    const s = body["x-medkit-streams"] || {};
    const evictions = Object.entries(p.evictions || {}).filter(([, n]) => n > 0);
    const lookups = (p.pool_hits || 0) + (p.pool_misses || 0);
    const row = (name, value, key) => h("tr", { dataset: { key } }, h("th", {}, name), h("td", {}, value));
    return h("div", {},
      h("table", { class: "counters" },
        h("caption", {}, "Subscription pool"),
        row("pooled topics", `${p.pool_size} / ${p.pool_cap}`, "pool"),
        row("pool memory", `${formatBytes(p.pool_bytes)} / ${formatBytes(p.pool_bytes_cap)}`, "bytes"),
        row("hits / misses", `${p.pool_hits} / ${p.pool_misses}` +
            (lookups ? ` (${Math.round((100 * p.pool_hits) / lookups)} % hits)` : ""), "hits"),
        row("cold waits", `${p.concurrent_cold_waits} / ${p.cold_wait_cap}`, "cold"),
        row("evictions", String(p.evictions_total), "evictions")),
      h("ul", { class: "evictions", "aria-label": "evictions by cause" },
        evictions.length
          ? evictions.map(([cause, n]) => h("li", { dataset: { cause } }, `${cause} `, h("b", {}, String(n))))
          : h("li", { class: "muted" }, "none")),
      h("table", { class: "counters" },
        h("caption", {}, "Streams"),
        row("open streams", String(s.open_streams), "streams"),
        row("subscriptions", `${s.active_subscriptions} / ${s.max_subscriptions}`, "subscriptions"),
        row("frames sent / dropped", `${s.frames_sent} / ${s.frames_dropped}`, "frames")),
      h("table", { class: "counters" },
        h("caption", {}, "ROS worker"),
        row("queue", `${e.queue_depth} (max seen ${e.queue_max_depth_observed})`, "queue"),
        row("tasks done / failed", `${e.tasks_completed} / ${e.tasks_failed}`, "tasks"),
        row("watchdog trips", String(e.watchdog_trips), "watchdog")));
  }
}
