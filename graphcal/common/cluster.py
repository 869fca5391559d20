"""Where per-tile work runs: in this process, or on a Dask cluster (dask.distributed) while the factor graph
stays on the driver.

A TaskMap applies a top-level function to a list of jobs (plain arrays in, plain arrays out) and returns the
results in the jobs' order, whichever worker ran each. Given the jobs' costs (any unit, e.g. their returns), a
cluster spreads them so that its workers' loads are even (the largest first, each to the least loaded worker).
open_task_map(address) gives one:

- None: in this process, one job after the other;
- "local" or "local:N": a LocalCluster of N worker processes (default: the cores this process may use), one thread each,
  started here and closed when the block ends (not confined to a core each: their libraries' thread pools,
  open3d's among them, use every core);
- "tcp://HOST:PORT" (or any scheduler address dask.distributed accepts): an existing cluster. The workers
  need graphcal installed; the jobs carry their arrays, so the recording need not be on their disks.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Protocol

import numpy as np

from graphcal.common.errors import ConfigError


class TaskMap(Protocol):
    workers: int

    def __call__(self, function: Callable, jobs: Sequence, costs: Sequence[float] | None = None) -> list: ...


class InProcess:
    """Every job here, in order."""

    workers = 1

    def __call__(self, function: Callable, jobs: Sequence, costs: Sequence[float] | None = None) -> list:
        return [function(job) for job in jobs]


class OnCluster:
    """Every job on a dask.distributed cluster (client), results gathered in the jobs' order."""

    def __init__(self, client):
        self.client = client

    @property
    def workers(self) -> int:
        return max(len(self.client.scheduler_info().get("workers", {})), 1)

    def __call__(self, function: Callable, jobs: Sequence, costs: Sequence[float] | None = None) -> list:
        # each job's arrays go straight to its worker (scatter), not through the scheduler inside a task graph, to
        # the worker balanced_loads gives it (round robin without costs), the costliest first; each job is
        # submitted as soon as its arrays are there, so that workers compute while the next jobs' arrays travel,
        # and its result is fetched as soon as it is done
        from dask.distributed import as_completed

        addresses = sorted(self.client.scheduler_info().get("workers", {}))
        costs = np.ones(len(jobs)) if costs is None else np.asarray(costs, dtype=float)
        where = balanced_loads(costs, max(len(addresses), 1))
        index_of = {}
        for index in np.argsort(-costs, kind="stable").tolist():
            worker = [addresses[where[index]]] if addresses else None
            [held] = self.client.scatter([jobs[index]], workers=worker, hash=False)
            index_of[self.client.submit(function, held, workers=worker, pure=False)] = index
        out = [None] * len(jobs)
        for future, result in as_completed(index_of, with_results=True):
            out[index_of[future]] = result
        return out


def balanced_loads(costs: Sequence[float], workers: int) -> np.ndarray:
    """The worker (0..workers-1) of each job: the costliest first, each to the least loaded worker so far
    (longest processing time first: the largest load is at most 4/3 of the best possible)."""
    load, where = np.zeros(workers), np.zeros(len(costs), np.int64)
    for job in np.argsort(-np.asarray(costs, dtype=float), kind="stable"):
        where[job] = int(np.argmin(load))
        load[where[job]] += costs[job]
    return where


IN_PROCESS = InProcess()


def usable_cores() -> int:
    """The cores this process may run on (its affinity: a worker confined to one core sees one), not the
    machine's."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def local_workers(address: str) -> int:
    """The worker count of "local" (the usable cores) or "local:N"; ConfigError naming the option otherwise."""
    _, _, count = address.partition(":")
    if not count:
        return usable_cores()
    if not count.isdigit() or int(count) < 1:
        raise _not_an_address(address)
    return int(count)


def _not_an_address(address: str) -> ConfigError:
    return ConfigError(f"--dask {address!r}: expected local, local:N (N workers, N >= 1) or a scheduler address such "
                       "as tcp://HOST:PORT")


def _local(address: str) -> bool:
    """Whether the address asks for a LocalCluster here: local or local:N."""
    return address == "local" or address.startswith("local:")


def check_address(address: str) -> None:
    """ConfigError naming the option unless the address is local, local:N or a scheduler's URL (SCHEME://HOST:PORT):
    before a run folder is made."""
    if _local(address):
        local_workers(address)
    elif "://" not in address:
        raise _not_an_address(address)


@contextmanager
def open_task_map(address: str | None, quiet: bool = True) -> Iterator[TaskMap]:
    """The TaskMap of an address (module docstring); a cluster started here is closed on leaving."""
    if address is None:
        yield IN_PROCESS
        return
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as error:  # pragma: no cover - dask is a dependency
        raise ConfigError(f"--dask needs dask.distributed: {error}") from None
    if _local(address):
        with (LocalCluster(n_workers=local_workers(address), threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=50) as cluster, Client(cluster) as client):
            yield OnCluster(client)
        return
    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError) as error:
        raise ConfigError(f"--dask {address!r}: no Dask scheduler answered there ({error})") from None
    with client:
        yield OnCluster(client)
