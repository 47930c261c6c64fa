// The Operations panel of an app (#/apps/<id>/operations): its services and actions, a form for
// each made from the request's or goal's default value, Run, and the answer.
//
// A goal is followed while it runs (polled every POLL_MS): its state in an operator's words
// (running, completed, canceled, aborted: x-medkit.ros2_status says which, where SOVD's status
// says only "failed"), the latest feedback on one line, a progress bar where the feedback has an
// obvious one (a progress/percent field, or a list growing toward the goal's one number), the
// result once it is done, and Cancel while it runs.  Each action lists its past executions (the
// newest MAX_PAST), each with its state; a click follows it.
//
// The form is the default value as JSON text: what is typed is sent as "parameters", and the
// gateway's own check answers a field that does not fit (its message names the field).  Run and
// Cancel are shown only when the gateway allows operations (capabilities.operation_execution);
// the page's bearer token (api.js) goes with them.

import { describe, request } from "./api.js";
import { fill, h } from "./dom.js";
import { CollectionPanel } from "./panel.js";

const POLL_MS = 500;
const MAX_PAST = 8;
const FEEDBACK_CHARS = 400;
const STATES = { executing: "running", accepted: "running", canceling: "canceling", succeeded: "completed",
                 canceled: "canceled", aborted: "aborted", unknown: "unknown" };
const PROGRESS_FIELDS = ["progress", "percent", "percentage", "completion"];

/** A goal's state in an operator's words, from its execution: running, completed, canceled … */
export function goalState(execution) {
  const ros2 = (execution["x-medkit"] || {}).ros2_status;
  return STATES[ros2] || execution.status || "unknown";
}

/** 0–100 when the feedback shows how far the goal is, else null. */
export function progressOf(feedback, goal) {
  if (!feedback || typeof feedback !== "object") return null;
  for (const name of PROGRESS_FIELDS) {
    const v = feedback[name];
    if (typeof v === "number" && Number.isFinite(v)) return Math.max(0, Math.min(100, v <= 1 ? 100 * v : v));
  }
  // A list that grows toward the goal's one positive number (Fibonacci: `sequence` toward `order`).
  const lists = Object.values(feedback).filter(Array.isArray);
  const targets = Object.values(goal || {}).filter((v) => Number.isInteger(v) && v > 0);
  if (lists.length === 1 && targets.length === 1) return Math.min(100, (100 * lists[0].length) / (targets[0] + 1));
  return null;
}

function oneLine(value) {
  const text = JSON.stringify(value);
  return text && text.length > FEEDBACK_CHARS ? `${text.slice(0, FEEDBACK_CHARS)}…` : text || "";
}

export class OperationsView extends CollectionPanel {
  constructor(container, entity, { capabilities }) {
    super(container, entity, "operations", capabilities.operation_execution);
    this.timers = new Set();
  }

  texts() {
    return { heading: `Operations of ${this.entityId}`, noun: "operations",
             empty: "This app offers no services or actions.",
             readOnly: "Read-only: the gateway does not allow operations (--allow-operations)." };
  }

  render(item) {
    const ext = item["x-medkit"] || {};
    const ros2 = ext.ros2 || {};
    const action = ros2.kind === "action";
    const defaults = ((ext.type_info || {}).default_value || {})[action ? "goal" : "request"] || {};
    const input = h("textarea", { name: "parameters", rows: 4, spellcheck: "false",
                                  "aria-label": `${item.id} ${action ? "goal" : "request"}` });
    input.value = JSON.stringify(defaults, null, 2);
    const view = {
      item, action,
      status: h("p", { class: "form-status", role: "status" }),
      progress: h("div", { class: "op-progress", hidden: true }, h("progress", { max: 100, value: 0 }), h("span", {})),
      feedback: h("p", { class: "op-feedback", hidden: true }),
      output: h("pre", { class: "op-output" }),
      cancel: h("button", { type: "button", class: "op-cancel", hidden: true }, "Cancel"),
      past: h("ol", { class: "op-past" }),
      goal: null,
    };
    const run = h("button", { type: "submit" }, "Run");
    const form = h("form", { class: "publish operation", dataset: { operation: item.id }, novalidate: true },
      h("h3", {}, item.name, h("span", { class: "muted" }, ` ${action ? "action" : "service"} ${ros2[ros2.kind] || ""}`)),
      h("p", { class: "muted" }, ros2.type || ""),
      this.allowed ? [h("label", {}, action ? "goal" : "request"), input,
                      h("div", { class: "actions" }, run, view.cancel)] : null,
      view.status, view.progress, view.feedback, view.output,
      action ? h("details", { class: "op-history", open: true }, h("summary", {}, "Past executions"), view.past) : null);
    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      let parameters;
      try {
        parameters = JSON.parse(input.value || "{}");
      } catch (error) {
        view.status.textContent = `Not JSON: ${error.message}`;
        return;
      }
      view.status.textContent = "running…";
      view.output.textContent = "";
      try {
        const answer = await request("POST", `${this.base}/${item.id}/executions`, { body: { parameters },
                                                                                     timeout: 3_700_000 });
        if (action) {
          this._follow(view, answer.id, parameters);
        } else {
          view.status.textContent = "done";
          view.output.textContent = JSON.stringify(answer.parameters, null, 2);
        }
      } catch (error) {
        view.status.textContent = describe(error);
      }
    });
    if (action) this._history(view);
    return form;
  }

  /** The action's newest executions, each with its state; a click follows it. */
  async _history(view) {
    const path = `${this.base}/${view.item.id}/executions`;
    let ids;
    try {
      ids = ((await request("GET", path)).items || []).map((i) => i.id).slice(0, MAX_PAST);
    } catch (error) {
      fill(view.past, h("li", { class: "muted" }, `not loaded: ${describe(error)}`));
      return;
    }
    const rows = await Promise.all(ids.map(async (id) => {
      try {
        return [id, await request("GET", `${path}/${id}`)];
      } catch {
        return [id, null];   // gone meanwhile (past --goal-retention)
      }
    }));
    if (this.destroyed) return;
    const shown = rows.filter(([, body]) => body);
    fill(view.past, shown.length ? shown.map(([id, body]) => h("li", { dataset: { id, state: goalState(body) } },
      h("button", { type: "button", class: "link", title: id, onclick: () => this._follow(view, id, null) },
        id.slice(0, 8)),
      ` ${goalState(body)}`, h("span", { class: "muted" }, ` ${oneLine(body.parameters)}`)))
      : h("li", { class: "muted" }, "none yet"));
  }

  /** Follow one goal; `goal` is what was sent (for the progress bar), null when not known here. */
  _follow(view, execId, goal) {
    const path = `${this.base}/${view.item.id}/executions/${execId}`;
    view.followed = execId;
    view.goal = goal;
    view.cancel.hidden = !this.allowed;
    view.cancel.onclick = async () => {
      try {
        await request("DELETE", path);
        view.status.textContent = "cancel requested";
      } catch (error) {
        view.status.textContent = describe(error);
      }
    };
    const poll = async () => {
      if (this.destroyed || view.followed !== execId) return;
      try {
        const body = await request("GET", path);
        const ext = body["x-medkit"] || {};
        const state = goalState(body);
        view.status.textContent = state + (ext.message ? `: ${ext.message}` : "");
        view.status.dataset.status = state;
        const feedback = ext.feedback;
        view.feedback.hidden = feedback === undefined;
        view.feedback.textContent = feedback === undefined ? "" : `Latest feedback: ${oneLine(feedback)}`;
        const progress = state === "completed" ? 100 : progressOf(feedback, view.goal);
        view.progress.hidden = progress === null;
        if (progress !== null) {
          view.progress.firstChild.value = progress;
          view.progress.lastChild.textContent = ` ${Math.round(progress)} %`;
        }
        if (body.status === "running") {
          view.output.textContent = "";
          this._later(poll);
        } else {
          view.cancel.hidden = true;
          view.output.textContent = ext.result !== undefined ? `Result: ${JSON.stringify(ext.result, null, 2)}` : "";
          this._history(view);
        }
      } catch (error) {
        view.status.textContent = describe(error);
        this._later(poll);
      }
    };
    this._history(view);
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
    super.destroy();
    for (const timer of this.timers) clearTimeout(timer);
    this.timers.clear();
  }
}
