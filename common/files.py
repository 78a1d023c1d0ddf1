"""Writing a file so that no reader ever sees half of it."""

from __future__ import annotations

import os
from pathlib import Path


def write_atomically(path: Path, data: bytes, tmp_name: str) -> None:
    """Write ``data`` to ``tmp_name`` in ``path``'s folder, fsync it, then rename it over ``path``.

    The data is on disk before the rename is (a crash cannot leave ``path`` pointing at zeros), and the temporary
    file is removed if anything fails. ``os.open`` with 0o666 lets the umask decide the permissions (``mkstemp``
    would force 0600, unreadable to other users or containers sharing the folder)."""
    tmp = path.parent / tmp_name
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
