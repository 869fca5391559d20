"""Where per-tile work runs: in this process, or on a Dask cluster (dask.distributed) while the factor graph
stays on the driver.

A TaskMap applies a top-level function to a list of jobs (plain arrays in, plain arrays out) and returns the
results in the jobs' order, whichever worker ran each. Given the jobs' costs (any unit, e.g. their returns), a
cluster spreads them so that its workers' loads are even (the largest first, each to the least loaded worker).
open_task_map(address) gives one:

- None: in this process, one job after the other;
- "local" or "local:N": a LocalCluster of N worker processes (default: the machine's cores), one thread each,
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
        # each job's arrays go straight to one worker (scatter), not through the scheduler inside a task graph;
        # with costs, to the worker balanced_loads gives it (a scattered job's task runs where its arrays are)
        addresses = sorted(self.client.scheduler_info().get("workers", {}))
        if costs is None or len(addresses) < 2:
            held = self.client.scatter(list(jobs), hash=False)
        else:
            held = [None] * len(jobs)
            where = balanced_loads(costs, len(addresses))
            for worker, address in enumerate(addresses):
                mine = np.flatnonzero(where == worker).tolist()
                for index, future in zip(mine, self.client.scatter([jobs[i] for i in mine], workers=[address],
                                                                   hash=False)):
                    held[index] = future
        return self.client.gather(self.client.map(function, held, pure=False))


def balanced_loads(costs: Sequence[float], workers: int) -> np.ndarray:
    """The worker (0..workers-1) of each job: the costliest first, each to the least loaded worker so far
    (longest processing time first: the largest load is at most 4/3 of the best possible)."""
    load, where = np.zeros(workers), np.zeros(len(costs), np.int64)
    for job in np.argsort(-np.asarray(costs, dtype=float), kind="stable"):
        where[job] = int(np.argmin(load))
        load[where[job]] += costs[job]
    return where


IN_PROCESS = InProcess()


def local_workers(address: str) -> int:
    """The worker count of "local" (the cores) or "local:N"; ConfigError naming the option otherwise."""
    _, _, count = address.partition(":")
    if not count:
        return os.cpu_count() or 1
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
