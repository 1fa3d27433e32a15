"""Strand chunks on a Dask distributed cluster: ``sagfree.optimize(..., scheduler=ADDRESS)``.

``scheduler`` is the address of a running scheduler ("tcp://host:8786"), a ``distributed.Client``
(used as is, left open), or "local": a LocalCluster of ``workers`` single-threaded worker processes
on this machine, started for the batch and closed after it. The workers must run the same sagfree
and Python packages as the caller (they import sagfree and compile or load its model from their
own ``$SAGFREE_CACHE``).

The batch is cut into the same contiguous chunks as on local processes, one task per chunk; results
stream back as chunks finish and are put back in input order, so they are identical to a local
run. A chunk whose task fails (a worker died, a pickling error) gives each of its strands the record
``on_crash`` makes; the other chunks are unaffected. ``dask.distributed`` is an optional dependency
(``pip install "sagfree[cluster]"``).
"""
from __future__ import annotations

from contextlib import contextmanager

#: Seconds to wait for a scheduler to answer before giving up.
CONNECT_TIMEOUT = 30


def _distributed():
    try:
        import distributed
    except ImportError:
        raise ImportError("running on a Dask cluster needs dask.distributed: pip install 'sagfree[cluster]' "
                          "(or pip install distributed)") from None
    return distributed


@contextmanager
def client_for(scheduler, workers: int):
    """A Client for ``scheduler`` (see module docstring), closed on exit unless it was given."""
    distributed = _distributed()
    if isinstance(scheduler, distributed.Client):
        yield scheduler
    elif scheduler == "local":
        with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster, distributed.Client(cluster) as client:
            yield client
    else:
        with distributed.Client(scheduler, timeout=CONNECT_TIMEOUT) as client:
            yield client


def run_chunks(run_chunk, function, chunks: list, arguments: tuple, scheduler, workers: int, finished,
               on_crash, timeout: float) -> list:
    """[run_chunk(function, chunk, arguments) for chunk in chunks] on the cluster, in order;
    ``finished(k, results)`` as chunk k comes back. If no chunk finishes within ``timeout`` seconds,
    the remaining ones are cancelled and their strands get on_crash records."""
    distributed = _distributed()
    results: list = [None] * len(chunks)
    with client_for(scheduler, workers) as client:
        pending = {client.submit(run_chunk, function, chunk, arguments, pure=False): k
                   for k, chunk in enumerate(chunks)}
        while pending:
            try:
                done = distributed.wait(list(pending), timeout=timeout, return_when="FIRST_COMPLETED").done
            except TimeoutError:
                done = set()
            if not done:
                for future, k in pending.items():
                    future.cancel()
                    results[k] = [on_crash(f"timed out: no chunk finished within {timeout:.0f} s") for _ in chunks[k]]
                    finished(k, results[k])
                break
            for future in done:
                k = pending.pop(future)
                if future.status == "finished":
                    results[k] = future.result()
                else:
                    error = future.exception() if future.status == "error" else future.status
                    results[k] = [on_crash(f"cluster task failed: {error!r}") for _ in chunks[k]]
                future.release()
                finished(k, results[k])
    return results
