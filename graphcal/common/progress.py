"""Progress bars for long work (rich) on stderr when it is a terminal, silenced with quiet=True or GRAPHCAL_QUIET=1.
Without a terminal (a batch job's log file, a pipe) no bar is drawn: a loop that runs longer than LOG_EVERY_S
writes one plain line each LOG_EVERY_S (how far it is, the seconds spent and left at its pace), a shorter one
nothing."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import TypeVar

from rich.console import Console
from rich.progress import track

T = TypeVar("T")
LOG_EVERY_S = 60.0  # seconds between two lines of a loop's progress in a log


def silenced(quiet: bool = False) -> bool:
    """quiet, or the GRAPHCAL_QUIET environment variable set (not 0)."""
    return quiet or os.environ.get("GRAPHCAL_QUIET", "") not in ("", "0")


def progress(items: Iterable[T], description: str, total: int | None = None, quiet: bool = False) -> Iterator[T]:
    """Iterate over items with a progress bar on a terminal, lines in a log (module docstring), unless quiet (or
    GRAPHCAL_QUIET is set)."""
    if silenced(quiet):
        return iter(items)
    console = _terminal()
    if console is None:
        return _logged(items, description, total)
    return track(items, description=description, total=total, transient=True, console=console)


def _logged(items: Iterable[T], description: str, total: int | None) -> Iterator[T]:
    """items, with a line on stderr after each LOG_EVERY_S: 'description: done/total after S s, about L s left'."""
    started = last = time.monotonic()
    for done, item in enumerate(items, 1):
        yield item
        now = time.monotonic()
        if now - last >= LOG_EVERY_S:
            last, spent = now, now - started
            left = f", about {spent / done * (total - done):.0f} s left" if total else ""
            print(f"{description}: {done}{f'/{total}' if total else ''} after {spent:.0f} s{left}", file=sys.stderr,
                  flush=True)


@contextmanager
def status(description: str, quiet: bool = False) -> Iterator[None]:
    """A spinner with `description` while a step without countable items runs, unless quiet."""
    console = None if silenced(quiet) else _terminal()
    if console is None:
        yield
        return
    with console.status(description):
        yield


def _terminal() -> Console | None:
    """A rich console on stderr when stderr is a terminal, else None."""
    console = Console(stderr=True)
    return console if console.is_terminal else None
