"""Progress bars for long work (rich), silenced with quiet=True or GRAPHCAL_QUIET=1."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from typing import TypeVar

from rich.progress import track

T = TypeVar("T")


def progress(items: Iterable[T], description: str, total: int | None = None, quiet: bool = False) -> Iterator[T]:
    """Iterate over items with a progress bar unless quiet (or GRAPHCAL_QUIET is set)."""
    quiet = quiet or os.environ.get("GRAPHCAL_QUIET", "") not in ("", "0")
    return iter(items) if quiet else track(items, description=description, total=total, transient=True)
