// A collapsible JSON tree that is patched in place on every new value.
//
// A live value arrives up to 20 times a second with the same shape each time: the tree is built
// once and afterwards only the text of the leaves that changed is written (a subtree is rebuilt
// only when its shape changes: other keys, another array length).  Collapsing uses <details>, and
// what the user opened or closed is remembered by path across rebuilds.  Long arrays show their
// first MAX_ITEMS items, long strings their first MAX_TEXT characters.
//
// Floats that JSON cannot carry arrive as the strings "NaN", "Infinity", "-Infinity" (or as null);
// in a field whose schema says "number" (or number-or-those-strings) they are shown, and plotted, as
// the numbers they stand for.

import { h } from "./dom.js";

const MAX_ITEMS = 100;
const MAX_TEXT = 160;
const OPEN_DEPTH = 4;        // containers shallower than this start open...
const OPEN_ARRAY_MAX = 12;   // ...arrays only when they are this short
const NON_FINITE = { NaN: NaN, Infinity: Infinity, "-Infinity": -Infinity };

/** Whether `schema` describes a float: "number", or number-or-"NaN"/"Infinity"/"-Infinity". */
export function isNumberSchema(schema) {
  if (!schema) return false;
  if (schema.type === "number") return true;
  return Array.isArray(schema.anyOf) && schema.anyOf.some((s) => s && s.type === "number");
}

/** The number a leaf stands for, or undefined when it is not numeric. */
export function numericValue(value, schema) {
  if (typeof value === "number") return value;
  if (isNumberSchema(schema)) {
    if (typeof value === "string" && value in NON_FINITE) return NON_FINITE[value];
    if (value === null) return NaN;
  }
  return undefined;
}

/** The value at `path` (an array of keys and indices) in `data`. */
export function valueAt(data, path) {
  let value = data;
  for (const key of path) {
    if (value === null || typeof value !== "object") return undefined;
    value = value[key];
  }
  return value;
}

/** "pose.pose.position.x", "covariance[3]" */
export function pathText(path) {
  let text = "";
  for (const key of path) text += typeof key === "number" ? `[${key}]` : (text ? "." : "") + key;
  return text;
}

function kindOf(value) {
  if (Array.isArray(value)) return "array";
  if (value !== null && typeof value === "object") return "object";
  return "leaf";
}

function childSchema(schema, key) {
  if (!schema) return undefined;
  if (typeof key === "number") return schema.items;
  return schema.properties ? schema.properties[key] : undefined;
}

function leafText(value, schema) {
  const number = numericValue(value, schema);
  if (number !== undefined && !Number.isFinite(number)) {
    return { text: value === null ? "NaN (null)" : String(number), cls: "val nonfinite" };
  }
  if (typeof value === "number") return { text: String(value), cls: "val num" };
  if (typeof value === "boolean") return { text: String(value), cls: "val bool" };
  if (value === null) return { text: "null", cls: "val null" };
  if (typeof value === "string") {
    // A byte array asked for with ?bytes=base64 is one string where the schema says array.
    if (schema && (schema.contentEncoding === "base64" || schema.type === "array")) {
      return { text: `base64, ${Math.floor((value.length * 3) / 4)} bytes`, cls: "val bytes" };
    }
    const shown = value.length > MAX_TEXT ? `${value.slice(0, MAX_TEXT)}… (${value.length} chars)` : value;
    return { text: JSON.stringify(shown), cls: "val str" };
  }
  return { text: String(value), cls: "val" };
}

export class JsonTree {
  /**
   * @param {HTMLElement} container
   * @param {object} options  schema (JSON schema of the value, may be undefined);
   *                          onPick(path) and isPicked(path) for numeric leaves (the plot)
   */
  constructor(container, { schema, onPick, isPicked } = {}) {
    this.container = container;
    this.schema = schema;
    this.onPick = onPick;
    this.isPicked = isPicked || (() => false);
    this.userOpen = new Map(); // path text -> open, as the user left it
    this.root = null;
  }

  update(value) {
    if (this.root && this._patch(this.root, value)) return;
    const node = this._build("data", value, this.schema, [], 0);
    this.container.replaceChildren(node.el);
    this.root = node;
  }

  /** Refresh the pick buttons (after the plot's selection changed). */
  refreshPicks() {
    for (const button of this.container.querySelectorAll("button.pick")) {
      const picked = this.isPicked(button.dataset.path);
      button.classList.toggle("active", picked);
      button.setAttribute("aria-pressed", String(picked));
    }
  }

  _build(key, value, schema, path, depth) {
    const kind = kindOf(value);
    if (kind === "leaf") return this._leaf(key, value, schema, path);
    const text = pathText(path);
    const entries = kind === "array"
      ? value.slice(0, MAX_ITEMS).map((v, i) => [i, v])
      : Object.entries(value);
    const size = kind === "array" ? `[${value.length}]` : `{${entries.length}}`;
    const defaultOpen = depth < OPEN_DEPTH && (kind === "object" || value.length <= OPEN_ARRAY_MAX);
    const open = this.userOpen.has(text) ? this.userOpen.get(text) : defaultOpen;
    const summary = h("summary", {}, key === null ? "" : h("span", { class: "key" }, String(key)),
                      h("span", { class: "size" }, size));
    const body = h("div", { class: "children" });
    const details = h("details", { class: `node ${kind}`, open, dataset: { path: text } }, summary, body);
    summary.addEventListener("click", () => this.userOpen.set(text, !details.open));
    const children = new Map();
    for (const [k, v] of entries) {
      const child = this._build(k, v, childSchema(schema, k), [...path, k], depth + 1);
      children.set(k, child);
      body.append(child.el);
    }
    if (kind === "array" && value.length > MAX_ITEMS) {
      body.append(h("div", { class: "leaf more muted" }, `… ${value.length - MAX_ITEMS} more items`));
    }
    const signature = kind === "array" ? value.length : entries.map(([k]) => k).join("\u0000");
    return { kind, el: details, children, signature, schema, key, path, depth };
  }

  _leaf(key, value, schema, path) {
    const { text, cls } = leafText(value, schema);
    const valueEl = h("span", { class: cls }, text);
    const el = h("div", { class: "leaf", dataset: { path: pathText(path) } });
    if (key !== null) el.append(h("span", { class: "key" }, String(key)), ": ");
    el.append(valueEl);
    const numeric = numericValue(value, schema) !== undefined;
    if (numeric && this.onPick) {
      const p = pathText(path);
      const picked = this.isPicked(p);
      el.append(h("button", {
        type: "button", class: picked ? "pick active" : "pick", title: `plot ${p}`,
        "aria-pressed": String(picked), dataset: { path: p },
        onclick: () => this.onPick(path),
      }, "plot"));
    }
    return { kind: "leaf", el, valueEl, text, cls, numeric, schema, key, path };
  }

  /** Patch `node` to show `value`; false when its shape changed and it must be rebuilt. */
  _patch(node, value) {
    const kind = kindOf(value);
    if (kind !== node.kind) return false;
    if (kind === "leaf") {
      const { text, cls } = leafText(value, node.schema);
      if ((numericValue(value, node.schema) !== undefined) !== node.numeric) return false;
      if (text !== node.text) {
        node.valueEl.textContent = text;
        node.text = text;
      }
      if (cls !== node.cls) {
        node.valueEl.className = cls;
        node.cls = cls;
      }
      return true;
    }
    if (kind === "array") {
      if (value.length !== node.signature) return false;
    } else if (Object.keys(value).join("\u0000") !== node.signature) {
      return false;
    }
    for (const [k, child] of node.children) {
      if (!this._patch(child, value[k])) {
        const fresh = this._build(k, value[k], child.schema, child.path, node.depth + 1);
        child.el.replaceWith(fresh.el);
        node.children.set(k, fresh);
      }
    }
    return true;
  }
}
