"""Where per-tile work runs: in this process, or on a Dask cluster (dask.distributed) while the factor graph
stays on the driver.

A TaskMap applies a top-level function to a list of jobs (plain arrays in, plain arrays out) and returns the
results in the jobs' order, whichever worker ran each. Given the jobs' costs (any unit, e.g. their returns), a
cluster sends the costliest first and gives each worker the costliest job left whenever one of its jobs is done,
so that the workers finish together even where the costs are only estimates.
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


IN_FLIGHT = 2  # a worker's jobs sent at once: one computing, the next one's arrays on their way


class OnCluster:
    """Every job on a dask.distributed cluster (client), results gathered in the jobs' order."""

    def __init__(self, client):
        self.client = client

    @property
    def workers(self) -> int:
        return max(len(self.client.scheduler_info().get("workers", {})), 1)

    def __call__(self, function: Callable, jobs: Sequence, costs: Sequence[float] | None = None) -> list:
        # each job's arrays go straight to a worker (scatter), not through the scheduler inside a task graph, and
        # the job is pinned there; the costliest first, IN_FLIGHT a worker at a time (it computes one while the
        # next one's arrays travel), and each time one of its jobs is done the worker gets the costliest job left:
        # the loads even out whatever the costs' errors; results are fetched as soon as they are done
        from dask.distributed import as_completed

        addresses = sorted(self.client.scheduler_info().get("workers", {})) or [None]
        order = iter(np.argsort(-(np.ones(len(jobs)) if costs is None else np.asarray(costs, float)), kind="stable"))
        index_of, worker_of, done = {}, {}, as_completed(with_results=True)

        def send(worker) -> None:
            index = next(order, None)
            if index is not None:
                where = None if worker is None else [worker]
                [held] = self.client.scatter([jobs[index]], workers=where, hash=False, direct=True)
                future = self.client.submit(function, held, workers=where, pure=False)
                index_of[future], worker_of[future] = int(index), worker
                done.add(future)

        for _ in range(IN_FLIGHT):
            for worker in addresses:
                send(worker)
        out = [None] * len(jobs)
        for future, result in done:
            out[index_of.pop(future)] = result
            send(worker_of.pop(future))
        return out


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
