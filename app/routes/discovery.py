"""Entity listings and details: areas, components, apps, functions (runtime-only discovery)."""

from __future__ import annotations

from flask import Blueprint

from .. import rosclient
from ..entities import API_BASE
from .common import json_response, lookup

bp = Blueprint("discovery", __name__, url_prefix=API_BASE)


@bp.get("/<collection:collection>")
def listing(collection: str):
    items = [e.listing_item() for e in rosclient.get().entities().listing(collection)]
    return json_response({"items": items, "x-medkit": {"total_count": len(items)}})


@bp.get("/<collection:collection>/<entity_id>")
def detail(collection: str, entity_id: str):
    return json_response(lookup(collection, entity_id).detail())


@bp.get("/apps/<entity_id>/is-located-on")
def is_located_on(entity_id: str):
    app = lookup("apps", entity_id)
    host = lookup("components", app.component_id)
    return json_response({"items": [host.listing_item()]})
