// The robot picker of the fleet gateway (issue 34, docs/fleet.md).
//
// It shows on the fleet gateway (GET /api/v1/ says capabilities.aggregation) and on one robot's page
// through it (<prefix>/fleet/<fleet_id>/ui/): a list in the header of the fleet's robots with their link
// state and latency, from the fleet gateway's /health every POLL_MS (it needs no token).  Picking a
// robot opens the dashboard on that robot through the fleet gateway (its own API under its own ids, the
// whole page unchanged); "All robots" opens the fleet's merged view again.  The token is kept in a
// page's memory only: a page opened this way asks for it again.
//
// Through the fleet every read needs the token (the robots answer only to an identity), so the page
// sends it with reads too (api.js's setReadsNeedToken).  Streams are not carried through the fleet: on
// a robot's page, live values and the fault stream are the robot's own dashboard's.

import { setReadsNeedToken } from "./api.js";
import { h } from "./dom.js";

const POLL_MS = 5000;
const ROBOT_PAGE = /\/fleet\/([A-Za-z0-9_-]+)\/ui\/$/;

/** The fleet gateway's root (where its /api/v1/ and ui/ are) and the robot this page shows, if any. */
export function fleetPlace() {
  const match = ROBOT_PAGE.exec(location.pathname);
  return match ? { root: new URL("../../../", document.baseURI), robot: match[1] }
               : { root: new URL("../", document.baseURI), robot: "" };
}

export class RobotPicker {
  constructor(header, before) {
    this.header = header;
    this.before = before;
    this.select = null;
    this.place = fleetPlace();
  }

  /** Show the picker when this page is the fleet gateway's; true when it did. */
  start(capabilities) {
    if (!capabilities.aggregation && !this.place.robot) return false;
    setReadsNeedToken(true);
    this.select = h("select", { id: "robot-picker", "aria-label": "Robot" });
    this.select.addEventListener("change", () => {
      const robot = this.select.value;
      location.assign(new URL(robot ? `fleet/${robot}/ui/` : "ui/", this.place.root));
    });
    this.header.insertBefore(h("label", { class: "robot-picker" }, "Robot ", this.select), this.before);
    if (this.place.robot) document.getElementById("token").hidden = false;   // reads need it at once
    this.poll();
    return true;
  }

  async poll() {
    try {
      const response = await fetch(new URL("api/v1/health", this.place.root), { signal: AbortSignal.timeout(POLL_MS) });
      this.draw((await response.json()).peers || []);
    } catch {
      /* the next poll tries again; the list keeps what it showed */
    }
    setTimeout(() => this.poll(), POLL_MS);
  }

  draw(peers) {
    const options = [h("option", { value: "" }, `All robots (${peers.length})`)];
    for (const peer of peers) {
      const latency = typeof peer.latency_ms === "number" ? ` · ${Math.round(peer.latency_ms)} ms` : "";
      options.push(h("option", { value: peer.name, dataset: { status: peer.status } },
                     `${peer.name} · ${peer.status}${latency}`));
    }
    this.select.replaceChildren(...options);
    this.select.value = this.place.robot;
  }
}
