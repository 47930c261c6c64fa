"""The dashboard: the static files of ``app/ui/`` at ``/ui/``, and ``/`` redirecting there.

Flask calls these routes in the HTTP workers, like any other.  The page is
plain HTML, CSS and JavaScript modules that talk only to the public API under
``/api/v1`` (the same calls a ``curl`` user makes), so the UI adds no
capability of its own on the server side.  Every URL the page uses is
relative: the redirect says ``ui/``, and the page finds the API at
``../api/v1/`` from where it was loaded, so it works unchanged under a path
prefix behind nginx.

Every answer here carries the security headers of :data:`SECURITY_HEADERS`:
a Content-Security-Policy that allows only the gateway's own origin (and so
no inline script or style), ``nosniff``, and no framing.  A file that is not
there answers the API's JSON 404 (``app/core/errors.py``).
"""

from __future__ import annotations

from pathlib import Path

from flask import Blueprint, Response, redirect, send_from_directory

UI_DIR = Path(__file__).resolve().parent.parent / "ui"

SECURITY_HEADERS = {
    "Content-Security-Policy": ("default-src 'self'; object-src 'none'; base-uri 'self'; "
                                "form-action 'self'; frame-ancestors 'none'"),
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    # Revalidate on every load (ETag / Last-Modified): a new gateway version shows at once.
    "Cache-Control": "no-cache",
}

bp = Blueprint("ui", __name__)


@bp.after_request
def _security_headers(response: Response) -> Response:
    for name, value in SECURITY_HEADERS.items():
        response.headers.setdefault(name, value)
    return response


@bp.get("/")
def root():
    # Relative, so that a path prefix in front of the gateway is kept (Werkzeug leaves it as is).
    return redirect("ui/", 302)


@bp.get("/ui")
def ui_without_slash():
    return redirect("ui/", 308)


@bp.get("/ui/")
def index():
    return send_from_directory(UI_DIR, "index.html")


@bp.get("/ui/<path:name>")
def asset(name: str):
    return send_from_directory(UI_DIR, name)
