"""Running independent simulations on several cores (spawned workers, never forked)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from multiprocessing import get_context


def _apply(job: tuple[Callable[..., dict], tuple]) -> dict:
    fn, case = job
    return fn(*case)


def parallel_map(fn: Callable[..., dict], cases: Sequence[tuple], workers: int,
                 progress: Callable[[dict, int, int], None] | None = None) -> list[dict]:
    """``[fn(*case) for case in cases]`` on ``workers`` spawned processes, in completion order.

    ``fn`` must be importable at module level (spawned workers re-import it). Spawn, not
    fork: a fork would copy whatever sessions or threads the parent holds. The pool is
    terminated on the way out, so Ctrl-C or an exception in any case stops every worker
    at once. With ``workers <= 1`` it runs here, in order. ``progress(result, done,
    total)`` is called after each case.
    """
    results: list[dict] = []
    if workers <= 1:
        for case in cases:
            results.append(fn(*case))
            if progress:
                progress(results[-1], len(results), len(cases))
        return results
    with get_context("spawn").Pool(min(workers, len(cases)) or 1) as pool:  # __exit__ terminates
        for result in pool.imap_unordered(_apply, [(fn, case) for case in cases]):
            results.append(result)
            if progress:
                progress(result, len(results), len(cases))
    return results
