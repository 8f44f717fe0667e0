"""jaxpose's log lines on the terminal, whatever else configured logging.

`logging.basicConfig` does nothing once any library has given the root logger a handler (JAX's
dependencies do, on import), so a command line that relied on it printed none of jaxpose's INFO
lines: not "resumed from step N", not the chosen rig or the sync offsets.  Each command line calls
`show_logs()` instead: the `jaxpose` and `experiments` loggers get a handler of their own and stop
propagating, so their lines appear exactly once, on stderr, at INFO and above.
"""

from __future__ import annotations

import logging
import sys

LOGGERS = ("jaxpose", "experiments")
FORMAT = "%(asctime)s %(levelname)s %(message)s"
HANDLER_NAME = "jaxpose-terminal"


class _TerminalHandler(logging.StreamHandler):
    """Writes to whatever `sys.stderr` is when a record comes (pytest and notebooks replace it)."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # StreamHandler.__init__ assigns one; the property ignores it
        pass


def show_logs(level: int = logging.INFO) -> None:
    """Send jaxpose's and the experiments' log records at `level` and above to stderr; idempotent."""
    for name in LOGGERS:
        logger = logging.getLogger(name)
        logger.setLevel(level)
        logger.propagate = False
        if not any(handler.get_name() == HANDLER_NAME for handler in logger.handlers):
            handler = _TerminalHandler()
            handler.set_name(HANDLER_NAME)
            handler.setFormatter(logging.Formatter(FORMAT, datefmt="%H:%M:%S"))
            logger.addHandler(handler)
