// The Logs panel: a live tail of the robot's /rosout lines as the gateway keeps them, for the whole
// robot or for the entity the page looks at (scope.js).
//
// It reads GET <scope>/logs?severity=<minimum> every POLL_MS while the tab is shown (the whole
// robot's are the host component's, which hosts every app) and appends the lines it has not shown
// yet (ids only grow), newest last; the view follows the tail unless the reader has scrolled up.
// Changing the severity or the scope starts over.  At most MAX_ROWS lines stay on screen.  The node
// filter (the nodes seen so far) and the search box (words of the message or the node) hide the
// other lines; they ask the gateway nothing.  A failed read is shown in the panel's status line and
// retried at the next round; while the health panel says the ROS worker is away, no read is made.

import { describe, get } from "./api.js";
import { fill, formatTime, h, timeEl } from "./dom.js";
import { current, pathOf, scopeSwitch } from "./scope.js";

const POLL_MS = 1000;
const MAX_ROWS = 300;

function idNumber(item) {
  const n = Number(String(item.id || "").replace(/^log_/, ""));
  return Number.isFinite(n) ? n : 0;
}

export class LogsPanel {
  constructor({ body, severity, node, search, status, scope }) {
    this.body = body;
    this.severity = severity;
    this.node = node;
    this.search = search;
    this.status = status;
    this.host = null;
    this.lastId = 0;
    this.timer = null;
    this.nodes = new Set();
    this.generation = 0; // one polling loop at a time: a restart starts a new generation
    this.severity.addEventListener("change", () => this.restart());
    this.node.addEventListener("change", () => this.filter());
    this.search.addEventListener("input", () => this.filter());
    scopeSwitch(scope);
    window.addEventListener("sovd-scope", () => this.restart());
    // Paused while the ROS worker is away (health.js says so): its answer would only be a 503.
    this.paused = false;
    window.addEventListener("sovd-health", (event) => {
      this.paused = event.detail.state === "unavailable" || event.detail.state === "unreachable";
    });
  }

  start() {
    this.restart();   // one polling loop, whatever the scope's changes started before
  }

  restart() {
    this.generation += 1;
    this.lastId = 0;
    this.nodes.clear();
    fill(this.node, h("option", { value: "" }, "all nodes"));
    fill(this.body);
    clearTimeout(this.timer);
    this._poll();
  }

  /** Whether a line passes the node filter and the search box. */
  _shows(line) {
    const node = this.node.value;
    const words = this.search.value.trim().toLowerCase();
    return (!node || line.dataset.node === node)
      && (!words || `${line.dataset.node} ${line.lastChild.textContent}`.toLowerCase().includes(words));
  }

  filter() {
    for (const line of this.body.children) line.hidden = !this._shows(line);
    this._count();
  }

  _count() {
    const shown = [...this.body.children].filter((line) => !line.hidden).length;
    const total = this.body.childElementCount;
    this.status.textContent = `${shown === total ? total : `${shown} of ${total}`} lines · `
      + `updated ${formatTime(new Date())}`;
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

  async _path() {
    const scope = current();
    if (scope) return pathOf(scope, "logs");
    if (!this.host) {
      const components = await get("components");
      this.host = components.items && components.items[0] ? components.items[0].id : null;
    }
    return this.host ? `components/${encodeURIComponent(this.host)}/logs` : null;
  }

  async _read(generation) {
    const path = await this._path();
    if (!path) {
      this.status.textContent = "no component yet";
      return;
    }
    const asked = this.severity.value;
    const query = asked ? `?severity=${encodeURIComponent(asked)}` : "";
    const answer = await get(`${path}${query}`);
    if (generation !== this.generation) return; // the severity or scope changed meanwhile: a new loop reads
    const fresh = (answer.items || []).filter((item) => idNumber(item) > this.lastId);
    const follow = this.body.scrollTop + this.body.clientHeight >= this.body.scrollHeight - 8;
    for (const item of fresh) {
      this.lastId = Math.max(this.lastId, idNumber(item));
      const context = item.context || {};
      const node = context.node || "";
      if (node && !this.nodes.has(node)) this._addNode(node);
      const line = h("div", { class: "log-line", dataset: { severity: item.severity, id: item.id, node } },
        h("span", { class: "log-time" }, timeEl(item.timestamp, { withMs: true })),
        h("span", { class: "log-severity" }, item.severity),
        h("span", { class: "log-node", title: context.file ? `${context.file}:${context.line || ""}` : "" }, node),
        h("span", { class: "log-message" }, item.message));
      line.hidden = !this._shows(line);
      this.body.append(line);
    }
    while (this.body.childElementCount > MAX_ROWS) this.body.firstElementChild.remove();
    if (follow && fresh.length) this.body.scrollTop = this.body.scrollHeight;
    this._count();
  }

  _addNode(node) {
    this.nodes.add(node);
    const options = [...this.nodes].sort().map((n) => h("option", { value: n }, n));
    const chosen = this.node.value;
    fill(this.node, h("option", { value: "" }, "all nodes"), options);
    this.node.value = chosen;
  }
}
