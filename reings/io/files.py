"""Files written whole or not at all, and the cache folder.

    with atomic_write("out/metrics.json") as f: json.dump(m, f)      # text
    with atomic_write(path, binary=True) as f: np.savez(f, ...)     # bytes
    cache_dir("depth")  ->  $REINGS_CACHE_DIR/depth, else the user cache folder of the platform
                            (platformdirs; on Linux $XDG_CACHE_HOME/reings/depth or ~/.cache/reings/depth)

atomic_write writes to a temporary file in the target's folder and renames it over the target on
success (os.replace is atomic on one filesystem), so an interrupted run never leaves a
half-written metrics.json, cache entry or table; on an exception the temporary file is removed,
and an OSError of the write (a full disk, a file-size limit) is raised again naming the target. The
data is fsynced before the rename.
The temporary name is unique (mkstemp, O_EXCL) and the rename replaces a symlink at the target
instead of writing through it; the file gets the mode open() would give it (0666 & ~umask).
"""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


class WriteError(OSError):
    """A write the OS refused (full disk, size limit, ...): errno kept, the message names the file."""

    def __str__(self) -> str:
        return str(self.strerror)


@contextmanager
def atomic_write(path, binary: bool = False):
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    suffix = os.path.splitext(path)[1]
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=suffix, dir=d)
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes 0600: give the file the mode open() would
        with os.fdopen(fd, "wb" if binary else "w") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())  # on disk before it takes the target's name (a crash leaves old or new)
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(e, OSError) and e.errno is not None and not e.filename:  # a failed write: name the file
            raise WriteError(e.errno, f"writing {path}: {e.strerror or e}") from e
        raise


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    m = os.umask(0o022)
    os.umask(m)
    return m


def cache_dir(sub: str) -> Path:
    """$REINGS_CACHE_DIR/<sub>, else the platform's user cache folder for reings (platformdirs:
    $XDG_CACHE_HOME/reings or ~/.cache/reings on Linux, ~/Library/Caches/reings on macOS,
    %LOCALAPPDATA%\\reings\\Cache on Windows) / <sub>."""
    env = os.environ.get("REINGS_CACHE_DIR")
    if env:
        return Path(env).expanduser() / sub
    try:
        import platformdirs
    except ImportError:  # pragma: no cover - platformdirs comes with pyopencl (pytools)
        return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "reings" / sub
    return Path(platformdirs.user_cache_dir("reings", appauthor=False)) / sub


def read_json(path, missing: str, error=ValueError, what: str = "unreadable"):
    """The JSON value in `path`: FileNotFoundError(`missing`) when there is no file, `error`
    naming the file when it is not JSON (or not UTF-8)."""
    import json

    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise FileNotFoundError(missing) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise error(f"{path}: {what} ({e})") from None
