"""Running independent simulations on several cores (workers forked from a clean fork server,
never from the caller), or on a Dask distributed cluster."""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

#: ``--executor`` value that sends the work to a Dask scheduler: ``dask://HOST:PORT``.
DASK_PREFIX = "dask://"

#: Local workers are forked from a fork server: a fresh interpreter (nothing of the caller's
#: sessions or threads) that imports the workers' modules once, so a worker starts in
#: milliseconds instead of each importing numpy and fxswarm again (about 0.7 s, on every core
#: at once, at the start of every campaign). Windows has no fork server: workers are spawned there.
_FORKSERVER = "forkserver" in multiprocessing.get_all_start_methods()
_CONTEXT = multiprocessing.get_context("forkserver" if _FORKSERVER else "spawn")


def start_workers_early(modules: Sequence[str]) -> None:
    """Start the fork server now, importing ``modules``, while the caller does other work (a
    campaign plans its runs): the workers of :func:`completed` then start at once. Optional."""
    if not _FORKSERVER:
        return
    _CONTEXT.set_forkserver_preload(sorted(set(modules)))
    from multiprocessing import forkserver

    forkserver.ensure_running()


class WorkerLost(RuntimeError):
    """A worker process died (killed, out of memory) with a case in hand: its result is lost."""


def parallel_map(fn: Callable[..., dict], cases: Sequence[tuple], workers: int,
                 progress: Callable[[dict, int, int], None] | None = None) -> list[dict]:
    """``[fn(*case) for case in cases]`` on ``workers`` spawned processes, in completion order.

    ``progress(result, done, total)`` is called after each case. See :func:`completed`.
    """
    results: list[dict] = []
    for _, result in completed(fn, cases, workers):
        results.append(result)
        if progress:
            progress(result, len(results), len(cases))
    return results


def completed(fn: Callable[..., dict], cases: Sequence[tuple], workers: int,
              executor: str | None = None, modules: Sequence[Path] = ()) -> Iterator[tuple[int, dict]]:
    """``(k, fn(*cases[k]))`` for every case, as each finishes.

    ``fn`` must be importable at module level (workers import it again). ``executor``: None
    for local worker processes (``workers`` of them; with ``workers <= 1`` the cases run
    here, in order), or ``dask://HOST:PORT`` for a Dask distributed scheduler. Workers come
    from a fork server (:data:`_CONTEXT`), not a fork of this process: that would copy
    whatever sessions or threads it holds. ``modules``: Python module files or package
    folders the cases import that only this machine has (a user's law); a Dask cluster gets
    them first (local workers share this machine's files). Leaving the loop
    early (Ctrl-C, an exception, ``break``) stops every worker process at once; a worker that
    dies raises :class:`WorkerLost` instead of hanging.
    """
    if executor is not None and executor.startswith(DASK_PREFIX):
        yield from _dask_completed(fn, cases, executor[len(DASK_PREFIX):], modules)
    elif executor not in (None, "local"):
        raise ValueError(f"executor: expected 'local' or '{DASK_PREFIX}HOST:PORT', got {executor!r}")
    elif workers <= 1:
        for k, case in enumerate(cases):
            yield k, fn(*case)
    else:
        yield from _pool_completed(fn, cases, workers)


def _pool_completed(fn, cases, workers) -> Iterator[tuple[int, dict]]:
    pool = ProcessPoolExecutor(min(workers, len(cases)) or 1, mp_context=_CONTEXT, initializer=_worker_started)
    try:
        pending = {pool.submit(fn, *case): k for k, case in enumerate(cases)}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                try:
                    result = future.result()
                except BrokenProcessPool as exc:
                    raise WorkerLost(f"a local worker process died ({exc})") from None
                yield pending.pop(future), result
    finally:
        # Terminate, not wait: Ctrl-C must not sit out the runs in flight (their results are lost
        # either way, and a rerun of a campaign runs them again). Only this pool's workers: the
        # caller's other children are not ours to end. The pool forgets them on shutdown, so they
        # are taken first (Python 3.14 has pool.terminate_workers(); before it, the pool's own table).
        workers = list((pool._processes or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for worker in workers:
            if worker.is_alive():
                worker.terminate()
        for worker in workers:
            worker.join(5.0)


def _worker_started() -> None:
    """In each local worker: Ctrl-C is the caller's to handle (it stops the workers), and a
    worker whose caller died (SIGKILL) exits instead of waiting for work forever. It waits on
    the caller's sentinel (a pipe the caller holds), not on its parent: that is the fork server,
    which stays up as long as any worker does."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    caller = multiprocessing.parent_process()

    def watch() -> None:
        multiprocessing.connection.wait([caller.sentinel])
        os._exit(1)

    if caller is not None:
        threading.Thread(target=watch, daemon=True, name="caller-watch").start()


def _dask_completed(fn, cases, address: str, modules: Sequence[Path]) -> Iterator[tuple[int, dict]]:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ValueError(f"executor {DASK_PREFIX}{address}: Dask is not installed "
                         "(pip install 'fxswarm[campaign]')") from None
    try:
        client = Client(address, timeout="10s")
    except OSError as exc:
        raise ValueError(f"executor {DASK_PREFIX}{address}: no Dask scheduler answers there ({exc})") from None
    futures = []
    try:
        _upload(client, modules)
        # pure=False: two equal cases are still two runs (Dask would otherwise merge them).
        futures = [client.submit(fn, *case, pure=False) for case in cases]
        index = {f.key: k for k, f in enumerate(futures)}
        for future in as_completed(futures):
            if future.status != "finished":  # the scheduler gave up on it (KilledWorker: its workers died)
                raise WorkerLost(f"Dask could not run a case: {future.exception()!r}")
            yield index[future.key], future.result()
    finally:
        client.cancel(futures)
        client.close()


def _upload(client, modules: Sequence[Path]) -> None:
    """Send each module file (a package folder as a zip) to every worker, now and joining later:
    Dask's upload_file puts it in the worker's folder on its import path."""
    with tempfile.TemporaryDirectory(prefix="fxswarm-upload-") as tmp:
        for module in modules:
            module = Path(module)
            if module.is_dir():  # a zip of the package folder imports as the package
                module = Path(shutil.make_archive(str(Path(tmp) / module.name), "zip", module.parent, module.name))
            client.upload_file(str(module))
