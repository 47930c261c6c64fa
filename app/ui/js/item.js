// The view of one data item: its live value through one cyclic subscription, its metadata, a
// time plot of the fields the user picks, an image canvas for sensor_msgs/msg/Image, and the
// publish form when the gateway allows publishing.
//
// Frames are taken as they come (the plot keeps every one), but the page is drawn at most once
// per animation frame, with the newest frame only: at `fast` (20 frames a second) the JSON tree
// is patched in place, not rebuilt, and a hidden tab draws nothing.  A tab hidden for longer than
// HIDDEN_CLOSE_MS gives its stream back; it opens a new one when it is shown again.  destroy()
// ends the stream (DELETE) when the user leaves the view or the page.

import { describe, get, getToken, whoAmI } from "./api.js";
import { fill, formatAge, h } from "./dom.js";
import { IMAGE_TYPE, ImageCanvas } from "./image.js";
import { JsonTree, numericValue, pathText, valueAt } from "./jsontree.js";
import { NotifyForm } from "./notify.js"; // "notify me when…": a LeaveRange trigger
import { TimePlot } from "./plot.js";
import { PublishForm } from "./publish.js";
import { Subscription } from "./stream.js";

const INTERVALS = ["fast", "normal", "slow"];
const HIDDEN_CLOSE_MS = 5000;
// Drawn at most 10 times a second: at `fast` (20 frames a second) every other frame is only
// plotted.  Painting, not script, is what a live value costs a browser without a GPU.
const MIN_DRAW_MS = 100;
const REASONS = {
  "no-publishers": "nobody publishes this topic",
  "not-in-graph": "the topic is not in the ROS graph",
  timeout: "no message arrived within the sample timeout",
  "unsupported-type": "its message type is not installed on the gateway",
  evicted: "it was just evicted from the gateway's pool",
  shutdown: "the gateway is shutting down",
};

function schemaAt(schema, path) {
  let s = schema;
  for (const key of path) {
    if (!s) return undefined;
    s = typeof key === "number" ? s.items : s.properties && s.properties[key];
  }
  return s;
}

export class ItemView {
  /** route: {collection, entityId, topic (without the leading /)}; options: {capabilities} */
  constructor(container, route, { capabilities }) {
    this.container = container;
    this.route = route;
    this.capabilities = capabilities || {};
    this.topic = `/${route.topic}`;
    this.entityPath = `/api/v1/${route.collection}/${route.entityId}`;
    this.interval = "normal";
    this.sub = null;
    this.latest = null;      // {payload, t (gateway ms), arrived (performance.now())}
    this.error = null;       // the error body of the newest error frame, until a data frame comes
    this.frames = 0;
    this.pending = 0;        // requestAnimationFrame id (-1: waiting for MIN_DRAW_MS)
    this.drawnAt = 0;        // performance.now() of the last draw
    this.destroyed = false;
    this.timers = [];
    this.onVisibility = () => this._visibility();
    this.onToken = () => {
      if (this.capabilities.authentication && !this.sub && !this.destroyed && !document.hidden && getToken()) {
        this._subscribe();   // the legacy token typed in the header (a sign-in makes a new view)
      }
    };
  }

  async start() {
    this._skeleton();
    try {
      const detail = await get(this.entityPath);
      this.dataListing = detail.data;
      const listing = await get(detail.data);
      this.item = (listing.items || []).find((i) => i.id === this.topic) || null;
    } catch (error) {
      if (this.destroyed) return;
      this._fatal(`This data item cannot be shown: ${describe(error)}`);
      return;
    }
    if (this.destroyed) return;
    const ext = (this.item && this.item["x-medkit"]) || {};
    this.type = (ext.ros2 && ext.ros2.type) || null;
    this.typeInfo = ext.type_info || null;
    this.schema = this.typeInfo ? this.typeInfo.schema : undefined;
    this.dataPath = `${this.dataListing}/${this.route.topic}`;
    if (!this.item) {
      this.notice.textContent = `${this.topic} is not among the data items of ${this.route.entityId} now; ` +
        "it is read all the same.";
    }
    this._describe();
    this.tree = new JsonTree(this.valueEl, {
      schema: this.schema,
      onPick: (path) => this._pick(path),
      isPicked: (key) => this.plot.has(key),
    });
    this.plot = new TimePlot(this.plotEl, (path, data) => numericValue(valueAt(data, path), schemaAt(this.schema, path)));
    if (this.type === IMAGE_TYPE) {
      const canvas = h("canvas", { class: "image", width: 1, height: 1, "aria-label": "camera image" });
      this.imageMessage = h("p", { class: "muted" });
      this.imageEl.append(canvas, this.imageMessage);
      this.imageEl.hidden = false;
      this.image = new ImageCanvas(canvas);
    }
    if (this.capabilities.publishing) {
      this.publish = new PublishForm(this.publishEl, {
        dataPath: this.dataPath, topic: this.topic, type: this.type, typeInfo: this.typeInfo,
        authentication: this.capabilities.authentication,
      });
    }
    if (this.capabilities.triggers) { // "notify me when…" (notify.js)
      this.notify = new NotifyForm(this.notifyEl, { entityPath: this.entityPath, resource: this.dataPath });
    }
    document.addEventListener("visibilitychange", this.onVisibility);
    window.addEventListener("sovd-token", this.onToken);
    this.timers.push(setInterval(() => this._schedule(), 1000)); // the age goes on when frames stop
    this._subscribe();
  }

  _skeleton() {
    this.title = h("h2", {}, this.topic);
    this.typeEl = h("span", { class: "type" });
    this.streamEl = h("span", { class: "badge", dataset: { state: "connecting" } }, "connecting");
    this.streamDetail = h("span", { class: "muted stream-detail" });
    this.notice = h("p", { class: "muted" });
    this.banner = h("p", { class: "alert stream-error", role: "alert", hidden: true });
    this.metaEl = h("dl", { class: "meta" });
    this.intervalEl = h("div", { class: "segmented", role: "radiogroup", "aria-label": "interval" },
      INTERVALS.map((name) => h("button", {
        type: "button", role: "radio", "aria-checked": String(name === this.interval), dataset: { interval: name },
        onclick: () => this._setInterval(name),
      }, name)));
    this.valueEl = h("div", { class: "json", "aria-label": "value" });
    this.plotEl = h("div", {});
    this.imageEl = h("div", { class: "image-box", hidden: true });
    this.publishEl = h("div", {});
    this.notifyEl = h("div", {}); // "notify me when…" (notify.js)
    fill(this.container,
      h("div", { class: "item-head" }, this.title, this.typeEl),
      h("div", { class: "item-controls" }, h("span", { class: "muted" }, "under "),
        h("code", {}, this.entityPath.replace(/^\/api\/v1\//, "")), this.streamEl, this.streamDetail,
        this.intervalEl),
      this.notice, this.banner, this.metaEl, this.imageEl, this.plotEl,
      h("h3", {}, "Value"), this.valueEl, this.notifyEl, this.publishEl);
    this.container.dataset.frames = "0";
  }

  _fatal(text) {
    this.failed = true;
    this.streamEl.dataset.state = "error";
    this.streamEl.textContent = "not available";
    this.banner.hidden = false;
    this.banner.textContent = text;
  }

  _describe() {
    this.typeEl.textContent = this.type || "type unknown";
  }

  _subscribe() {
    if (this.capabilities.cyclic_subscriptions === false) {
      // Identities on the gateway, and this page may not make a cyclic subscription (not signed in, or a
      // viewer): the value is read once a second instead, as the role may.
      this._poll();
      return;
    }
    if (this.capabilities.authentication && !getToken()) {
      // The gateway wants the token to make a subscription: wait for it (onToken), unrefused.
      this._streamState("waiting");
      this.streamDetail.textContent = "live values need the gateway's bearer token (top of the page)";
      return;
    }
    const query = this.type === IMAGE_TYPE ? "?bytes=base64" : "";
    this.sub = new Subscription(this.entityPath, `${this.dataPath}${query}`, this.interval, {
      onFrame: (frame) => this._frame(frame),
      onState: (state, detail) => this._streamState(state, detail),
    });
    this.sub.open();
  }

  _poll() {
    this._streamState("polling");
    this.streamDetail.textContent = whoAmI() ? `read every second: a ${whoAmI().role} may not make cyclic subscriptions`
      : "read every second: sign in for a live stream";
    const query = this.type === IMAGE_TYPE ? "?bytes=base64" : "";
    const read = async () => {
      if (this.destroyed || document.hidden) return;
      try {
        this._frame({ timestamp: new Date().toISOString(), payload: await get(`${this.dataPath}${query}`) });
      } catch (error) {
        this._frame({ timestamp: new Date().toISOString(), error: error.body || { message: describe(error) } });
      }
    };
    read();
    this.timers.push(setInterval(read, 1000));
  }

  _streamState(state, detail) {
    if (this.destroyed) return;
    const labels = { connecting: "connecting", live: "live", retrying: "reconnecting", closed: "closed",
                     waiting: "waiting for the token", polling: "polling" };
    this.streamEl.dataset.state = state;
    this.streamEl.textContent = labels[state] || state;
    this.streamDetail.textContent = state === "retrying" && detail ? describe(detail) : "";
  }

  async _setInterval(name) {
    this.interval = name;
    for (const b of this.intervalEl.querySelectorAll("button")) {
      b.setAttribute("aria-checked", String(b.dataset.interval === name));
    }
    try {
      if (this.sub) await this.sub.setInterval(name);
    } catch (error) {
      this.streamDetail.textContent = `interval not changed: ${describe(error)}`;
    }
  }

  _pick(path) {
    if (this.notify) this.notify.suggest(path);
    this.plot.toggle(pathText(path), path);
    this.tree.refreshPicks();
    this._schedule();
  }

  _frame(frame) {
    if (this.destroyed) return;
    this.frames += 1;
    const t = Date.parse(frame.timestamp);
    if (frame.payload) {
      this.latest = { payload: frame.payload, t, arrived: performance.now() };
      this.error = null;
      const ext = frame.payload["x-medkit"] || {};
      if (ext.status === "data") this.plot.push(t, frame.payload.data);
    } else if (frame.error) {
      this.error = frame.error;
    }
    this._schedule();
  }

  /** Draw the newest frame soon: at the next animation frame, but no sooner than MIN_DRAW_MS after the last. */
  _schedule() {
    if (this.pending || this.destroyed) return;
    const wait = this.drawnAt + MIN_DRAW_MS - performance.now();
    if (wait > 0) {
      this.pending = -1;
      this.delay = setTimeout(() => {
        this.pending = requestAnimationFrame(() => this._render());
      }, wait);
    } else {
      this.pending = requestAnimationFrame(() => this._render());
    }
  }

  _render() {
    this.pending = 0;
    if (this.destroyed) return;
    this.drawnAt = performance.now();
    this.container.dataset.frames = String(this.frames);
    if (this.error) {
      const e = this.error;
      this.banner.hidden = false;
      this.banner.textContent = `${e.message || "error"} (${e.vendor_code || e.error_code || "error"}). ` +
        (this.latest ? "The value below is the last one received." : "");
    } else if (this.latest) {
      this.banner.hidden = true;
    }
    this.container.classList.toggle("stale", Boolean(this.error));
    if (!this.latest) return;
    const { payload, t, arrived } = this.latest;
    const ext = payload["x-medkit"] || {};
    const type = (ext.ros2 && ext.ros2.type) || this.type;
    if (type && type !== this.type) {
      this.type = type;
      this._describe();
    }
    const ageMs = typeof ext.timestamp === "number" ? t - ext.timestamp / 1e6 + (performance.now() - arrived) : NaN;
    const status = ext.status === "data" ? "data" : `metadata_only${ext.reason ? ` (${ext.reason})` : ""}`;
    this._meta({
      status,
      publishers: String(ext.publisher_count ?? "–"),
      subscribers: String(ext.subscriber_count ?? "–"),
      age: ext.status === "data" ? formatAge(ageMs) : "–",
    });
    if (ext.status === "data") {
      this.noValue = null;
      this.tree.update(payload.data);
      if (this.image) this._drawImage(payload.data);
    } else {
      const text = `No value: ${REASONS[ext.reason] || ext.reason || "no data"}.`;
      if (text !== this.noValue) {
        this.noValue = text;
        fill(this.valueEl, h("p", { class: "muted" }, text));
        this.tree.root = null;
      }
    }
    this.plot.draw();
  }

  /** The metadata row, written in place (only the texts that changed). */
  _meta(values) {
    if (!this.metaCells) {
      this.metaCells = {};
      for (const key of Object.keys(values)) {
        this.metaCells[key] = h("dd", { dataset: { key } });
        this.metaEl.append(h("dt", {}, key), this.metaCells[key]);
      }
    }
    for (const [key, text] of Object.entries(values)) {
      if (this.metaCells[key].textContent !== text) this.metaCells[key].textContent = text;
    }
  }

  _drawImage(msg) {
    try {
      this.image.draw(msg);
      this.imageMessage.textContent = `${msg.width} × ${msg.height} ${msg.encoding}`;
    } catch (error) {
      this.imageMessage.textContent = `Not drawn: ${error.message}`;
    }
  }

  _visibility() {
    if (document.hidden) {
      this.hiddenTimer = setTimeout(() => {
        if (this.sub && document.hidden) {
          this.sub.close();
          this.sub = null;
        }
      }, HIDDEN_CLOSE_MS);
    } else {
      clearTimeout(this.hiddenTimer);
      if (!this.sub && !this.destroyed && this.capabilities.cyclic_subscriptions !== false) this._subscribe();
    }
  }

  /** End the stream and stop drawing; resolves when the stream has ended. */
  destroy({ unloading = false } = {}) {
    this.destroyed = true;
    if (this.pending > 0) cancelAnimationFrame(this.pending);
    clearTimeout(this.delay);
    for (const timer of this.timers) clearInterval(timer);
    clearTimeout(this.hiddenTimer);
    document.removeEventListener("visibilitychange", this.onVisibility);
    window.removeEventListener("sovd-token", this.onToken);
    if (this.publish) this.publish.destroy();
    if (this.notify) this.notify.destroy();
    const sub = this.sub;
    this.sub = null;
    return sub ? sub.close({ unloading }) : Promise.resolve();
  }
}
