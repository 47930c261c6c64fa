// The audit trail, for admin (#/audit): who tried to change what, and what came of it.
//
// GET x-medkit-audit (app/audit/), newest first, PAGE records at a time: "Older" asks for the page
// after the last one shown (its `next_before`), "Newest" starts again.  A client id typed in the
// filter narrows it to that client.  A refused attempt (4xx, 5xx) is marked.

import { describe, get } from "./api.js";
import { fill, h, timeEl } from "./dom.js";

const PAGE = 50;

export class AuditView {
  constructor(container) {
    this.container = container;
    this.destroyed = false;
  }

  start() {
    this.client = h("input", { type: "search", placeholder: "client id", "aria-label": "client id",
                               spellcheck: "false", onchange: () => this.load(null) });
    this.status = h("p", { class: "muted", role: "status" });
    this.table = h("div", {});
    this.older = h("button", { type: "button", onclick: () => this.load(this.next) }, "Older");
    this.newest = h("button", { type: "button", onclick: () => this.load(null) }, "Newest");
    fill(this.container, h("h2", {}, "Audit trail"),
      h("p", { class: "muted" }, "Every write that reached the gateway: who, what, and its answer."),
      h("div", { class: "audit-tools" }, this.client, " ", this.newest, " ", this.older), this.status, this.table);
    this.load(null);
  }

  async load(before) {
    const query = new URLSearchParams({ limit: String(PAGE) });
    if (before) query.set("before", String(before));
    if (this.client.value.trim()) query.set("client_id", this.client.value.trim());
    let page;
    try {
      page = await get(`x-medkit-audit?${query}`);
    } catch (error) {
      if (!this.destroyed) this.status.textContent = `the audit trail is not readable: ${describe(error)}`;
      return;
    }
    if (this.destroyed) return;
    this.next = page.next_before || null;
    this.older.disabled = !this.next;
    this.status.textContent = page.items.length ? "" : "no record";
    fill(this.table, page.items.length ? h("table", { class: "audit" },
      h("thead", {}, h("tr", {}, ["when", "who", "role", "request", "status", "error"].map((t) => h("th", {}, t)))),
      h("tbody", {}, page.items.map((r) => h("tr", { dataset: { outcome: r.status >= 400 ? "refused" : "done" } },
        h("td", {}, timeEl(r.timestamp)),
        h("td", {}, r.client_id || r.address),
        h("td", {}, r.role || "–"),
        h("td", { class: "code" }, `${r.method} ${r.resource}`),
        h("td", { class: "status" }, String(r.status)),
        h("td", { class: "code" }, r.error_code || ""))))) : null);
  }

  destroy() {
    this.destroyed = true;
    return Promise.resolve();
  }
}
