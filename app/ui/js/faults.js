// The Faults panel: the faults of the whole robot, or of the entity the page looks at (scope.js),
// kept current by the fault stream (GET /api/v1/faults/stream): each event reloads the list, so
// the panel never drifts from what the gateway holds.
//
// Active faults come first, the most severe first, then the most recent; healed and cleared ones
// after them, the most recent first.  The list has a bounded height and scrolls, and shows at most
// MAX_SHOWN rows.  A row opens its detail: the freeze frames, each as a table of its values (a
// diagnostic status's key/value pairs) or as JSON, and the fault's recordings (issue 32: what the
// recorded topics carried before and after it, an MCAP file) with a download link, their duration,
// topics and size.  "Clear" is offered only when the gateway clears
// faults (capabilities.fault_clear, --allow-fault-clear); it sends DELETE with the page's token.
// Faults that an earlier run left in the store (their nodes are not on the graph: /health's
// x-medkit-faults.left_by_absent_nodes) are said to be so, and their rows are marked.

import { describe, eventSource, get, request, url } from "./api.js";
import { fill, formatTime, h } from "./dom.js";
import { current, pathOf, scopeSwitch } from "./scope.js";

const ACTIVE = { CONFIRMED: true, PREFAILED: true, PREPASSED: true };
const RELOAD_MIN_MS = 300;   // events in a burst: one reload
const MAX_SHOWN = 200;

/** Active first; then the most severe; then the most recent. */
export function byUrgency(a, b) {
  const active = Number(Boolean(ACTIVE[b.status])) - Number(Boolean(ACTIVE[a.status]));
  if (active) return active;
  if (ACTIVE[a.status] && b.severity !== a.severity) return b.severity - a.severity;
  return (b.last_occurred || 0) - (a.last_occurred || 0);
}

/** 1536 -> "1.5 KB" (powers of 1024, as the disk caps are set). */
export function formatBytes(n) {
  const units = ["B", "KB", "MB", "GB"];
  let value = Number(n) || 0;
  let unit = 0;
  while (value >= 1024 && unit < units.length - 1) {
    value /= 1024;
    unit += 1;
  }
  return `${unit ? value.toFixed(1) : value} ${units[unit]}`;
}

/** The rows of a freeze frame's data: a diagnostic status's message and values, or null (show JSON). */
function frameRows(data) {
  if (!data || typeof data !== "object" || Array.isArray(data)) return null;
  const rows = [];
  for (const [key, value] of Object.entries(data)) {
    if (key === "values" && value && typeof value === "object" && !Array.isArray(value)) {
      for (const [k, v] of Object.entries(value)) rows.push([k, v]);
    } else if (value === null || typeof value !== "object") {
      rows.push([key, value]);
    } else {
      return null;   // nested: shown as JSON
    }
  }
  return rows;
}

export class FaultsPanel {
  constructor(body, scopeEl, health) {
    this.body = body;
    this.health = health;        // the health panel: its last /health answer (faults left by absent nodes)
    this.capabilities = {};
    this.host = null;
    this.source = null;
    this.timer = null;
    this.open = new Set();
    scopeSwitch(scopeEl);
    window.addEventListener("sovd-scope", () => {
      this.open.clear();
      this.reload();
    });
    window.addEventListener("sovd-faults-left", () => this.soon());   // health.js: the left faults changed
  }

  async start(capabilities) {
    this.capabilities = capabilities || {};
    try {
      const components = await get("components");
      this.host = (components.items || [])[0]?.id || null;
    } catch { /* the detail links wait for the next reload */ }
    await this.reload();
    this.source = eventSource("faults/stream");
    for (const name of ["fault_confirmed", "fault_updated", "fault_cleared", "open"]) {
      this.source.addEventListener(name, () => this.soon());
    }
  }

  soon() {
    if (this.timer) return;
    this.timer = setTimeout(() => { this.timer = null; this.reload(); }, RELOAD_MIN_MS);
  }

  /** The path of a fault's detail (and of its DELETE): through the entity shown, else the host. */
  detailPath(code) {
    const scope = current();
    const base = scope ? pathOf(scope, "faults") : `components/${encodeURIComponent(this.host || "")}/faults`;
    return `${base}/${encodeURIComponent(code)}`;
  }

  async reload() {
    const scope = current();
    let items;
    try {
      items = (await get(`${pathOf(scope, "faults", "faults")}?status=all`)).items || [];
    } catch (error) {
      fill(this.body, h("p", { class: "muted" }, `faults not loaded: ${describe(error)}`));
      return;
    }
    if (scope !== current()) return;   // the scope changed meanwhile: its own reload draws
    items.sort(byUrgency);
    const active = items.filter((f) => ACTIVE[f.status]);
    const confirmed = active.filter((f) => f.status === "CONFIRMED").length;
    const left = this.health?.last?.["x-medkit-faults"] || {};
    const absent = new Set(left.absent_nodes || []);
    const shown = items.slice(0, MAX_SHOWN);
    fill(this.body,
      h("p", { class: "muted", id: "faults-summary" },
        `${active.length} active${confirmed ? ` (${confirmed} confirmed)` : ""}, ${items.length} kept`),
      left.left_by_absent_nodes ? this.leftNote(left.left_by_absent_nodes, absent) : null,
      shown.length ? h("ul", { class: "faults" }, shown.map((f) => this.row(f, absent))) : null,
      items.length > shown.length ? h("p", { class: "muted small" }, `${items.length - shown.length} more not shown`)
        : null);
  }

  /** The note on faults an earlier run left, with "Clear every active fault" when the gateway clears faults. */
  leftNote(count, absent) {
    const status = h("span", { class: "muted small" });
    return h("div", { class: "note left-faults", role: "note" },
      `${count} active fault${count === 1 ? " was" : "s were"} left by an earlier run: ${[...absent].join(", ")} `
      + `${absent.size === 1 ? "is" : "are"} not on the ROS graph, so nobody reports them any more. `
      + "Clear them, or give this gateway a state directory of its own (--state-dir).",
      this.capabilities.fault_clear ? h("div", { class: "fault-actions" }, h("button", {
        type: "button", class: "faults-clear-all", onclick: async () => {
          try {
            await request("DELETE", "faults");
            this.reload();
          } catch (error) {
            fill(status, describe(error));
          }
        } }, "Clear every active fault"), status) : null);
  }

  row(fault, absent) {
    const detail = h("div", { class: "fault-detail" });
    const sources = fault.reporting_sources || [];
    const leftOver = ACTIVE[fault.status] && sources.length && sources.every((s) => absent.has(s));
    const item = h("li", { class: "fault", dataset: { code: fault.fault_code, status: fault.status,
                                                      severity: fault.severity_label, left: leftOver ? "true" : null } },
      h("div", { class: "fault-head", role: "button", tabindex: "0",
                 onclick: () => this.toggle(fault.fault_code, detail, leftOver) },
        h("span", { class: `sev sev-${fault.severity_label}` }, fault.severity_label),
        h("code", { class: "fault-code" }, fault.fault_code),
        h("span", { class: "fault-status" }, fault.status.toLowerCase()),
        h("span", { class: "muted", title: "occurrences" }, `×${fault.occurrence_count}`)),
      h("div", { class: "small" }, fault.description || ""),
      h("div", { class: "muted small" }, `${sources.join(", ")} · last ${formatTime(fault.last_occurred)}`
        + (fault.first_occurred !== fault.last_occurred ? ` · since ${formatTime(fault.first_occurred)}` : "")),
      leftOver ? h("div", { class: "small left-mark" }, "left by an earlier run") : null,
      detail);
    if (this.open.has(fault.fault_code)) this.showDetail(fault.fault_code, detail, leftOver);
    return item;
  }

  toggle(code, detail, leftOver) {
    if (this.open.has(code)) {
      this.open.delete(code);
      fill(detail);
    } else {
      this.open.add(code);
      this.showDetail(code, detail, leftOver);
    }
  }

  async showDetail(code, detail, leftOver) {
    if (leftOver) {
      // A fault's detail is read through an entity that holds all its nodes (medkit's rule): one whose
      // nodes are gone has none; DELETE /api/v1/faults clears it with the others (the note above).
      fill(detail, h("span", { class: "muted small" }, "no detail: its node is not on the ROS graph, so no app holds it"));
      return;
    }
    const path = this.detailPath(code);
    const status = h("span", { class: "muted small" });
    const clear = this.capabilities.fault_clear ? h("button", { type: "button", class: "fault-clear", onclick: async () => {
      try {
        await request("DELETE", path);
        this.reload();
      } catch (error) {
        fill(status, describe(error));
      }
    } }, "Clear") : null;
    try {
      const body = await get(path);
      const frames = body.environment_data?.snapshots || [];
      fill(detail,
        frames.length ? frames.map((s) => (s.type === "rosbag" ? this.recording(s) : this.frame(s)))
          : h("p", { class: "muted small" }, "no freeze frame"),
        h("div", { class: "fault-actions" }, clear, status));
    } catch (error) {
      fill(detail, h("span", { class: "muted small" }, `no detail: ${describe(error)}`));
    }
  }

  /** A fault recording: its download (the API path of its bulk_data_uri), duration, topics and size. */
  recording(snapshot) {
    const ext = snapshot["x-medkit"] || {};
    const topics = ext.topics || [];
    const link = h("a", { href: url(snapshot.bulk_data_uri.replace(/^\//, "")).href, download: "",
      class: "recording-download" }, "Download MCAP");
    return h("div", { class: "snapshot recording" },
      h("div", { class: "muted small" }, "Recording" + (ext.captured_at ? ` · ${formatTime(ext.captured_at)}` : "")),
      h("div", { class: "recording-facts" }, link,
        h("span", { class: "recording-duration" }, `${Number(snapshot.duration_sec).toFixed(1)} s`),
        h("span", { class: "recording-size" }, formatBytes(snapshot.size_bytes)),
        h("span", { class: "muted small" }, `${ext.messages ?? 0} messages`)),
      h("div", { class: "recording-topics small" }, topics.length ? topics.join(", ") : "no topic"));
  }

  frame(snapshot) {
    const ext = snapshot["x-medkit"] || {};
    const rows = frameRows(snapshot.data);
    return h("div", { class: "snapshot" },
      h("div", { class: "muted small" }, `${snapshot.name} · ${ext.topic || ""}`
        + (ext.captured_at ? ` · ${formatTime(ext.captured_at)}` : "")),
      rows ? h("table", { class: "frame" }, rows.map(([k, v]) => h("tr", { dataset: { key: k } },
        h("th", {}, k), h("td", {}, typeof v === "string" ? v : JSON.stringify(v)))))
        : h("pre", { class: "frame-json" }, JSON.stringify(snapshot.data, null, 2)));
  }
}
