"""Running independent simulations on several cores (spawned workers, never forked)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context


def parallel_map(fn: Callable[..., dict], cases: Sequence[tuple], workers: int,
                 progress: Callable[[dict, int, int], None] | None = None) -> list[dict]:
    """``[fn(*case) for case in cases]`` on ``workers`` spawned processes, in completion order.

    ``fn`` must be importable at module level (spawned workers re-import it). Spawn, not
    fork: a fork would copy whatever sessions or threads the parent holds. With
    ``workers <= 1`` it runs here, in order. ``progress(result, done, total)`` is called
    after each case.
    """
    results: list[dict] = []
    if workers <= 1:
        for case in cases:
            results.append(fn(*case))
            if progress:
                progress(results[-1], len(results), len(cases))
        return results
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(fn, *case) for case in cases]
        for fut in as_completed(futures):
            results.append(fut.result())
            if progress:
                progress(results[-1], len(results), len(cases))
    return results
