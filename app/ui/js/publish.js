// The publish form of a data item (only shown when the gateway allows publishing).
//
// The fields are made from the item's type_info: its default value gives the fields and their
// starting values, its schema their kinds.  Arrays (and anything without a default value) are
// edited as JSON.  Numbers are sent as numbers when they read as one and as the text typed
// otherwise, so that the gateway's own check answers, naming the field.  The gateway's JSON
// errors are shown next to the field they name: "data.header.stamp.sec: ..." next to that input,
// parameters.field ("type", "data") next to that part, 401/403 for the token next to the token.
// The token field is the page's one bearer token (api.js): what is typed here is what the page
// sends, and it shows what was typed in the page's header.

import { ApiError, getToken, request, setToken } from "./api.js";
import { h } from "./dom.js";
import { isNumberSchema } from "./jsontree.js";

const NUMBER = /^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/;
const FIELD_IN_MESSAGE = /^(data(?:\.[A-Za-z_][A-Za-z0-9_]*|\[\d+\])*)\s*:/;

function kindOf(value, schema) {
  if (Array.isArray(value) || (schema && schema.type === "array")) return "json";
  if (value !== null && typeof value === "object") return "object";
  if (typeof value === "boolean") return "bool";
  if (typeof value === "number" || isNumberSchema(schema) || (schema && schema.type === "integer")) return "number";
  if (typeof value === "string") return "string";
  return "json";
}

export class PublishForm {
  /**
   * @param {object} options  dataPath (the item's API path), topic, type, typeInfo ({schema, default_value}
   *                          or undefined), authentication (the gateway wants a bearer token)
   */
  constructor(container, { dataPath, topic, type, typeInfo, authentication }) {
    this.dataPath = dataPath;
    this.type = type;
    this.fields = new Map(); // path text -> {el, error}
    this.status = h("p", { class: "form-status", role: "status" });
    const defaults = typeInfo && typeInfo.default_value;
    this.root = defaults && typeof defaults === "object"
      ? this._spec("data", defaults, typeInfo.schema, 0)
      : this._spec("data", {}, undefined, 0, "json");
    this.typeRow = this._row("type", "type", h("code", {}, type || "unknown"));
    this.tokenInput = null;
    if (authentication) {
      this.tokenInput = h("input", { type: "password", name: "token", autocomplete: "off", spellcheck: "false",
                                     placeholder: "bearer token", value: getToken() });
      this.tokenInput.addEventListener("input", () => setToken(this.tokenInput.value));
      this.onToken = () => {
        if (this.tokenInput.value !== getToken()) this.tokenInput.value = getToken();
      };
      window.addEventListener("sovd-token", this.onToken);
      this.tokenRow = this._row("token", "token", this.tokenInput);
    }
    this.button = h("button", { type: "submit" }, "Publish");
    this.form = h("form", { class: "publish", "aria-label": `publish to ${topic}`, novalidate: true },
      h("h3", {}, "Publish"),
      h("p", { class: "muted" }, `One message to ${topic}. Fields left as they are keep their default.`),
      this.typeRow, this.root.el, this.tokenRow, h("div", { class: "actions" }, this.button), this.status);
    this.form.addEventListener("submit", (event) => {
      event.preventDefault();
      this.submit();
    });
    container.append(this.form);
  }

  _row(path, label, input) {
    const error = h("span", { class: "field-error", role: "alert" });
    const id = `f-${Math.random().toString(36).slice(2)}`;
    if (input.tagName !== "CODE") {
      input.id = id;
      input.setAttribute("aria-describedby", `${id}-error`);
    }
    error.id = `${id}-error`;
    const el = h("div", { class: "field", dataset: { field: path } },
      h("label", { for: input.tagName !== "CODE" ? id : null }, label), input, error);
    this.fields.set(path, { el, error });
    return el;
  }

  _spec(path, value, schema, depth, forced) {
    const kind = forced || kindOf(value, schema);
    const label = path.split(".").pop();
    if (kind === "object") {
      const children = Object.entries(value).map(([k, v]) =>
        this._spec(`${path}.${k}`, v, schema && schema.properties ? schema.properties[k] : undefined, depth + 1));
      const error = h("span", { class: "field-error", role: "alert" });
      const el = h("fieldset", { class: "group", dataset: { field: path } },
        h("legend", {}, depth === 0 ? "data" : label), error, children.map((c) => c.el));
      this.fields.set(path, { el, error });
      return { kind, path, children: children.map((c, i) => [Object.keys(value)[i], c]), el };
    }
    let input;
    if (kind === "bool") {
      input = h("input", { type: "checkbox", checked: Boolean(value) });
    } else if (kind === "number") {
      input = h("input", { type: "text", inputmode: "decimal", value: String(value ?? 0), spellcheck: "false" });
    } else if (kind === "string") {
      input = h("input", { type: "text", value: value ?? "", spellcheck: "false" });
    } else {
      const text = JSON.stringify(value ?? {}, null, Array.isArray(value) && value.length > 8 ? 0 : 1);
      input = h("textarea", { rows: Math.min(6, text.split("\n").length + 1), spellcheck: "false" });
      input.value = text;
    }
    const el = this._row(path, label, input);
    return { kind, path, input, el };
  }

  _collect(spec, problems) {
    if (spec.kind === "object") {
      const out = {};
      for (const [key, child] of spec.children) out[key] = this._collect(child, problems);
      return out;
    }
    const { input } = spec;
    if (spec.kind === "bool") return input.checked;
    if (spec.kind === "number") {
      const text = input.value.trim();
      return NUMBER.test(text) ? Number(text) : text;
    }
    if (spec.kind === "string") return input.value;
    try {
      return JSON.parse(input.value);
    } catch (error) {
      problems.push([spec.path, `not valid JSON: ${error.message}`]);
      return undefined;
    }
  }

  _clearErrors() {
    for (const { el, error } of this.fields.values()) {
      error.textContent = "";
      el.classList.remove("invalid");
    }
    this.status.textContent = "";
    this.status.className = "form-status";
  }

  _fieldError(path, message) {
    const field = this.fields.get(path);
    if (!field) return false;
    field.error.textContent = message;
    field.el.classList.add("invalid");
    return true;
  }

  /** The field an error of the gateway names, or null. */
  _fieldOf(error) {
    const body = error.body || {};
    const params = body.parameters || {};
    if (this.tokenInput && (error.status === 401 || (error.status === 403 && /token/i.test(body.message || "")))) {
      return "token";
    }
    if (typeof params.field === "string" && this.fields.has(params.field)) return params.field;
    const match = FIELD_IN_MESSAGE.exec(body.message || "");
    if (!match) return null;
    // The longest field path that the named one starts with ("data.pose.covariance[3]" -> "data.pose.covariance").
    let best = null;
    for (const path of this.fields.keys()) {
      const named = match[1];
      if ((named === path || named.startsWith(`${path}.`) || named.startsWith(`${path}[`))
          && (!best || path.length > best.length)) best = path;
    }
    return best;
  }

  destroy() {
    if (this.onToken) window.removeEventListener("sovd-token", this.onToken);
  }

  async submit() {
    this._clearErrors();
    const problems = [];
    const data = this._collect(this.root, problems);
    if (problems.length) {
      for (const [path, message] of problems) this._fieldError(path, message);
      return;
    }
    this.button.disabled = true;
    this.status.textContent = "publishing…";
    try {
      const answer = await request("PUT", this.dataPath, { body: { type: this.type, data } });
      const ext = answer["x-medkit"] || {};
      this.status.className = "form-status ok";
      this.status.textContent = `Published to ${ext.subscriber_count ?? 0} subscriber(s).` +
        (ext.warning ? ` ${ext.warning}` : "");
    } catch (error) {
      this.status.className = "form-status error";
      if (error instanceof ApiError) {
        const body = error.body || {};
        const text = `${body.message || error.message} (${error.status} ${body.vendor_code || body.error_code || ""})`;
        const field = this._fieldOf(error);
        if (field && this._fieldError(field, text)) {
          this.status.textContent = "Not published: see the field marked.";
        } else {
          this.status.textContent = `Not published: ${text}`;
        }
      } else {
        this.status.textContent = `Not published: ${error.message}. It may or may not have reached the gateway.`;
      }
    } finally {
      this.button.disabled = false;
    }
  }
}
