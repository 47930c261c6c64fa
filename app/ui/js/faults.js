// The Faults panel: the gateway's faults (GET /api/v1/faults?status=all), active first, kept
// current by the fault stream (GET /api/v1/faults/stream): each event reloads the list, so the
// panel never drifts from what the gateway holds.  A fault's row opens its detail (the freeze
// frames) through the host component, which every app's fault belongs to; "Clear" sends DELETE
// with the token (the gateway answers 403 unless it was started with --allow-fault-clear).

import { describe, get, request, url } from "./api.js";
import { fill, h } from "./dom.js";

const ORDER = { CONFIRMED: 0, PREFAILED: 1, PREPASSED: 2, HEALED: 3, CLEARED: 4 };
const RELOAD_MIN_MS = 300;   // events in a burst: one reload

function when(seconds) {
  return Number.isFinite(seconds) ? new Date(seconds * 1000).toLocaleString() : "–";
}

export class FaultsPanel {
  constructor(body) {
    this.body = body;
    this.host = null;
    this.source = null;
    this.timer = null;
    this.open = new Set();
    this.details = new Map();
  }

  async start() {
    try {
      const components = await get("components");
      this.host = (components.items || [])[0]?.id || null;
    } catch { /* the detail links wait for the next reload */ }
    await this.reload();
    this.source = new EventSource(url("faults/stream"));
    this.source.addEventListener("fault_confirmed", () => this.soon());
    this.source.addEventListener("fault_updated", () => this.soon());
    this.source.addEventListener("fault_cleared", () => this.soon());
    this.source.addEventListener("open", () => this.soon());
  }

  soon() {
    if (this.timer) return;
    this.timer = setTimeout(() => { this.timer = null; this.reload(); }, RELOAD_MIN_MS);
  }

  async reload() {
    let items;
    try {
      items = (await get("faults?status=all")).items || [];
    } catch (error) {
      fill(this.body, h("p", { class: "muted" }, `faults not loaded: ${describe(error)}`));
      return;
    }
    items.sort((a, b) => (ORDER[a.status] ?? 9) - (ORDER[b.status] ?? 9) || b.severity - a.severity
      || b.last_occurred - a.last_occurred);
    const active = items.filter((f) => ORDER[f.status] <= 2).length;
    fill(this.body,
      h("p", { class: "muted", id: "faults-summary" }, `${active} active, ${items.length} kept`),
      items.length ? h("ul", { class: "faults" }, items.map((f) => this.row(f))) : null);
  }

  row(fault) {
    const detail = h("div", { class: "fault-detail" });
    const item = h("li", { class: "fault", dataset: { code: fault.fault_code, status: fault.status,
                                                      severity: fault.severity_label } },
      h("div", { class: "fault-head", onclick: () => this.toggle(fault.fault_code, detail) },
        h("span", { class: `sev sev-${fault.severity_label}` }, fault.severity_label),
        h("code", {}, fault.fault_code),
        h("span", { class: "fault-status" }, fault.status),
        h("span", { class: "muted", title: "occurrences" }, `×${fault.occurrence_count}`)),
      h("div", { class: "muted small" }, fault.description || ""),
      h("div", { class: "muted small" }, `first ${when(fault.first_occurred)} · last ${when(fault.last_occurred)}`),
      detail);
    if (this.open.has(fault.fault_code)) this.showDetail(fault.fault_code, detail);
    return item;
  }

  toggle(code, detail) {
    if (this.open.has(code)) {
      this.open.delete(code);
      fill(detail);
    } else {
      this.open.add(code);
      this.showDetail(code, detail);
    }
  }

  async showDetail(code, detail) {
    const path = `components/${encodeURIComponent(this.host || "")}/faults/${encodeURIComponent(code)}`;
    const clear = h("button", { type: "button", onclick: async () => {
      try {
        await request("DELETE", path);
        this.reload();
      } catch (error) {
        fill(status, describe(error));
      }
    } }, "Clear");
    const status = h("span", { class: "muted small" });
    try {
      const body = await get(path);
      const frames = body.environment_data?.snapshots || [];
      fill(detail, frames.map((s) => h("div", { class: "snapshot" },
        h("div", { class: "muted small" }, `${s.name} (${s["x-medkit"]?.topic || ""})`),
        h("pre", {}, JSON.stringify(s.data, null, 1)))), clear, status);
    } catch (error) {
      fill(detail, h("span", { class: "muted small" }, `no detail: ${describe(error)}`));
    }
  }
}
