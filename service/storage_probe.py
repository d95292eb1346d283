"""Probing the data directory: does it take writes, how much space is free (used at
start-up by ``otgeo serve``/``otgeo worker`` and by /healthz). No heavy imports: the CLI
checks storage before loading the service."""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

STORAGE_ERRNOS = {errno.EROFS: "read-only file system", errno.ENOSPC: "no space left",
                  errno.EDQUOT: "disk quota exceeded", errno.EACCES: "permission denied",
                  errno.EPERM: "permission denied", errno.ENOTDIR: "not a directory",
                  errno.EEXIST: "a file is in the way", errno.EFBIG: "file too large",
                  errno.EIO: "input/output error"}


def storage_reason(exc: OSError) -> str:
    return STORAGE_ERRNOS.get(exc.errno, exc.strerror or type(exc).__name__)


def storage_status(data_dir: Path, subdirs=()) -> dict:
    """Probe ``data_dir`` (and ``subdirs``): create the directories, write, sync and remove
    a small file in each. ``{"writable", "free_bytes", "reason"}``; ``reason`` names the
    failure without the path."""
    data_dir = Path(data_dir)
    free = None
    try:
        for directory in (data_dir, *subdirs):
            Path(directory).mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=".probe-", dir=directory)
            try:
                os.write(fd, b"otgeo")
                os.fsync(fd)
            finally:
                os.close(fd)
                os.unlink(tmp)
        st = os.statvfs(data_dir)
        free = int(st.f_bavail * st.f_frsize)
    except OSError as exc:
        try:
            st = os.statvfs(data_dir)
            free = int(st.f_bavail * st.f_frsize)
        except OSError:
            pass
        return {"writable": False, "free_bytes": free, "reason": storage_reason(exc)}
    return {"writable": True, "free_bytes": free, "reason": None}
