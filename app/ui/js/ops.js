// The Operations panel of an app (#/apps/<id>/operations): its services and actions, a form for
// each made from the request's or goal's default value, Run, the answer or the goal's live
// status and feedback (polled while it runs), and Cancel.
//
// The form is the default value as JSON text: what is typed is sent as "parameters", and the
// gateway's own check answers a field that does not fit (its message names the field).  Run and
// Cancel are shown only when the gateway allows operations (capabilities.operation_execution);
// the page's bearer token (api.js) goes with them.

import { describe, request } from "./api.js";
import { fill, h } from "./dom.js";

const POLL_MS = 500;

export class OperationsView {
  constructor(container, { collection, entityId }, { capabilities }) {
    this.container = container;
    this.base = `${collection}/${entityId}/operations`;
    this.entityId = entityId;
    this.allowed = Boolean(capabilities.operation_execution);
    this.timers = new Set();
    this.failed = false;
    this.destroyed = false;
  }

  async start() {
    fill(this.container, h("h2", {}, `Operations of ${this.entityId}`), h("p", { class: "muted" }, "loading…"));
    let items;
    try {
      items = (await request("GET", this.base)).items;
    } catch (error) {
      this.failed = true;
      fill(this.container, h("h2", {}, `Operations of ${this.entityId}`),
        h("p", { class: "form-status", role: "alert" }, `The operations could not be loaded: ${describe(error)}`));
      return;
    }
    if (this.destroyed) return;
    fill(this.container, h("h2", {}, `Operations of ${this.entityId}`),
      items.length ? null : h("p", { class: "muted" }, "This app offers no services or actions."),
      this.allowed ? null : h("p", { class: "muted" }, "Read-only: the gateway does not allow operations "
        + "(--allow-operations)."),
      items.map((item) => this._operation(item)));
  }

  _operation(item) {
    const ext = item["x-medkit"] || {};
    const ros2 = ext.ros2 || {};
    const action = ros2.kind === "action";
    const defaults = ((ext.type_info || {}).default_value || {})[action ? "goal" : "request"] || {};
    const input = h("textarea", { name: "parameters", rows: 4, spellcheck: "false",
                                  "aria-label": `${item.id} ${action ? "goal" : "request"}` });
    input.value = JSON.stringify(defaults, null, 2);
    const status = h("p", { class: "form-status", role: "status" });
    const output = h("pre", { class: "op-output" });
    const cancel = h("button", { type: "button", class: "op-cancel", hidden: true }, "Cancel");
    const run = h("button", { type: "submit" }, "Run");
    const form = h("form", { class: "publish operation", dataset: { operation: item.id }, novalidate: true },
      h("h3", {}, item.name, h("span", { class: "muted" }, ` ${action ? "action" : "service"} ${ros2[ros2.kind] || ""}`)),
      h("p", { class: "muted" }, ros2.type || ""),
      this.allowed ? [h("label", {}, action ? "goal" : "request"), input,
                      h("div", { class: "actions" }, run, cancel)] : null,
      status, output);
    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      let parameters;
      try {
        parameters = JSON.parse(input.value || "{}");
      } catch (error) {
        status.textContent = `Not JSON: ${error.message}`;
        return;
      }
      status.textContent = "running…";
      output.textContent = "";
      try {
        const answer = await request("POST", `${this.base}/${item.id}/executions`, { body: { parameters },
                                                                                     timeout: 3_700_000 });
        if (action) this._follow(item, answer.id, status, output, cancel);
        else {
          status.textContent = "done";
          output.textContent = JSON.stringify(answer.parameters, null, 2);
        }
      } catch (error) {
        status.textContent = describe(error);
      }
    });
    return form;
  }

  _follow(item, execId, status, output, cancel) {
    const path = `${this.base}/${item.id}/executions/${execId}`;
    cancel.hidden = false;
    cancel.onclick = async () => {
      try {
        await request("DELETE", path);
        status.textContent = "cancel requested";
      } catch (error) {
        status.textContent = describe(error);
      }
    };
    const poll = async () => {
      if (this.destroyed) return;
      try {
        const body = await request("GET", path);
        const ext = body["x-medkit"] || {};
        status.textContent = `${body.status} (${ext.ros2_status})${ext.message ? `: ${ext.message}` : ""}`;
        status.dataset.status = body.status;
        output.textContent = JSON.stringify(body.parameters || {}, null, 2);
        if (body.status === "running") this._later(poll);
        else cancel.hidden = true;
      } catch (error) {
        status.textContent = describe(error);
        this._later(poll);
      }
    };
    poll();
  }

  _later(fn) {
    const timer = setTimeout(() => {
      this.timers.delete(timer);
      fn();
    }, POLL_MS);
    this.timers.add(timer);
  }

  destroy() {
    this.destroyed = true;
    for (const timer of this.timers) clearTimeout(timer);
    this.timers.clear();
  }
}
