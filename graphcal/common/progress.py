"""Progress bars for long work (rich) on stderr when it is a terminal, silenced with quiet=True or GRAPHCAL_QUIET=1.
Without a terminal (a log file, a pipe) nothing is drawn: no bar, and no blank line where it was."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import TypeVar

from rich.console import Console
from rich.progress import track

T = TypeVar("T")


def silenced(quiet: bool = False) -> bool:
    """quiet, or the GRAPHCAL_QUIET environment variable set (not 0)."""
    return quiet or os.environ.get("GRAPHCAL_QUIET", "") not in ("", "0")


def progress(items: Iterable[T], description: str, total: int | None = None, quiet: bool = False) -> Iterator[T]:
    """Iterate over items with a progress bar on a terminal unless quiet (or GRAPHCAL_QUIET is set)."""
    console = None if silenced(quiet) else _terminal()
    if console is None:
        return iter(items)
    return track(items, description=description, total=total, transient=True, console=console)


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
