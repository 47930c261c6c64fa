// "Notify me when…": a LeaveRange trigger on a numeric field of the data item, and its events.
//
//   start   POST {entity}/triggers {LeaveRange, lower_bound, upper_bound, path, multishot}, then an
//           EventSource on its event_source; each event is listed (newest first, at most MAX_SHOWN)
//           with its time in the page's one format; the trigger's id is the gateway's business, not
//           shown (the form keeps it in data-trigger)
//   stop    DELETE (the gateway ends the stream at once), then the EventSource is closed
//
// The trigger lives LIFETIME_S at most, so a page that dies does not leave it behind for long.

import { describe, eventSource, request } from "./api.js";
import { h, timeEl } from "./dom.js";
import { valueAt } from "./jsontree.js";

const LIFETIME_S = 3600;
const MAX_SHOWN = 20;
const CLOSE_WAIT_MS = 2000;   // how long stop waits for the gateway to end the stream

/** The JSON Pointer (RFC 6901) of a path of keys and indexes. */
export function pointer(path) {
  return path.map((key) => "/" + String(key).replaceAll("~", "~0").replaceAll("/", "~1")).join("");
}

export class NotifyForm {
  /** entityPath: "/api/v1/apps/x"; resource: the data item's API path; fields(): numeric paths picked */
  constructor(container, { entityPath, resource }) {
    this.entityPath = entityPath;
    this.resource = resource;
    this.trigger = null;
    this.source = null;
    this.path = h("input", { type: "text", placeholder: "/temperature", "aria-label": "field (JSON Pointer)",
                             size: 18 });
    this.lower = h("input", { type: "number", step: "any", placeholder: "lower", "aria-label": "lower bound" });
    this.upper = h("input", { type: "number", step: "any", placeholder: "upper", "aria-label": "upper bound" });
    this.button = h("button", { type: "submit" }, "Notify me");
    this.state = h("span", { class: "muted notify-state" });
    this.list = h("ol", { class: "notify-events", reversed: true });
    this.form = h("form", { class: "notify", onsubmit: (event) => { event.preventDefault(); this._toggle(); } },
      h("h3", {}, "Notify me when…"),
      h("p", { class: "muted" }, "the field ", this.path, " leaves ", this.lower, " … ", this.upper, " ",
        this.button, " ", this.state),
      this.list);
    container.append(this.form);
  }

  /** Prefill the field with a path the user picked in the value tree. */
  suggest(path) {
    if (!this.trigger && !this.path.value) this.path.value = pointer(path);
  }

  async _toggle() {
    if (this.trigger) {
      await this.destroy();
      return;
    }
    const lower = Number.parseFloat(this.lower.value);
    const upper = Number.parseFloat(this.upper.value);
    if (!Number.isFinite(lower) || !Number.isFinite(upper) || lower > upper) {
      this.state.textContent = "give two numbers, the lower one first";
      return;
    }
    this.button.disabled = true;
    try {
      this.trigger = await request("POST", `${this.entityPath}/triggers`, { body: {
        resource: this.resource, path: this.path.value.trim(), multishot: true, lifetime: LIFETIME_S,
        trigger_condition: { condition_type: "LeaveRange", lower_bound: lower, upper_bound: upper },
      } });
    } catch (error) {
      this.state.textContent = describe(error);
      return;
    } finally {
      this.button.disabled = false;
    }
    this.button.textContent = "Stop";
    this.state.textContent = "watching";
    this.form.dataset.trigger = this.trigger.id;
    const source = eventSource(this.trigger.event_source);
    this.source = source;
    source.onmessage = (message) => this._event(JSON.parse(message.data));
    source.onerror = () => {
      source.close();
      if (this.source === source) this.state.textContent = "the stream ended";
    };
  }

  _event(event) {
    const value = event.payload !== undefined
      ? valueAt(event.payload, this._keys()) : undefined;
    const text = event.error !== undefined ? `error: ${event.error}` : `left the range: ${JSON.stringify(value)}`;
    this.list.prepend(h("li", {}, timeEl(event.timestamp, { withMs: true }), " ", text));
    while (this.list.children.length > MAX_SHOWN) this.list.lastChild.remove();
    this.form.dataset.events = String(Number(this.form.dataset.events || 0) + 1);
  }

  _keys() {
    const text = this.trigger && this.trigger.path ? this.trigger.path : "";
    return text ? text.slice(1).split("/").map((k) => k.replaceAll("~1", "/").replaceAll("~0", "~"))
      .map((k) => (/^(0|[1-9][0-9]*)$/.test(k) ? Number(k) : k)) : [];
  }

  /** Delete the trigger (the gateway ends its stream at once), then close the stream. */
  async destroy() {
    const trigger = this.trigger;
    const source = this.source;
    this.trigger = null;
    this.source = null;
    this.button.textContent = "Notify me";
    delete this.form.dataset.trigger;
    if (trigger) {
      this.state.textContent = "stopped";
      const ended = source ? new Promise((resolve) => {
        const timer = setTimeout(resolve, CLOSE_WAIT_MS);
        source.onerror = () => { clearTimeout(timer); resolve(); };
      }) : Promise.resolve();
      try {
        await request("DELETE", `${this.entityPath}/triggers/${trigger.id}`, { keepalive: true });
        await ended;
      } catch (error) {
        this.state.textContent = describe(error);
      }
    }
    if (source) source.close();
  }
}
