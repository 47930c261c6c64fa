"""Request bodies: the one reader of every route that takes a JSON body.

A view function calls :func:`json_object` on its request greenlet (the HTTP
worker's event loop, ``app/http_worker.py``), after it has checked what it can
without the body.  Every route that takes a body reads it here and nowhere
else: cyclic subscriptions (POST, PUT), data (PUT, through
``requests.publish_body``), and whatever route takes a body next.  The
answers, in the order they are checked:

- **415** unless the body is declared ``Content-Type: application/json``
  (parameters such as ``charset`` allowed, media type compared without case).
  This is what keeps other web sites out: a page may send a "simple"
  cross-origin request (``text/plain``, a form) without a preflight, so no
  CORS decision is ever asked for; ``application/json`` always takes a
  preflight, which only ``cors_origins`` can allow (``app/core/cors.py``);
- **413** for a body past ``max_body_bytes``, with a Content-Length (refused
  before it is read) or chunked (read up to one byte past the limit, never
  cut silently);
- **400** for a body that breaks its own framing (a bad chunk size, a chunk
  without its CRLF, fewer bytes than announced), whatever exception the
  server's reader raises, and without a traceback in the log;
- **408** when the body does not arrive within ``body_timeout``
  (``http_worker.BodyTimeout``, passed through);
- **400** for a body that is not JSON, or not a JSON object.
"""

from __future__ import annotations

import re
from typing import Any

import orjson
from flask import current_app, request
from werkzeug.exceptions import HTTPException, RequestEntityTooLarge
from werkzeug.http import parse_options_header

from .errors import ApiError

JSON_MEDIA_TYPE = "application/json"
_NON_FINITE_LITERAL = re.compile(rb"[:,\[]\s*-?(?:NaN|Infinity)\b")  # JavaScript's spellings


def json_object(expected: str) -> dict[str, Any]:
    """The request's body as a JSON object, or the contract's 415/413/408/400.

    ``expected`` shows the shape the route wants, for the 400 of a body that
    is JSON but not an object (``{"type": "pkg/msg/Name", "data": {...}}``).
    """
    require_json_content_type()
    raw = read_body()
    try:
        body = orjson.loads(raw)
    except orjson.JSONDecodeError as exc:
        details = str(exc)
        if "infinity" in details or _NON_FINITE_LITERAL.search(raw):  # 1e999, or NaN/Infinity
            details += '; JSON has no NaN or infinity: write them as "NaN", "Infinity", "-Infinity"'
        raise ApiError(400, "invalid-request", "Request body is not valid JSON",
                       {"details": details}) from None
    if not isinstance(body, dict):
        raise ApiError(400, "invalid-request", "Request body must be a JSON object",
                       {"details": f"expected {expected}"})
    return body


def require_json_content_type() -> None:
    """415 ``invalid-request`` unless the request says ``Content-Type: application/json``."""
    given = request.headers.get("Content-Type", "")
    media_type, _ = parse_options_header(given)
    if media_type.strip().lower() == JSON_MEDIA_TYPE:
        return
    raise ApiError(415, "invalid-request", "Unsupported Content-Type: the body must be JSON",
                   {"details": "send the body with the header 'Content-Type: application/json'",
                    "content_type": given[:100]})


def read_body() -> bytes:
    """The whole request body; 413 past ``MAX_CONTENT_LENGTH``, 400 when it cannot be read."""
    try:
        return _read_limited_body()
    except HTTPException:  # 413, the body deadline's 408, Werkzeug's 400 for a short body
        raise
    except Exception as exc:  # gunicorn's NoMoreData, InvalidChunkSize, ChunkMissingTerminator …
        raise ApiError(400, "invalid-request", "Request body could not be read",
                       {"details": f"malformed request body ({type(exc).__name__})"}) from None


def _read_limited_body() -> bytes:
    # With a Content-Length, Werkzeug refuses an oversized body before reading it.
    if request.content_length is not None:
        return request.get_data(cache=False)
    # Without one (a chunked upload) Werkzeug would cut the body at the limit without
    # a word, so one byte more than the limit is read to tell.
    limit = current_app.config["MAX_CONTENT_LENGTH"]
    stream = request.environ.get("wsgi.input")
    if stream is None or not request.environ.get("wsgi.input_terminated"):
        return b""  # the server cannot say where an unsized body ends: treat it as empty
    chunks, size = [], 0
    while size <= limit:
        chunk = stream.read(limit + 1 - size)
        if not chunk:
            break
        chunks.append(chunk)
        size += len(chunk)
    if size > limit:
        raise RequestEntityTooLarge()
    return b"".join(chunks)
