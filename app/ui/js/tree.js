// The entity tree: components → apps → data items, and functions → apps → data items.
//
// It follows the API's own links: the component and function listings give each entity's href,
// its detail gives the URIs of its "hosts" (the apps) and of its "data"; a component's data
// listing names, for each topic, the apps that publish or subscribe to it (member_ids).  A data
// item links to the view of that topic under its app ("#/apps/<id>/data/<topic>").
//
// The filter matches a topic name, an app id or its ROS node name; matching branches open.
// Hidden topics (a name part that starts with "_", such as an action's .../_action/feedback) and
// /rosout and /parameter_events (every node has them) are left out unless asked for, as
// `ros2 topic list` leaves hidden topics out; a filter that names one shows it.
// Open branches stay open across reloads.

import { describe, get } from "./api.js";
import { fill, h } from "./dom.js";

const SYSTEM_TOPICS = new Set(["/rosout", "/parameter_events"]);

/** Whether a topic is left out by default: /rosout, /parameter_events, or hidden (a part starts with "_"). */
export function isHiddenTopic(name) {
  return SYSTEM_TOPICS.has(name) || name.split("/").some((part) => part.startsWith("_"));
}

/** The hash route of a data item under an entity ("/api/v1/apps/x", "/a/b") → "#/apps/x/data/a/b". */
export function itemRoute(entityHref, topic) {
  return `#${entityHref.replace(/^\/api\/v1/, "")}/data/${topic.replace(/^\/+/, "")}`;
}

export class EntityTree {
  constructor(container, status, search, showSystem) {
    this.container = container;
    this.status = status;
    this.search = search;
    this.showSystem = showSystem;
    this.model = null;
    this.open = new Set(["components", "functions"]);
    this.current = null; // the hash of the item shown
    this.loadedAt = 0;
    this.loading = null;
    search.addEventListener("input", () => this.render());
    showSystem.addEventListener("change", () => this.render());
  }

  /** Load the whole tree (a few requests per entity), then draw it. */
  load() {
    if (!this.loading) {
      this.loading = this._load().finally(() => {
        this.loading = null;
      });
    }
    return this.loading;
  }

  async _load() {
    this.status.textContent = this.model ? "reloading…" : "loading…";
    try {
      const [components, functions] = await Promise.all([get("components"), get("functions")]);
      const comps = await Promise.all(components.items.map(async (item) => {
        const detail = await get(item.href);
        const [hosts, data] = await Promise.all([get(detail.hosts), get(detail.data)]);
        return { item, detail, apps: hosts.items, data: data.items };
      }));
      const funcs = await Promise.all(functions.items.map(async (item) => {
        const detail = await get(item.href);
        const hosts = await get(detail.hosts);
        return { item, detail, apps: hosts.items };
      }));
      // app id -> its topics (from the components' data listings)
      const topics = new Map();
      for (const comp of comps) {
        for (const data of comp.data) {
          const ext = data["x-medkit"] || {};
          for (const member of ext.member_ids || []) {
            if (!topics.has(member)) topics.set(member, []);
            topics.get(member).push({ name: data.id, ros2: ext.ros2 || {} });
          }
        }
      }
      // operations: the apps that offer services or actions (from the components' operations)
      const withOps = new Set();
      for (const comp of comps) {
        const ops = await get(`${comp.item.href}/operations`).catch(() => ({ items: [] }));
        for (const op of ops.items) for (const member of (op["x-medkit"] || {}).member_ids || []) withOps.add(member);
      }
      if (!this.model) for (const comp of comps) this.open.add(`c:${comp.item.id}`);
      this.model = { comps, funcs, topics, withOps };
      this.loadedAt = Date.now();
      this.status.textContent = "";
    } catch (error) {
      this.status.textContent = `The entity tree could not be ${this.model ? "reloaded" : "loaded"}: ${describe(error)}`;
    }
    this.render();
  }

  select(hash) {
    this.current = hash;
    for (const a of this.container.querySelectorAll("a.topic")) {
      if (a.getAttribute("href") === hash) a.setAttribute("aria-current", "true");
      else a.removeAttribute("aria-current");
    }
  }

  render() {
    if (!this.model) return;
    const query = this.search.value.trim().toLowerCase();
    const system = this.showSystem.checked;
    const matches = (...texts) => !query || texts.some((t) => t && t.toLowerCase().includes(query));
    const { comps, funcs, topics } = this.model;

    const appNode = (app, key) => {
      const node = (app["x-medkit"] && app["x-medkit"].ros2 && app["x-medkit"].ros2.node) || "";
      const appMatches = matches(app.id, app.name, node);
      const items = (topics.get(app.id) || [])
        .filter((t) => system || !isHiddenTopic(t.name) || (query && matches(t.name)))
        .filter((t) => appMatches || matches(t.name))
        .sort((a, b) => a.name.localeCompare(b.name));
      if (!appMatches && items.length === 0) return null;
      const opsHash = `#/apps/${app.id}/operations`; // operations: the app's Operations panel
      const opsLink = this.model.withOps && this.model.withOps.has(app.id)
        ? h("li", {}, h("a", { class: "ops-link", href: opsHash, dataset: { app: app.id },
                               "aria-current": opsHash === this.current ? "true" : null }, "⚙ operations"))
        : null;
      // ui (issue 21): every app's Parameters panel (its node's ROS 2 parameters)
      const paramsHash = `#/apps/${app.id}/configurations`;
      const paramsLink = h("li", {}, h("a", { class: "params-link", href: paramsHash, dataset: { app: app.id },
                                              "aria-current": paramsHash === this.current ? "true" : null },
                                        "⚙ parameters"));
      const list = h("ul", {}, opsLink, paramsLink, items.map((t) => {
        const hash = itemRoute(app.href, t.name);
        return h("li", {}, h("a", {
          class: "topic", href: hash, title: `${t.name} (${t.ros2.type || "type unknown"})`,
          "aria-current": hash === this.current ? "true" : null, dataset: { topic: t.name, app: app.id },
        }, h("span", { class: "name" }, t.name), h("span", { class: "type" }, t.ros2.type || "")));
      }));
      return this._branch(key, h("span", { class: "app", dataset: { app: app.id } }, app.id,
        node ? h("span", { class: "muted" }, ` ${node}`) : null), list, Boolean(query));
    };

    const section = (key, title, groups) => {
      const children = groups.filter(Boolean);
      return this._branch(key, h("span", { class: "section" }, title),
        children.length ? h("ul", {}, children.map((c) => h("li", {}, c)))
                        : h("p", { class: "muted" }, query ? "no match" : "none"), Boolean(query) || undefined);
    };

    const compNodes = comps.map((c) => {
      const apps = c.apps.map((a) => appNode(a, `c:${c.item.id}:${a.id}`)).filter(Boolean);
      if (query && apps.length === 0) return null;
      return this._branch(`c:${c.item.id}`, h("span", { class: "entity" }, c.item.name || c.item.id,
        c.detail.description ? h("span", { class: "description" }, c.detail.description) : null),
        h("ul", {}, apps.map((a) => h("li", {}, a))), Boolean(query));
    });
    const funcNodes = funcs.map((f) => {
      const apps = f.apps.map((a) => appNode(a, `f:${f.item.id}:${a.id}`)).filter(Boolean);
      if (query && apps.length === 0 && !matches(f.item.id)) return null;
      return this._branch(`f:${f.item.id}`, h("span", { class: "entity" }, f.item.name || f.item.id),
        h("ul", {}, apps.map((a) => h("li", {}, a))), Boolean(query));
    });
    fill(this.container, h("ul", { class: "tree" },
      h("li", {}, section("components", "Components", compNodes)),
      h("li", {}, section("functions", "Functions", funcNodes))));
  }

  _branch(key, label, body, forceOpen) {
    const details = h("details", { open: forceOpen || this.open.has(key), dataset: { key } },
      h("summary", {}, label), body);
    details.addEventListener("toggle", () => {
      if (this.search.value.trim()) return; // a filter opens branches; that is not the user's choice
      if (details.open) this.open.add(key);
      else this.open.delete(key);
    });
    return details;
  }
}
