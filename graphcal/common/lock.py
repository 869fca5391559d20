"""A file held by one process at a time: an advisory lock (fcntl.flock) on a sibling .lock file, released by the
kernel when its holder ends, even when killed, so a lock is never left behind."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from graphcal.common.errors import ConfigError


@contextmanager
def held_alone(path: Path, what: str) -> Iterator[None]:
    """Hold path (its sibling <name>.lock) for the block; ConfigError naming path, what holds it (what: the
    holder's kind, e.g. "calibration") and its process when another process holds it. The lock file is removed
    on release."""
    lock = path.with_name(path.name + ".lock")
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 64).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise ConfigError(f"{path}: held by another {what} (process {holder}) on this machine; wait for it, or "
                              "give this one another place (--out)") from None
        if _same_file(fd, lock):  # not a lock file its last holder removed after this one opened it
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        yield
    finally:
        lock.unlink(missing_ok=True)
        os.close(fd)


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except FileNotFoundError:
        return False
