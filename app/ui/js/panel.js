// What the panels of an entity's collection (operations, parameters) share: the collection's URL,
// whether the gateway allows its writes, and start(): "loading…", then the items, or why they could
// not be loaded, with a note when the gateway allows no changes.  A panel names itself (heading,
// noun, empty and readOnly texts) and draws one item (render); load() may ask for more than the list.

import { describe, request } from "./api.js";
import { fill, h } from "./dom.js";

export class CollectionPanel {
  constructor(container, { collection, entityId }, resource, allowed) {
    this.container = container;
    this.base = `${collection}/${entityId}/${resource}`;
    this.entityId = entityId;
    this.allowed = Boolean(allowed);
    this.failed = false;
    this.destroyed = false;
  }

  /** The collection's items (a panel that needs each item's own answer overrides it). */
  async load() {
    return (await request("GET", this.base)).items;
  }

  async start() {
    const { heading, noun, empty, readOnly } = this.texts();
    fill(this.container, h("h2", {}, heading), h("p", { class: "muted" }, "loading…"));
    let items;
    try {
      items = await this.load();
    } catch (error) {
      this.failed = true;
      fill(this.container, h("h2", {}, heading),
        h("p", { class: "form-status", role: "alert" }, `The ${noun} could not be loaded: ${describe(error)}`));
      return;
    }
    if (this.destroyed) return;
    fill(this.container, h("h2", {}, heading),
      items.length ? null : h("p", { class: "muted" }, empty),
      this.allowed ? null : h("p", { class: "muted" }, readOnly),
      items.map((item) => this.render(item)));
  }

  destroy() {
    this.destroyed = true;
  }
}
