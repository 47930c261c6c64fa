"""JSON Pointers (RFC 6901): a trigger's ``path`` into the message it watches.

Parsed once, where a client sends it (the HTTP side refuses a bad one with
400) and again by the ROS worker when it restores a trigger; resolved on
every message of the trigger's topic.  Standard library only.
"""

from __future__ import annotations

import re
from typing import Any

MAX_LENGTH = 1024
_INDEX = re.compile(r"^(0|[1-9][0-9]{0,9})$")


class MissingType:
    """What a pointer resolves to when the document has nothing there."""

    _instance = None

    def __new__(cls):
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "MISSING"


MISSING = MissingType()


def parse(text: str) -> tuple[str, ...]:
    """The reference tokens of ``text``; raises ValueError (with the reason) for a malformed pointer."""
    if not isinstance(text, str):
        raise ValueError("a JSON Pointer is a string")
    if len(text) > MAX_LENGTH:
        raise ValueError(f"a JSON Pointer has at most {MAX_LENGTH} characters")
    if text == "":
        return ()
    if not text.startswith("/"):
        raise ValueError("a JSON Pointer is empty or starts with '/'")
    tokens = []
    for raw in text[1:].split("/"):
        if re.search(r"~(?![01])", raw):
            raise ValueError("'~' in a JSON Pointer must be followed by '0' or '1'")
        tokens.append(raw.replace("~1", "/").replace("~0", "~"))
    return tuple(tokens)


def resolve(doc: Any, tokens: tuple[str, ...]) -> Any:
    """The value at ``tokens`` in ``doc``, or :data:`MISSING`."""
    for token in tokens:
        if isinstance(doc, dict):
            if token not in doc:
                return MISSING
            doc = doc[token]
        elif isinstance(doc, list):
            if not _INDEX.match(token) or int(token) >= len(doc):
                return MISSING
            doc = doc[int(token)]
        else:
            return MISSING
    return doc
