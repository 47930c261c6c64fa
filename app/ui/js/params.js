// The Parameters panel of an app (#/apps/<id>/configurations): its node's ROS 2 parameters, each
// with its value, type, description and range (GET …/configurations/<id>: x-medkit.parameter, the
// node's describe_parameters answer), read-only ones marked.
//
// The editor (a text field and Set) is shown only when the gateway allows configuration writes
// (capabilities.configuration_writes, --allow-configurations) and the parameter is not read-only;
// the page's bearer token (api.js) goes with the PUT.  A string is sent as typed, any other type
// as JSON ("20.0", "true", "[1, 2]").  When the node refuses a value (out of its range, of the
// wrong type, read-only), its own reason (the error's parameters.details) is shown next to the
// field, and the value shown stays the node's.

import { describe, request } from "./api.js";
import { h } from "./dom.js";
import { CollectionPanel } from "./panel.js";

/** "0.5 – 50" (and the step when there is one), or "" when the parameter declares no range. */
function rangeText(parameter) {
  const range = parameter.floating_point_range || parameter.integer_range;
  if (!range) return "";
  const step = range.step ? `, step ${range.step}` : "";
  return `${range.from_value} – ${range.to_value}${step}`;
}

function valueText(value) {
  return typeof value === "string" ? value : JSON.stringify(value);
}

export class ParametersView extends CollectionPanel {
  constructor(container, entity, { capabilities }) {
    super(container, entity, "configurations", capabilities.configuration_writes);
  }

  texts() {
    return { heading: `Parameters of ${this.entityId}`, noun: "parameters",
             empty: "This app's node declares no parameters.",
             readOnly: "Read-only: the gateway does not allow configuration changes (--allow-configurations)." };
  }

  /** Each parameter's own answer: the descriptors (range, description, read-only) are only there.  Asked one at a
   * time, so the panel never adds a burst of requests to the tree's own loading. */
  async load() {
    const detailed = [];
    for (const item of await super.load()) detailed.push(await request("GET", `${this.base}/${encodeURIComponent(item.id)}`));
    return detailed;
  }

  render(item) {
    const parameter = (item["x-medkit"] || {}).parameter || {};
    const range = rangeText(parameter);
    const value = h("code", { class: "param-value" }, valueText(item.data));
    const status = h("p", { class: "form-status", role: "status" });
    const input = h("input", { type: "text", name: "value", spellcheck: "false",
                               "aria-label": `${item.id} new value` });
    input.value = valueText(item.data);
    const editable = this.allowed && !parameter.read_only;
    const form = h("form", { class: "publish parameter", dataset: { parameter: item.id }, novalidate: true },
      h("h3", {}, item.id, h("span", { class: "muted param-type" }, ` ${parameter.type || ""}`),
        parameter.read_only ? h("span", { class: "muted param-read-only" }, " read-only") : null),
      parameter.description ? h("p", { class: "muted" }, parameter.description) : null,
      h("div", { class: "field" }, h("label", {}, "value"), value),
      range ? h("div", { class: "field" }, h("label", {}, "range"), h("span", { class: "param-range" }, range))
        : null,
      editable ? h("div", { class: "field" }, h("label", {}, "new value"), input) : null,
      editable ? h("div", { class: "actions" }, h("button", { type: "submit" }, "Set")) : null,
      status);
    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      let data = input.value;
      if (parameter.type !== "string") {
        try {
          data = JSON.parse(input.value);
        } catch (error) {
          status.textContent = `Not JSON: ${error.message}`;
          return;
        }
      }
      status.textContent = "setting…";
      delete status.dataset.refused;
      try {
        const answer = await request("PUT", `${this.base}/${encodeURIComponent(item.id)}`, { body: { data } });
        value.textContent = valueText(answer.data);
        input.value = valueText(answer.data);
        status.textContent = "set";
      } catch (error) {
        // the node's own reason (SetParametersResult.reason) is in the error's details
        const details = error.body && error.body.parameters && error.body.parameters.details;
        status.textContent = details ? `Refused: ${details} (${describe(error)})` : describe(error);
        status.dataset.refused = "true";
      }
    });
    return form;
  }
}
