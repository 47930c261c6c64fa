"""Uploaded bulk-data files (medkit's ``BulkDataStore``): on disk, read and written by the HTTP workers.

Layout under ``bulk_data_storage_dir`` (default ``<state_dir>/bulk_data``, 0700)::

    <collection>/<entity id>/<category>/<item id>/descriptor.json   its facts (medkit's descriptor)
    <collection>/<entity id>/<category>/<item id>/<file name>       the bytes
    .incoming/<random>/                                             an upload being received
    .trash/<random>/                                                a deleted item being removed

An item is listed once its directory exists under its category with a readable
``descriptor.json``: an upload is received into ``.incoming`` (the file and then the
descriptor, each fsynced, 0600), and its directory is renamed into place in one step,
so a half-received upload is never listed.  A delete renames the directory to
``.trash`` and removes it there: a download already under way keeps its open file.
Anything left in ``.incoming`` and ``.trash`` (an HTTP worker killed mid-way) is
removed on the next write.

Names are checked before they reach the file system: an entity id is the contract's
(``[A-Za-z0-9_-]``), a category one of ``bulk_data_categories``, an item id
``ID_RE``, with no ``..`` nor separator (400 ``invalid-parameter`` otherwise); the
client's file name is reduced to its last component and to printable characters.

Uploads stream to disk (``werkzeug.sansio.multipart``, the multipart decoder Flask
itself uses, fed ``CHUNK`` bytes at a time): memory stays at a chunk and the form's
small fields, whatever the file's size.  Past ``bulk_data_max_upload_size`` the
upload is refused (413) as soon as that many bytes came (or at once, from its
``Content-Length``); past ``bulk_data_max_total_mb`` of files in all, 507.  A
disk that is full or a directory that is not writable answers 507 / 500 with the
reason, and leaves nothing behind.  fsync and the removal of a tree run in the
event loop's thread pool (``blocking``), so other requests of the worker go on.
"""

from __future__ import annotations

import errno
import json
import os
import re
import secrets
import shutil
import time
import unicodedata
from typing import Any

from werkzeug.exceptions import RequestEntityTooLarge
from werkzeug.http import parse_options_header
from werkzeug.sansio.multipart import Data, Epilogue, Field, File, MultipartDecoder, NeedData

from ..core.errors import ApiError
from ..sse.stream import rfc3339

DESCRIPTOR = "descriptor.json"
INCOMING = ".incoming"
TRASH = ".trash"
CHUNK = 256 * 1024             # bytes read from the client at a time
FIELD_MAX = 64 * 1024          # bytes of description or metadata
PART_HEADERS_MAX = 1 << 20     # bytes the decoder may hold unparsed (a part's headers, the preamble)
MAX_PARTS = 64                 # parts of one upload
MULTIPART_SLACK = 1 << 20      # bytes of a body besides its file (boundaries, headers, small fields)
FILENAME_MAX = 200             # characters of a stored file name
STORAGE_FULL = "x-medkit-insufficient-storage"  # 507's vendor code
ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,255}$")
_UNSAFE = re.compile(r"[\x00-\x1f\x7f/\\]")


def blocking(fn, *args):
    """Run a blocking file-system call off the event loop when the process is gevent's (an HTTP worker)."""
    try:
        from gevent import get_hub
        from gevent.monkey import is_module_patched
    except ImportError:  # pragma: no cover - gevent is a dependency
        return fn(*args)
    if not is_module_patched("os"):
        return fn(*args)
    return get_hub().threadpool.apply(fn, args)


def check_id(value: str, what: str = "bulk-data ID") -> None:
    """400 ``invalid-parameter`` for an id that could leave its directory (``..``, ``/``, ``\\``, NUL ...)."""
    if not ID_RE.match(value) or ".." in value:
        raise ApiError(400, "invalid-parameter", f"Invalid {what}",
                       {"details": f"{what} must be 1-256 letters, digits, '_', '-' and '.', starting with a "
                                   "letter or digit, without '..'", "value": value[:300]})


def safe_filename(given: str | None) -> str:
    """The client's file name as stored: its last path component, printable, at most FILENAME_MAX."""
    name = (given or "").replace("\\", "/").rsplit("/", 1)[-1]
    name = unicodedata.normalize("NFC", _UNSAFE.sub("_", name)).strip().lstrip(".")
    if not name or name == DESCRIPTOR:
        name = "upload"
    return name[:FILENAME_MAX]


def public(desc: dict[str, Any]) -> dict[str, Any]:
    """medkit's ``BulkDataDescriptor`` of an uploaded file."""
    out: dict[str, Any] = {"id": desc["id"], "name": desc["name"], "mimetype": desc["mime_type"],
                           "size": desc["size"], "creation_date": rfc3339(desc["created_ns"]).decode()}
    if desc.get("description"):
        out["description"] = desc["description"]
    if desc.get("metadata"):
        out["x-medkit"] = desc["metadata"]
    return out


class FileStore:
    """One storage directory (every HTTP worker has its own object over the same directory)."""

    def __init__(self, root: str, categories: list[str], max_upload: int, max_total: int):
        self.root = os.path.abspath(root)
        self.categories = categories
        self.max_upload = max_upload
        self.max_total = max_total

    def _dir(self, collection: str, entity_id: str, category: str, item_id: str | None = None) -> str:
        parts = [self.root, collection, entity_id, category] + ([item_id] if item_id else [])
        path = os.path.join(*parts)
        if os.path.commonpath([self.root, os.path.abspath(path)]) != self.root:  # never, after the checks
            raise ApiError(400, "invalid-parameter", "Invalid bulk-data path")
        return path

    # ---- reads ------------------------------------------------------------------------------------------
    def items(self, collection: str, entity_id: str, category: str) -> list[dict[str, Any]]:
        folder = self._dir(collection, entity_id, category)
        try:
            names = os.listdir(folder)
        except (FileNotFoundError, NotADirectoryError):
            return []
        found = [d for d in (self._descriptor(os.path.join(folder, n)) for n in names if ID_RE.match(n)) if d]
        return sorted(found, key=lambda d: (d["created_ns"], d["id"]))

    def find(self, collection: str, entity_id: str, category: str, item_id: str) -> tuple[dict, str] | None:
        """``(descriptor, payload path)`` of an item, or None."""
        folder = self._dir(collection, entity_id, category, item_id)
        desc = self._descriptor(folder)
        return (desc, os.path.join(folder, desc["file"])) if desc else None

    @staticmethod
    def _descriptor(folder: str) -> dict[str, Any] | None:
        try:
            with open(os.path.join(folder, DESCRIPTOR), "rb") as fh:
                desc = json.loads(fh.read(1 << 20))
            if not (isinstance(desc, dict) and isinstance(desc.get("id"), str) and isinstance(desc.get("file"), str)
                    and isinstance(desc.get("size"), int) and isinstance(desc.get("created_ns"), int)):
                return None
            if os.path.basename(folder) != desc["id"] or safe_filename(desc["file"]) != desc["file"]:
                return None
            desc.setdefault("name", desc["file"])
            desc.setdefault("mime_type", "application/octet-stream")
            return desc
        except (OSError, ValueError):
            return None

    def usage(self) -> int:
        """Bytes of the stored files (descriptors and what is being received left out)."""
        total = 0
        for top, dirs, files in os.walk(self.root):
            if top == self.root:
                dirs[:] = [d for d in dirs if d not in (INCOMING, TRASH)]
            for name in files:
                if name != DESCRIPTOR:
                    try:
                        total += os.lstat(os.path.join(top, name)).st_size
                    except OSError:
                        pass
        return total

    # ---- writes -----------------------------------------------------------------------------------------
    def delete(self, collection: str, entity_id: str, category: str, item_id: str) -> bool:
        folder = self._dir(collection, entity_id, category, item_id)
        if self._descriptor(folder) is None:
            return False
        trash = os.path.join(self.root, TRASH, secrets.token_hex(8))
        try:
            _private_dirs(os.path.dirname(trash))
            os.rename(folder, trash)
        except FileNotFoundError:
            return False  # deleted by another request meanwhile
        except OSError as exc:
            raise _storage_error("deleted", exc) from None
        blocking(shutil.rmtree, trash, True)
        return True

    def upload(self, collection: str, entity_id: str, category: str, stream, boundary: bytes) -> dict[str, Any]:
        """Receive a multipart body from ``stream`` into a new item; its descriptor."""
        self._sweep()
        staging = os.path.join(self.root, INCOMING, secrets.token_hex(8))
        try:
            _private_dirs(staging)
        except OSError as exc:
            raise _storage_error("stored", exc) from None
        try:
            desc = self._receive(staging, stream, boundary, category)
            if self.usage() + desc["size"] > self.max_total:
                raise storage_full(self.max_total)
            final = self._dir(collection, entity_id, category, desc["id"])
            _private_dirs(os.path.dirname(final))
            os.rename(staging, final)
            _fsync_dir(os.path.dirname(final))
        except BaseException:
            blocking(shutil.rmtree, staging, True)
            raise
        return desc

    def _receive(self, staging: str, stream, boundary: bytes, category: str) -> dict[str, Any]:
        decoder = MultipartDecoder(boundary, PART_HEADERS_MAX, max_parts=MAX_PARTS)
        fields: dict[str, bytearray] = {}
        file_part: dict[str, Any] | None = None
        fd = -1
        current: str | None = None   # "file", a field's name, or None: a part that is skipped
        size = 0
        try:
            while True:
                try:
                    event = decoder.next_event()
                except ValueError as exc:
                    raise _malformed(str(exc)) from None
                if isinstance(event, NeedData):
                    chunk = stream.read(CHUNK)
                    try:
                        decoder.receive_data(chunk or None)
                    except RequestEntityTooLarge:
                        raise _malformed(f"a part's headers (or the preamble) exceed {PART_HEADERS_MAX} bytes") from None
                elif isinstance(event, File) and event.name == "file" and file_part is None:
                    file_part = {"filename": safe_filename(event.filename),
                                 "mime_type": _mime(event.headers.get("Content-Type"))}
                    fd = os.open(os.path.join(staging, file_part["filename"]),
                                 os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
                    current = "file"
                elif isinstance(event, (File, Field)):
                    current = event.name if event.name in ("description", "metadata") and \
                        event.name not in fields and isinstance(event, Field) else None
                    if current:
                        fields[current] = bytearray()
                elif isinstance(event, Data):
                    if current == "file":
                        size += len(event.data)
                        if size > self.max_upload:
                            raise ApiError(413, "payload-too-large", "File size exceeds maximum upload limit",
                                           {"max_upload_size": self.max_upload})
                        _write_all(fd, event.data)
                    elif current:
                        fields[current] += event.data
                        if len(fields[current]) > FIELD_MAX:
                            raise ApiError(400, "invalid-parameter", f"The '{current}' field is too long",
                                           {"details": f"at most {FIELD_MAX} bytes"})
                    if not event.more_data:
                        current = None
                elif isinstance(event, Epilogue):
                    break
            if file_part is None:
                raise ApiError(400, "invalid-request", "Missing 'file' field in multipart/form-data request")
            blocking(os.fsync, fd)
        except OSError as exc:
            raise _storage_error("stored", exc) from None
        finally:
            if fd >= 0:
                os.close(fd)
        description = _text(fields.get("description"), "description")
        metadata = _metadata(fields.get("metadata"))
        now = time.time_ns()
        desc = {"id": f"{category}_{now}_{secrets.token_hex(4)}", "category": category,
                "name": file_part["filename"], "file": file_part["filename"], "mime_type": file_part["mime_type"],
                "size": size, "created_ns": now, "description": description, "metadata": metadata}
        try:
            path = os.path.join(staging, DESCRIPTOR)
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
            try:
                _write_all(fd, json.dumps(desc).encode())
                blocking(os.fsync, fd)
            finally:
                os.close(fd)
        except OSError as exc:
            raise _storage_error("stored", exc) from None
        return desc

    def _sweep(self) -> None:
        """Remove what a killed HTTP worker left in ``.incoming`` or ``.trash`` (older than a day / any)."""
        for folder, min_age in ((INCOMING, 86400.0), (TRASH, 0.0)):
            top = os.path.join(self.root, folder)
            try:
                names = os.listdir(top)
            except OSError:
                continue
            for name in names:
                path = os.path.join(top, name)
                try:
                    if time.time() - os.lstat(path).st_mtime >= min_age:
                        blocking(shutil.rmtree, path, True)
                except OSError:
                    pass


def boundary_of(content_type: str | None) -> bytes:
    """The multipart boundary of a ``multipart/form-data`` body, or the contract's 415/400."""
    media_type, options = parse_options_header(content_type or "")
    if media_type.lower() != "multipart/form-data":
        raise ApiError(415, "invalid-request", "Unsupported Content-Type: an upload is multipart/form-data",
                       {"details": "send the file as a multipart/form-data part named 'file' (curl -F file=@...)",
                        "content_type": (content_type or "")[:100]})
    boundary = options.get("boundary", "")
    if not 0 < len(boundary) <= 70 or not all(32 <= ord(c) < 127 for c in boundary):
        raise ApiError(400, "invalid-request", "Invalid multipart/form-data boundary",
                       {"details": "the Content-Type needs a boundary of 1-70 printable characters"})
    return boundary.encode("ascii")


def storage_full(max_total: int) -> ApiError:
    return ApiError(507, "vendor-error", "The bulk-data storage is full",
                    {"details": f"the uploaded files would take more than bulk_data_max_total_mb "
                                f"({max_total // 2**20} MB); delete some first", "max_total_bytes": max_total},
                    vendor_code=STORAGE_FULL)


def _malformed(why: str) -> ApiError:
    return ApiError(400, "invalid-request", "Malformed multipart/form-data body", {"details": why[:300]})


def _mime(value: str | None) -> str:
    media_type, _ = parse_options_header(value or "")
    media_type = media_type.strip().lower()
    return media_type if re.match(r"^[a-z0-9!#$&^_.+-]{1,64}/[a-z0-9!#$&^_.+-]{1,64}$", media_type) \
        else "application/octet-stream"


def _text(raw: bytearray | None, what: str) -> str:
    if raw is None:
        return ""
    try:
        return bytes(raw).decode("utf-8")
    except UnicodeDecodeError:
        raise ApiError(400, "invalid-parameter", f"The '{what}' field is not UTF-8 text") from None


def _metadata(raw: bytearray | None) -> dict[str, Any]:
    text = _text(raw, "metadata")
    if not text.strip():
        return {}
    try:
        value = json.loads(text)
    except ValueError:
        raise ApiError(400, "invalid-parameter", "Invalid JSON in 'metadata' field") from None
    if not isinstance(value, dict):
        raise ApiError(400, "invalid-parameter", "metadata must be a JSON object")
    return value


def _private_dirs(path: str) -> None:
    """``os.makedirs`` with every directory it makes 0700 (makedirs gives the parents the umask's mode)."""
    missing = []
    while not os.path.isdir(path):
        missing.append(path)
        path = os.path.dirname(path)
    for folder in reversed(missing):
        try:
            os.mkdir(folder, 0o700)
        except FileExistsError:
            pass


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _fsync_dir(path: str) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        blocking(os.fsync, fd)
    finally:
        os.close(fd)


def _storage_error(done: str, exc: OSError) -> ApiError:
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return ApiError(507, "vendor-error", f"The file could not be {done}: the disk is full",
                        {"details": str(exc)[:300]}, vendor_code=STORAGE_FULL)
    return ApiError(500, "internal-error", f"The file could not be {done}",
                    {"details": f"{exc.strerror or exc} (the bulk-data storage directory)"[:300]})
