"""medkit's permission table as data (app/auth/roles.py): its wildcards, the README's table made from it,
what a request is aimed at (app/target.py), and the settings of identities (never a secret in a message)."""

from __future__ import annotations

import argparse

import pytest

from app.auth import roles
from app.core import target
from common import settings
from common.harness.procs import REPO


def test_the_readme_table_is_the_one_the_roles_make():
    text = (REPO / "README.md").read_text()
    assert roles.documented(text) == roles.markdown(), "run: python -m app.auth.roles --write"


def test_medkits_wildcards_and_methods():
    assert roles.allowed("viewer", "GET", "/api/v1/apps/x/data/x")
    assert roles.allowed("viewer", "HEAD", "/api/v1/apps/x/data/x")       # HEAD is a GET
    assert not roles.allowed("viewer", "GET", "/api/v1/apps/x/data/x/y")  # * is one segment
    assert roles.allowed("admin", "DELETE", "/api/v1/a/b/c/d/e")          # ** any number
    assert not roles.allowed("admin", "PATCH", "/api/v1/apps/x")          # a method admin's table lacks
    assert not roles.allowed("root", "GET", "/api/v1/health")             # no such role
    assert roles.allowed("operator", "DELETE", "/api/v1/faults")          # medkit's code, not its docs
    assert not roles.allowed("configurator", "POST", "/api/v1/apps/x/triggers")
    assert roles.allowed("viewer", "GET", "/metrics")                     # this gateway's EXTRA
    # every role's table contains every entry of the roles before it (medkit repeats them)
    for lower, higher in zip(roles.ROLES[:-2], roles.ROLES[1:-1], strict=True):
        assert set(roles.TABLE[lower]) <= set(roles.TABLE[higher])


@pytest.mark.parametrize("method, path, rule, args, expected", [
    ("PUT", "/api/v1/apps/a/data/p/q", "/api/v1/<collection:collection>/<entity_id>/data/<data_id:data_id>",
     {"collection": "apps", "entity_id": "a", "data_id": "p/q"}, ("data", "apps", "a", "/api/v1/apps/x/data/x")),
    ("POST", "/api/v1/components/h/operations/o/s/executions",
     "/api/v1/<any(components,apps,functions):collection>/<entity_id>/operations/<path:op_id>/executions",
     {"collection": "components", "entity_id": "h", "op_id": "o/s"},
     ("operations", "components", "h", "/api/v1/components/x/operations/x/executions")),
    ("POST", "/api/v1/apps/a/bulk-data/c", "/api/v1/apps/<app_id>/bulk-data/<category_id>",
     {"app_id": "a", "category_id": "c"}, ("bulk-data", "apps", "a", "/api/v1/apps/x/bulk-data/x")),
    # bulk data's routes (app/bulk_data/): {category}/{file_id} in one variable, two segments to the table
    ("DELETE", "/api/v1/apps/a/bulk-data/logs/f1", "/api/v1/<any(apps,components):collection>/<entity_id>"
     "/bulk-data/<bulk_rest:rest>", {"collection": "apps", "entity_id": "a", "rest": "logs/f1"},
     ("bulk-data", "apps", "a", "/api/v1/apps/x/bulk-data/x/x")),
    ("POST", "/api/v1/apps/a/bulk-data/logs", "/api/v1/<any(apps,components):collection>/<entity_id>"
     "/bulk-data/<bulk_rest:rest>", {"collection": "apps", "entity_id": "a", "rest": "logs"},
     ("bulk-data", "apps", "a", "/api/v1/apps/x/bulk-data/x")),
    ("DELETE", "/api/v1/faults", "/api/v1/faults", {}, ("faults", None, None, "/api/v1/faults")),
    ("GET", "/api/v1/apps/a", "/api/v1/<collection:collection>/<entity_id>", {"collection": "apps", "entity_id": "a"},
     ("discovery", "apps", "a", "/api/v1/apps/x")),
    ("GET", "/metrics", "/metrics", {}, ("metrics", None, None, "/metrics")),
    ("GET", "/ui/js/main.js", "/ui/<path:name>", {"name": "js/main.js"}, ("ui", None, None, "/ui/x")),
    ("POST", "/api/v1/components/t/operations/c", None, None,   # no route: the raw path, as medkit reads it
     ("operations", "components", "t", "/api/v1/components/t/operations/c")),
])
def test_a_requests_target(method, path, rule, args, expected):
    got = target.parse(method, path, rule, args)
    assert (got.family, got.collection, got.entity_id, got.role_path) == expected
    assert got.write == (method in ("POST", "PUT", "DELETE", "PATCH"))


def test_an_operator_may_upload_and_delete_bulk_data_as_medkits_table_says():
    for method, rest, allowed in (("POST", "logs", True), ("DELETE", "logs/f1", True),
                                  ("DELETE", "logs", False), ("DELETE", "a/b/c", False)):
        got = target.parse(method, f"/api/v1/apps/a/bulk-data/{rest}",
                           "/api/v1/<any(apps,components):collection>/<entity_id>/bulk-data/<bulk_rest:rest>",
                           {"collection": "apps", "entity_id": "a", "rest": rest})
        assert roles.allowed("operator", method, got.role_path) is allowed, (method, rest)
        assert roles.allowed("viewer", method, got.role_path) is False


def test_every_write_route_of_the_app_has_a_family_and_the_roles_know_its_shape():
    """Each write route maps to a family (so the lock check and the audit see it) and to a path the
    role table can match (admin may do everything, as medkit's ** says)."""
    from tests.support.fakeworker import make_app

    app = make_app(None, runtime_dir="/tmp")
    for rule in app.url_map.iter_rules():
        for method in rule.methods & target.WRITE_METHODS:
            args = {name: "apps" if name == "collection" else "x" for name in rule.arguments}
            got = target.parse(method, rule.rule, rule.rule, args)
            assert got.family and got.family not in ("root", "ui"), rule.rule
            assert roles.allowed("admin", method, got.role_path), rule.rule


def load(argv=(), env=None):
    parser = argparse.ArgumentParser()
    settings.add_arguments(parser)
    return settings.load(parser.parse_args(list(argv)), dict(env or {}))


def test_a_secret_is_never_quoted_in_a_refusal():
    secret = "s3cr3t-Value-never-shown"
    for env in ({"SOVD_AUTH_CLIENTS": f"ok:{secret}:superuser"},
                {"SOVD_AUTH_CLIENTS": f"bad id!:{secret}:admin"},
                {"SOVD_AUTH_ENABLED": "1", "SOVD_AUTH_CLIENTS": "a:b:admin", "SOVD_JWT_SECRET": secret}):
        with pytest.raises(settings.ConfigError) as info:
            load(env=env)
        assert secret not in str(info.value)
    with pytest.raises(settings.ConfigError) as info:
        load(["--jwt-secret", secret])
    assert secret not in str(info.value) and "SOVD_JWT_SECRET" in str(info.value)
    clients = settings.parse_clients(f"a:{secret}:viewer")
    assert secret not in repr(clients) and clients[0].secret == secret


def test_auth_clients_may_be_a_toml_array_and_a_secret_may_hold_a_colon(tmp_path):
    path = tmp_path / "gateway.toml"
    path.write_text('auth_enabled = true\njwt_secret = "' + "x" * 32 + '"\n'
                    'auth_clients = ["a:one:two:admin", "b:three:Viewer"]\n')
    cfg = load(["--config", str(path)])
    clients = settings.parse_clients(cfg.auth_clients)
    assert [(c.client_id, c.secret, c.role) for c in clients] == [("a", "one:two", "admin"), ("b", "three", "viewer")]
    assert load().locking_enabled is True and load(["--no-locking-enabled"]).locking_enabled is False
