// The Logs panel (issue 22): a live tail of the robot's /rosout lines, as the gateway keeps them.
//
// It reads GET components/<host>/logs?severity=<minimum> every POLL_MS while the tab is shown
// (the host component hosts every app, so its logs are every node's) and appends the lines it
// has not shown yet (ids only grow), newest last; the view follows the tail unless the reader
// has scrolled up.  Changing the severity starts over.  At most MAX_ROWS lines stay on screen.
// A failed read is shown in the panel's status line and retried at the next round; while the
// health panel says the ROS worker is away, no read is made.

import { describe, get } from "./api.js";
import { fill, h } from "./dom.js";

const POLL_MS = 1000;
const MAX_ROWS = 300;

function idNumber(item) {
  const n = Number(String(item.id || "").replace(/^log_/, ""));
  return Number.isFinite(n) ? n : 0;
}

export class LogsPanel {
  constructor(body, severity, status) {
    this.body = body;
    this.severity = severity;
    this.status = status;
    this.host = null;
    this.lastId = 0;
    this.timer = null;
    this.generation = 0; // one polling loop at a time: a restart starts a new generation
    this.severity.addEventListener("change", () => this.restart());
    // Paused while the ROS worker is away (health.js says so): its answer would only be a 503.
    this.paused = false;
    window.addEventListener("sovd-health", (event) => {
      this.paused = event.detail.state === "unavailable" || event.detail.state === "unreachable";
    });
  }

  start() {
    this._poll();
  }

  restart() {
    this.generation += 1;
    this.lastId = 0;
    fill(this.body);
    clearTimeout(this.timer);
    this._poll();
  }

  async _poll() {
    const generation = this.generation;
    if (!document.hidden && !this.paused) {
      try {
        await this._read(generation);
      } catch (error) {
        if (generation === this.generation) this.status.textContent = `logs not read: ${describe(error)}`;
        this.host = null; // the host may have been renamed (a new ROS worker, a new graph)
      }
    }
    if (generation === this.generation) this.timer = setTimeout(() => this._poll(), POLL_MS);
  }

  async _read(generation) {
    if (!this.host) {
      const components = await get("components");
      this.host = components.items && components.items[0] ? components.items[0].id : null;
      if (!this.host) {
        this.status.textContent = "no component yet";
        return;
      }
    }
    const asked = this.severity.value;
    const query = asked ? `?severity=${encodeURIComponent(asked)}` : "";
    const answer = await get(`components/${encodeURIComponent(this.host)}/logs${query}`);
    if (generation !== this.generation) return; // the severity changed meanwhile: a new loop reads
    const fresh = (answer.items || []).filter((item) => idNumber(item) > this.lastId);
    const follow = this.body.scrollTop + this.body.clientHeight >= this.body.scrollHeight - 8;
    for (const item of fresh) {
      this.lastId = Math.max(this.lastId, idNumber(item));
      const context = item.context || {};
      this.body.append(h("div", { class: "log-line", dataset: { severity: item.severity, id: item.id } },
        h("span", { class: "log-time" }, String(item.timestamp || "").slice(11, 23)),
        h("span", { class: "log-severity" }, item.severity),
        h("span", { class: "log-node", title: context.file ? `${context.file}:${context.line || ""}` : "" },
          context.node || ""),
        h("span", { class: "log-message" }, item.message)));
    }
    while (this.body.childElementCount > MAX_ROWS) this.body.firstElementChild.remove();
    if (follow && fresh.length) this.body.scrollTop = this.body.scrollHeight;
    this.status.textContent = `${this.body.childElementCount} lines · updated ${new Date().toLocaleTimeString()}`;
  }
}
