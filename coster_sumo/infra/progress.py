"""Progress bars on stderr that leave nothing behind on a terminal and end their line in a log.

A bar that closes with ``leave=False`` clears its line with a carriage return and spaces; in a log
file (stderr not a terminal) those are just more characters on the same line, so whatever comes
next (an error naming a file) was appended to the bar's last state. :func:`progress_bar` ends the
line in that case.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

# what a long job takes to show its progress: ``bars(desc, unit, total=None)`` -> a tqdm-like bar
# (a context manager with ``update``); :func:`bars` makes one, quiet or not
Bars = Callable[..., Any]


def progress_bar(desc: str, unit: str, total: float | None = None, quiet: bool = False) -> Any:
    """A tqdm bar on stderr (none with ``quiet``), cleared on a terminal, its line ended in a log."""
    from tqdm import tqdm

    class _Bar(tqdm):  # type: ignore[misc,type-arg]
        def close(self) -> None:
            shown = not self.disable and not getattr(self, "_ended", False)
            self._ended = True
            super().close()
            if not shown:
                return
            stream = getattr(self, "fp", None) or sys.stderr
            if not (hasattr(stream, "isatty") and stream.isatty()):
                stream.write("\n")
                stream.flush()

    tqdm.monitor_interval = 0  # no monitor thread in a process that forks
    return _Bar(total=total, desc=desc, unit=unit, disable=quiet, leave=False, file=sys.stderr, dynamic_ncols=True)


def bars(quiet: bool = False) -> Bars:
    """:func:`progress_bar` with ``quiet`` fixed: a command's ``--quiet`` is a matter of its console,
    handed to the work it runs as this, not as an option of the work."""
    return functools.partial(progress_bar, quiet=quiet)


def process_age_s() -> float:
    """[s] since this process started (its fork, for a command a server runs); 0 where the system
    does not say (no ``/proc``). What ``timings_s.startup_s`` counts from."""
    try:
        stat = Path("/proc/self/stat").read_text()
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        start_ticks = float(stat.rsplit(")", 1)[1].split()[19])  # field 22: starttime, in clock ticks
        return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return 0.0
