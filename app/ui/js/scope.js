// What the Faults and Logs panels show: the whole robot, or the entity the page is looking at.
//
// main.js says which entity the page looks at (an app's data item, operations or parameters:
// follow(); the start page: follow(null)).  The panels show that entity's faults and logs, until
// the user asks for the whole robot (showWholeRobot); looking at another entity follows it again.
// Each change is a "sovd-scope" event on window, {detail: scope}; scope is null for the whole robot,
// else {collection, id}.

let entity = null;
let wholeRobot = false;

export function current() {
  return wholeRobot ? null : entity;
}

function changed() {
  window.dispatchEvent(new CustomEvent("sovd-scope", { detail: current() }));
}

/** The page now looks at this entity ({collection, id}), or at no entity (null). */
export function follow(next) {
  const same = (entity && next && entity.collection === next.collection && entity.id === next.id) || entity === next;
  if (same) return;
  entity = next;
  wholeRobot = false;
  changed();
}

export function showWholeRobot(yes) {
  if (wholeRobot === yes) return;
  wholeRobot = yes;
  changed();
}

/** The entity followed, even while the whole robot is shown (null when none). */
export function followed() {
  return entity;
}

/** The API path of a scope's collection ("apps/x/faults"), or the whole robot's (`whole`). */
export function pathOf(scope, collection, whole) {
  return scope ? `${scope.collection}/${encodeURIComponent(scope.id)}/${collection}` : whole;
}

/** Fill `el` with the scope a panel shows and a button to switch, kept current. */
export function scopeSwitch(el) {
  const render = () => {
    const scope = current();
    const seen = followed();
    el.replaceChildren();
    const name = document.createElement("span");
    name.className = "scope-name";
    name.textContent = scope ? scope.id : "whole robot";
    el.append(name);
    if (seen) {
      const button = document.createElement("button");
      button.type = "button";
      button.className = "scope-toggle";
      button.textContent = scope ? "show the whole robot" : `only ${seen.id}`;
      button.addEventListener("click", () => showWholeRobot(Boolean(scope)));
      el.append(button);
    }
  };
  window.addEventListener("sovd-scope", render);
  render();
}
