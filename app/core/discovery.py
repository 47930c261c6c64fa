"""Entity listings, details and relation collections (runtime-only discovery).

Relation collections are medkit's HATEOAS links (``entities.RELATIONS``):
``/components/{id}/hosts``, ``/apps/{id}/is-located-on`` ... each answered as
``{"items", "x-medkit": {"total_count"}, "_links": {"self", <owner>}}``.  Their
errors are medkit's, handler by handler: the app relations check the id like
an entity detail does (:func:`~app.core.common.lookup`), the others name
their type (:func:`~app.core.common.lookup_owner`: ``"Component not found"``
with ``component_id``).
"""

from __future__ import annotations

from flask import Blueprint

from . import rosclient
from .common import json_response, lookup, lookup_owner
from .entities import API_BASE, RELATIONS

bp = Blueprint("discovery", __name__, url_prefix=API_BASE)


@bp.get("/<collection:collection>")
def listing(collection: str):
    items = [e.listing_item() for e in rosclient.get().entities().listing(collection)]
    return json_response({"items": items, "x-medkit": {"total_count": len(items)}})


@bp.get("/<collection:collection>/<entity_id>")
def detail(collection: str, entity_id: str):
    return json_response(lookup(collection, entity_id).detail())


def _relation_view(collection: str, relation: str):
    def view(entity_id: str):
        # medkit's app relation handlers use validate_entity_for_route; the rest name their type.
        owner = lookup(collection, entity_id) if collection == "apps" else lookup_owner(collection, entity_id)
        return json_response(rosclient.get().entities().relation_body(owner, relation))

    view.__name__ = f"{collection}_{relation.replace('-', '_')}"
    return view


for _collection, _relation in RELATIONS:
    bp.add_url_rule(f"/{_collection}/<entity_id>/{_relation}", view_func=_relation_view(_collection, _relation),
                    methods=["GET"])
