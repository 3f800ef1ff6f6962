"""Where the work runs: this process, a local Dask cluster, or an existing Dask scheduler.

``dispatch(fn, jobs, scheduler=...)`` runs ``fn(job)`` for every job and hands each result to
``on_result(index, result)`` as soon as it arrives (in completion order; the caller orders by
index, which is what makes the output independent of the scheduler). The scheduler is

    "serial"          this process, one job after the other (no Dask)
    "local" / None    a Dask LocalCluster on 127.0.0.1, one single-threaded worker process per core
    "tcp://host:port" an existing Dask scheduler (``dask scheduler`` plus ``dask worker``)

Failure handling:

* a job that raises is returned as ``TaskError`` (its traceback as text), never re-raised: the
  run goes on;
* a worker that dies loses nothing already received here; Dask reschedules its running and
  queued tasks on the other workers (a task that kills ``distributed.scheduler.allowed-failures``
  workers in a row, 3 by default, comes back as a ``TaskError`` naming ``KilledWorker``);
* Ctrl-C (KeyboardInterrupt) cancels what is left and returns with ``interrupted = True``; every
  result received so far has been handed to ``on_result``.

The progress (``hil.verdicts.progress.Meter`` on stderr) shows count, share, rate and time left; on a
terminal it is redrawn every half second whether or not a job finished, so it never sits still
while work goes on, and a log gets a line per tenth of the jobs.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

if TYPE_CHECKING:
    from ..verdicts.progress import Meter

#: how long a remote scheduler may take to show a first worker before the run is refused
WORKER_WAIT_S = 60.0
#: submission order of the jobs on Dask: index * SPREAD mod 1 (the golden ratio's fraction)
SPREAD = (5 ** 0.5 - 1) / 2


@dataclass(frozen=True)
class TaskError:
    """A job that raised (or killed its workers): the error and its traceback, as text."""

    message: str
    traceback: str


@dataclass
class DispatchInfo:
    scheduler: str                 #: "serial", "local" or the address given
    address: str | None = None     #: the Dask scheduler actually used (a LocalCluster's own address)
    workers: list[str] = field(default_factory=list)  #: addresses of the workers that ran jobs
    interrupted: bool = False
    elapsed_s: float = 0.0         #: the whole dispatch, cluster start included
    startup_s: float = 0.0         #: of which starting or reaching the cluster

    @property
    def workers_used(self) -> int:
        return len(self.workers)

    def as_dict(self) -> dict:
        return {"scheduler": self.scheduler, "scheduler_address": self.address, "workers_used": self.workers_used,
                "workers": sorted(self.workers), "interrupted": self.interrupted, "elapsed_s": self.elapsed_s,
                "startup_s": self.startup_s}


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 over the sources of hil and plant_models as this process imports them: a worker
    running other code (an older checkout on a cluster node) would give other results."""
    import plant_models

    h = hashlib.sha256()
    for root in (Path(__file__).resolve().parent.parent, Path(plant_models.__file__).resolve().parent):
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(root.parent).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _call(fn: Callable, index: int, job: Any) -> tuple[int, Any, str, str]:
    """Runs on the worker: the job's result or its error, which worker ran it, and its code."""
    try:
        from distributed import get_worker

        where = get_worker().address
    except (ImportError, ValueError):
        where = "this process"
    try:
        return index, fn(job), where, code_fingerprint()
    except Exception as exc:  # noqa: BLE001 - recorded, not fatal
        return index, TaskError(f"{type(exc).__name__}: {exc}", traceback.format_exc()), where, code_fingerprint()


def local_workers(requested: int | None = None) -> int:
    """``requested``, or the cores this process may run on."""
    if requested:
        return max(1, requested)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def dispatch(fn: Callable, jobs: list, on_result: Callable[[int, Any], None], *, scheduler: str | None = None,
             workers: int | None = None, label: str = "jobs", progress: bool = True) -> DispatchInfo:
    """Run ``fn`` over ``jobs`` on ``scheduler``; ``workers`` sizes a local cluster (default: the cores);
    ``label`` names the jobs in the progress line (and the Dask task keys)."""
    from ..verdicts.progress import Meter  # here: a Dask worker importing this module for _call needs no progress

    scheduler = scheduler or "local"
    info = DispatchInfo(scheduler)
    t0 = time.perf_counter()
    bar = Meter(label, len(jobs), enabled=progress)
    try:
        if scheduler == "serial":
            _serial(fn, jobs, on_result, info, bar)
        else:
            _dask(fn, jobs, on_result, info, bar, scheduler, workers, label)
    except KeyboardInterrupt:  # while the cluster started or stopped: nothing more to keep than what arrived
        info.interrupted = True
    finally:
        bar.close()
        info.elapsed_s = time.perf_counter() - t0
    return info


def _serial(fn, jobs, on_result, info: DispatchInfo, bar: Meter) -> None:
    try:
        for i, job in enumerate(jobs):
            _, value, where, _ = _call(fn, i, job)
            if where not in info.workers:
                info.workers.append(where)
            on_result(i, value)
            bar.advance()
    except KeyboardInterrupt:
        info.interrupted = True


def _connect(scheduler: str, workers: int | None):
    """(client, cluster or None) for ``scheduler``; a clear error when it cannot be reached."""
    from distributed import Client, LocalCluster

    if scheduler == "local":
        cluster = LocalCluster(n_workers=local_workers(workers), threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=":0", silence_logs=logging.CRITICAL)
        return Client(cluster), cluster
    if "://" not in scheduler:
        raise ValueError(f"--scheduler {scheduler!r}: give 'local', 'serial' or a Dask scheduler address such as tcp://host:8786")
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise ValueError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})") from None
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except TimeoutError:
        client.close()
        raise ValueError(f"--scheduler {scheduler}: no worker attached within {WORKER_WAIT_S:g} s (start one: dask "
        f"worker {scheduler})") from None
    return client, None


def _dask(fn, jobs, on_result, info: DispatchInfo, bar: Meter, scheduler: str, workers: int | None, label: str) -> None:
    from distributed import as_completed

    t0 = time.perf_counter()
    client, cluster = _connect(scheduler, workers)
    info.startup_s = time.perf_counter() - t0
    info.address = client.scheduler.address
    futures = []
    try:
        # one task per job, unique keys (pure=False): a re-run never reuses a cached result. Dask
        # starts tasks in submission order; neighbouring jobs cost alike (a grid row, a block of
        # electrical recordings), so they are submitted spread out (golden-ratio order): cheap and
        # dear jobs mix, the count moves evenly, and a partial table covers the whole grid
        order = sorted(range(len(jobs)), key=lambda i: (i * SPREAD) % 1.0)
        futures = [
            client.submit(_call, fn, i, jobs[i], pure=False, key=f"{label.replace(' ', '-')}-{i}-{os.urandom(4).hex()}")
            for i in order
        ]
        index_of = {f.key: i for i, f in zip(order, futures)}
        done = as_completed(futures, with_results=True, raise_errors=False)
        while not done.is_empty():
            batch = done.next_batch(block=False)
            if not batch:
                time.sleep(0.1)
                bar.tick()  # elapsed, rate and time left move between results
                continue
            for future, result in batch:
                if future.status != "finished":  # the task never returned (KilledWorker, cancelled)
                    exc = result[1] if isinstance(result, tuple) and len(result) == 3 else result
                    value = TaskError(f"{type(exc).__name__}: {exc}", "".join(traceback.format_exception(exc)))
                    i = index_of[future.key]
                else:
                    i, value, where, code = result
                    if code != code_fingerprint():
                        value = TaskError(
                            f"worker {where} runs other hil/plant_models code (fingerprint {code}, here "
                            f"{code_fingerprint()}): install the same checkout on every worker",
                            "",
                        )
                    if where not in info.workers:
                        info.workers.append(where)
                future.release()
                on_result(i, value)
                bar.advance()
    except KeyboardInterrupt:
        info.interrupted = True
        client.cancel(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
