"""Progress bars for long work (rich), silenced with quiet=True or GRAPHCAL_QUIET=1."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import TypeVar

from rich.progress import track

T = TypeVar("T")


def silenced(quiet: bool = False) -> bool:
    """quiet, or the GRAPHCAL_QUIET environment variable set (not 0)."""
    return quiet or os.environ.get("GRAPHCAL_QUIET", "") not in ("", "0")


def progress(items: Iterable[T], description: str, total: int | None = None, quiet: bool = False) -> Iterator[T]:
    """Iterate over items with a progress bar unless quiet (or GRAPHCAL_QUIET is set)."""
    return iter(items) if silenced(quiet) else track(items, description=description, total=total, transient=True)


@contextmanager
def status(description: str, quiet: bool = False) -> Iterator[None]:
    """A spinner with `description` while a step without countable items runs, unless quiet."""
    if silenced(quiet):
        yield
        return
    from rich.console import Console

    with Console(stderr=True).status(description):
        yield
