"""The Dask path: the members cut into chunks, one task per chunk (the system travels with every task, never a
compiled integrator), gathered into one :class:`~lieseries.solution.EnsembleSolution`; reruns and the errors of a
failing cluster (see the package docstring)."""

from __future__ import annotations

import time as _time

from ..solution import EnsembleSolution
from .build import check_batch_size

__all__ = ["run_dask", "dask_failure", "is_dask_error", "DASK_RETRIES"]


def dask_client_class():
    try:
        from distributed import Client
    except ImportError as err:
        raise ImportError(
            "`client=` needs Dask distributed, which is not installed: pip install 'lieseries[distributed]'"
        ) from err
    return Client


#: Times Dask may rerun a chunk whose worker died (on another worker, or on the same one restarted by its nanny).
DASK_RETRIES = 2


def dask_failure(err, what):
    """A RuntimeError naming `client`, saying what happened and what to do."""
    name = type(err).__name__
    if "Cancelled" in name or "KilledWorker" in name:
        cause = (f"a chunk was cancelled or its worker died ({name}: {err}) and could not be rerun "
                 f"({DASK_RETRIES} retries): with a single worker there is nowhere to rerun it")
        todo = "give the cluster more than one worker, or workers with nannies (processes=True) that restart them"
    else:
        cause = f"{name}: {err}"
        todo = "check that the cluster is running and reachable, or pass a new Client"
    return RuntimeError(f"`client`: the Dask run failed while {what} ({cause}); {todo}. Or leave `client` out to "
                        "run the members here.")


def is_dask_error(err) -> bool:
    """An error of Dask's machinery (a cancelled future, a killed worker, a lost connection), not of the run."""
    import asyncio
    import concurrent.futures

    from distributed.comm.core import CommClosedError
    from distributed.scheduler import KilledWorker

    return isinstance(err, (concurrent.futures.CancelledError, asyncio.CancelledError, KilledWorker, CommClosedError,
                            OSError))


def run_dask(client, task, system, Ynat, pars, t, t0, opts, chunk_size, progress, k, until=None):
    """The members on the cluster of ``client``: ``task(system, rows, pars, t, t0, opts, until)`` (a module-level
    function, pickled by reference) runs one chunk on a worker and returns its EnsembleSolution; ``until`` is the
    ensemble's deadline (a ``time.time()`` reading: the workers' clocks are taken to agree with this one's)."""
    Client = dask_client_class()
    if not isinstance(client, Client):
        raise TypeError(f"`client` must be a dask.distributed.Client; got {type(client).__name__}")
    status = str(getattr(client, "status", "running"))
    if status in ("closed", "closing", "failed"):
        raise RuntimeError(f"`client` is {status} (client.status = {status!r}): it can no longer send work to a "
                           "cluster. Create a new dask.distributed.Client (or call client.restart() before closing), "
                           "or leave `client` out to run the members here.")
    if chunk_size is None:
        try:
            threads = sum(client.nthreads().values())
        except Exception:  # pragma: no cover - scheduler unreachable: let submit raise the real error
            threads = 1
        B = check_batch_size(opts.get("batch_size"))
        chunk_size = max(B, -(-k // max(1, 4 * threads)))
        chunk_size = -(-chunk_size // B) * B
    from distributed import as_completed

    start = _time.perf_counter()
    futures = {}
    # the system travels with every task (not scattered once): data scattered to a worker that dies is lost, and
    # every task depending on it would be cancelled; a task that carries its inputs can be rerun elsewhere
    try:
        for lo in range(0, k, chunk_size):
            hi = min(k, lo + chunk_size)
            p = None if pars is None else [list(r) for r in pars[lo:hi]]
            f = client.submit(task, system, Ynat[lo:hi], p, t, t0, opts, until, pure=False, retries=DASK_RETRIES)
            futures[f] = lo
    except Exception as err:
        raise dask_failure(err, "sending the chunks") from err
    parts = {}
    done = 0
    try:
        for f in as_completed(list(futures)):
            part = f.result()
            parts[futures[f]] = part
            done += len(part.status)
            if progress is not None:
                progress(done, k)
    except Exception as err:
        if not is_dask_error(err):
            raise  # an error of the run itself (raised on the worker): as a local run would raise it
        raise dask_failure(err, f"collecting the chunks ({done} of {k} members back)") from err
    ordered = [parts[lo] for lo in sorted(parts)]
    return EnsembleSolution.concatenate(ordered, run_time=_time.perf_counter() - start,
                                        workers=len(client.nthreads()), chunks=len(ordered), chunk_size=chunk_size)
