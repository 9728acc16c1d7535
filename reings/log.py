"""The `reings` logger: stage lines and notes go to `logging.getLogger("reings")`.

As a library reings says nothing unless the application configures logging (a NullHandler is
attached; `logging.basicConfig(level=logging.INFO)` shows the stage lines). The command line calls
`configure_cli(quiet)`: messages to stderr, and with --quiet only errors (Python warnings and the
OpenCL compiler's output silenced too). Progress bars are drawn only when stderr is a terminal
(`progress_enabled`).
"""
from __future__ import annotations

import logging
import sys

logger = logging.getLogger("reings")
logger.addHandler(logging.NullHandler())


class _StderrHandler(logging.StreamHandler):
    """A StreamHandler on whatever sys.stderr is when a message is written (not when the
    handler was made: tests and applications replace sys.stderr)."""

    def __init__(self):
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):  # logging.StreamHandler.__init__ assigns it
        pass


def configure_cli(quiet: bool = False) -> None:
    """Logging for the `reings` command: one line per message on stderr; --quiet: errors only,
    warnings ignored."""
    import warnings

    for h in list(logger.handlers):
        if getattr(h, "_reings_cli", False):
            logger.removeHandler(h)
    h = _StderrHandler()
    h.setFormatter(logging.Formatter("%(message)s"))
    h._reings_cli = True  # type: ignore[attr-defined]
    logger.addHandler(h)
    logger.setLevel(logging.ERROR if quiet else logging.INFO)
    if quiet:
        warnings.simplefilter("ignore")


def progress_enabled(quiet: bool) -> bool:
    """Whether to draw progress bars: not quiet, and stderr is a terminal."""
    if quiet:
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False
