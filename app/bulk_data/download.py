"""A bulk-data file as an HTTP response: streamed from disk, resumable with ``Range``.

The file is never read into memory: the response's body is the open file in
``wsgi.file_wrapper``, which gunicorn sends with ``socket.sendfile`` (zero-copy and
cooperative in the HTTP workers, ``sendfile.py``; a TLS connection or the test client
read it in ``BLOCK`` pieces).  Headers: ``Content-Length``, ``Content-Disposition:
attachment`` with the file's name, ``Accept-Ranges: bytes``, ``ETag`` and
``Last-Modified`` (so a client can resume only the same file), and
``Access-Control-Expose-Headers`` naming them for a browser (medkit's).

``Range: bytes=a-b`` (one range; ``a-`` and ``-n`` too) answers 206 with
``Content-Range``; a range past the end answers 416 with ``Content-Range: bytes
*/size``; several ranges, a malformed header, or an ``If-Range`` that no longer
matches answer the whole file (200), as RFC 9110 allows.  A file deleted after it
was opened is still served to the end (Linux keeps it while it is open).
"""

from __future__ import annotations

import os
import unicodedata
from urllib.parse import quote

from flask import Response, current_app, request
from werkzeug.http import http_date, parse_if_range_header, parse_range_header
from werkzeug.wsgi import FileWrapper

from ..core.errors import ApiError

BLOCK = 256 * 1024  # bytes per read where the file cannot be sent with sendfile
EXPOSED = "Content-Disposition, Content-Length, Content-Range, Accept-Ranges, ETag, Last-Modified"


def disposition(filename: str) -> str:
    """``attachment; filename="..."`` (ASCII, quotes made ``_``) and ``filename*`` for any other character."""
    ascii_name = unicodedata.normalize("NFKD", filename).encode("ascii", "ignore").decode("ascii")
    ascii_name = "".join(c if 32 <= ord(c) < 127 and c not in '"\\' else "_" for c in ascii_name) or "download"
    value = f'attachment; filename="{ascii_name}"'
    if ascii_name != filename:
        value += "; filename*=UTF-8''" + quote(filename, safe="")
    return value


def _etag(st: os.stat_result) -> str:
    return f'"{st.st_ino:x}-{st.st_size:x}-{st.st_mtime_ns:x}"'


def _range(size: int, etag: str, mtime: float) -> tuple[int, int] | None:
    """``(start, stop)`` asked by ``Range`` and still valid by ``If-Range``; None: the whole file."""
    header = request.headers.get("Range")
    if not header:
        return None
    if_range = request.headers.get("If-Range")
    if if_range:
        parsed = parse_if_range_header(if_range)
        if parsed.etag is not None:
            if f'"{parsed.etag}"' != etag:
                return None
        elif parsed.date is None or int(parsed.date.timestamp()) != int(mtime):
            return None
    ranges = parse_range_header(header)
    if ranges is None or ranges.units != "bytes" or len(ranges.ranges) != 1:
        return None  # malformed or several ranges: the whole file
    bounds = ranges.range_for_length(size)
    if bounds is None:
        raise ApiError(416, "invalid-request", "Requested range not satisfiable",
                       {"details": f"the file has {size} bytes", "range": header[:100], "size": size},
                       headers={"Content-Range": f"bytes */{size}", "Accept-Ranges": "bytes"})
    return bounds


def file_response(path: str, filename: str, mimetype: str, not_found: ApiError) -> Response:
    """The file at ``path`` (whole, or the range asked); ``not_found`` when it is not there any more."""
    try:
        fh = open(path, "rb")  # noqa: SIM115 - closed by the response (its file wrapper)
    except (FileNotFoundError, NotADirectoryError):
        raise not_found from None
    try:
        st = os.fstat(fh.fileno())
        etag = _etag(st)
        bounds = _range(st.st_size, etag, st.st_mtime)
        start, stop = bounds if bounds is not None else (0, st.st_size)
        fh.seek(start)
    except BaseException:
        fh.close()
        raise
    headers = {"Content-Length": str(stop - start), "Accept-Ranges": "bytes", "ETag": etag,
               "Last-Modified": http_date(st.st_mtime), "Content-Disposition": disposition(filename),
               "Access-Control-Expose-Headers": EXPOSED, "Cache-Control": "no-cache"}
    if bounds is not None:
        headers["Content-Range"] = f"bytes {start}-{stop - 1}/{st.st_size}"
    wrapper = request.environ.get("wsgi.file_wrapper", FileWrapper)
    return current_app.response_class(wrapper(fh, BLOCK), status=206 if bounds is not None else 200,
                                      mimetype=mimetype, headers=headers, direct_passthrough=True)
