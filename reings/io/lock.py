"""The per-run lock of `reings eval` and its Dask tasks: an exclusive, non-blocking lock on
`<run folder>/.lock` (fcntl.flock on POSIX, msvcrt.locking on Windows), freed when the holding
process ends however it ends."""
from __future__ import annotations

import os


class RunLock:
    """An exclusive, non-blocking lock on `<folder>/.lock`, freed when the process ends: fcntl.flock
    on POSIX, msvcrt.locking on Windows (the equivalent; no extra package)."""

    def __init__(self, folder: str):
        self.path = os.path.join(folder, ".lock")
        self.fd = None

    def acquire(self) -> bool:
        import socket

        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            _lock(fd)
        except OSError:
            os.close(fd)
            return False
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {socket.gethostname()}\n".encode())
        self.fd = fd
        return True

    def release(self) -> None:
        if self.fd is not None:
            _unlock(self.fd)
            os.close(self.fd)
            self.fd = None


def _lock(fd: int) -> None:
    """Non-blocking exclusive lock of an open file; OSError when another process holds it."""
    try:
        import fcntl
    except ImportError:  # Windows
        import msvcrt

        os.lseek(fd, 0, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        return
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def _unlock(fd: int) -> None:
    try:
        import fcntl
    except ImportError:  # Windows
        import msvcrt

        os.lseek(fd, 0, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
        return
    fcntl.flock(fd, fcntl.LOCK_UN)
