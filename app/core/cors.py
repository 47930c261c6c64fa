"""CORS for browser tools served from other origins (flask-cors), off unless ``cors_origins`` is set.

``cors_origins`` (``common/settings.py``) is a comma-separated list of exact
origins (``https://dashboard.example:8443``, ``http://[fd00::10]:8443``: scheme,
host and port, compared as a whole without case, never as a prefix or pattern:
:func:`exact_patterns`), or ``*`` for any origin.  With a
list, an allowed origin is echoed in ``Access-Control-Allow-Origin`` with
``Access-Control-Allow-Credentials: true`` (so a tool behind nginx's own
authentication can send cookies or basic auth) and ``Vary: Origin``; with
``*`` the answer is ``*`` and credentials are never allowed (browsers refuse
that pair, and it would open the API to every site a user visits).  A
disallowed origin gets no CORS header at all: the browser then keeps the
answer from the page.

Preflights (``OPTIONS`` with ``Access-Control-Request-Method``) are answered
for GET, PUT, POST and DELETE with the ``Authorization``, ``Content-Type`` and
``X-Client-Id`` headers, and cached by the browser for ``MAX_AGE`` seconds.  Every route
carries the headers, the event streams included, and so do error answers
(a 429, a 503), whose ``Retry-After``, rate-limit and request-id headers a
page may read (``Access-Control-Expose-Headers``).
"""

from __future__ import annotations

import re

from flask import Flask

from common import settings

METHODS = ["GET", "PUT", "POST", "DELETE"]
ALLOW_HEADERS = ["Authorization", "Content-Type", "X-Client-Id"]  # X-Client-Id: who holds a lock
EXPOSE_HEADERS = ["X-Request-Id", "Retry-After", "X-RateLimit-Limit", "X-RateLimit-Remaining",
                  "X-RateLimit-Reset", "Location"]
MAX_AGE = 600


def init_app(app: Flask) -> None:
    origins = settings.parse_origins(app.config["SOVD"].cors_origins)
    if origins is None:
        return
    from flask_cors import CORS

    anyone = origins == "*"
    CORS(app, origins="*" if anyone else exact_patterns(origins), methods=METHODS, allow_headers=ALLOW_HEADERS,
         expose_headers=EXPOSE_HEADERS, supports_credentials=not anyone, send_wildcard=anyone,
         max_age=MAX_AGE, vary_header=True)


def exact_patterns(origins: tuple[str, ...]) -> list[re.Pattern[str]]:
    """Each origin as a pattern that matches that origin alone, whole, without case.

    flask-cors reads a plain string that holds any of ``*\\]?$^[]()`` as a
    regular expression, matched as a prefix: ``http://[fd00::10]:8443`` became a
    character class that let ``http://d:8443`` and ``http://0:8443`` in and kept
    the configured IPv6 origin out.  Escaped and anchored, no origin is ever a
    pattern, whatever characters it holds.
    """
    return [re.compile(re.escape(origin) + r"\Z", re.IGNORECASE) for origin in origins]
