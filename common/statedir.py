"""The state directory's files: private to the service user (a directory 0700, files 0600).

The gateway keeps two SQLite stores there: ``faults.db`` (the ROS worker's: faults, their events
and the triggers; ``rosworker/core/store.py``) and ``access.db`` (the HTTP workers': the audit
trail and the revoked tokens; ``app/core/accessdb.py``).  Freeze frames hold robot data and the audit
trail says who did what: neither is for other users of the machine.
"""

from __future__ import annotations

import os

FILE_MODE = 0o600         # the stores' files: the service user's alone
DIR_MODE = 0o700          # a state directory the gateway makes


def make_private_dir(path: str) -> None:
    """``path`` made 0700 if it is not there (its parents as the umask says); one that is stays as it is."""
    if not os.path.isdir(path):
        os.makedirs(path, exist_ok=True)
        os.chmod(path, DIR_MODE)


def private_files(path: str) -> None:
    """The database file made 0600 before SQLite opens it (SQLite gives its -wal and -shm the file's
    mode), and an existing file, -wal or -shm of a looser mode narrowed to 0600."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, FILE_MODE)
    os.close(fd)
    for name in (path, path + "-wal", path + "-shm"):
        try:
            if os.stat(name).st_mode & 0o777 != FILE_MODE:
                os.chmod(name, FILE_MODE)
        except FileNotFoundError:
            pass
