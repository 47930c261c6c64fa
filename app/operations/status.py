"""``GET /{apps|components}/{id}/status``: ready or notReady, as medkit's default answers it.

medkit serves it with no lifecycle provider loaded (``lifecycle_handlers.cpp`` ``handle_get_status``,
its default path), and so does this gateway: ``{"status": "ready" | "notReady"}``, nothing else (no
transition URIs: the transitions, ``PUT .../status/{transition}``, stay 501 in
``app/core/unimplemented.py``, as medkit's do without a provider).

- An app is ready while its node is in the graph; a managed (lifecycle) node only in the state
  ``active``: the ROS worker reads it through the node's ``get_state`` service (``lifecycle_state``,
  ``rosworker/operations/lifecycle.py``: its client, its deadline, its negative cache for a node that hangs).
- A component: this gateway's only component is the host (medkit's synthetic host component),
  ready while it answers at all.  (medkit's rule for another local component: notReady only when it
  hosts apps and none of them is online; every app here is in the graph.)
"""

from __future__ import annotations

from flask import Blueprint

from ..core import rosclient
from ..core.common import json_response, lookup
from ..core.entities import API_BASE

bp = Blueprint("status", __name__, url_prefix=API_BASE)


@bp.get("/<any(apps, components):collection>/<entity_id>/status")
def status(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    ready = True
    if collection == "apps":
        answer = rosclient.get().call("lifecycle_state", {"node": entity.x_medkit["ros2"]["node"]})
        ready = answer.get("online", True) is not False and (not answer.get("managed")
                                                             or answer.get("state") == "active")
    return json_response({"status": "ready" if ready else "notReady"})
