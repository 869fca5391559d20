"""What the benchmark scripts share: a stage run in its own process, and its peak memory."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import platform
import resource
from pathlib import Path
from queue import Empty


def machine() -> dict:
    """The machine a benchmark ran on: its CPUs, Python and platform (the results' "machine")."""
    return {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}


def peak_gib() -> float:
    """Peak resident memory of this process [GiB] (ru_maxrss is in kB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def run_in_process(target, *args) -> dict:
    """target(*args, queue) in a fresh spawned process (its own peak memory); what it put on the
    queue. Stops with the target's name if the process dies without answering (its traceback is
    printed above), instead of waiting for ever."""
    context = mp.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=target, args=(*args, queue))
    process.start()
    while True:
        try:
            result = queue.get(timeout=5)
            break
        except Empty:
            if not process.is_alive():
                raise SystemExit(f"{target.__name__}{args} failed (exit code {process.exitcode})") from None
    process.join()
    return result


def report(figures: dict, path: Path) -> None:
    """Print the figures (a dict value as a titled group) and write them to `path` as JSON, atomically."""
    from graphcal.common.atomic import atomic_path

    def show(items, indent=""):
        for key, value in items.items():
            if isinstance(value, dict) and all(not isinstance(v, dict) for v in value.values()) and indent == "":
                print(key)
                show(value, "  ")
            else:
                numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
                text = (f"{value:,.3f}" if isinstance(value, float) else f"{value:,}") if numeric else value
                print(f"{indent}{key:>30}: {text}")

    show(figures)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(figures, indent=2))
