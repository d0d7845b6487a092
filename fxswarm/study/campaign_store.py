"""A campaign's folder, written: ``spec.json`` (which campaign it holds), ``runs.jsonl`` (one
line per finished run, appended as each finishes) and ``campaign.json`` (the statistics per cell
and law). Read by :mod:`fxswarm.runtime.campaign_folder`, the one reader of that format.

``runs.jsonl`` is the only place results live: each line is written with one ``write`` on a
file opened for appending and synced, so a killed campaign leaves whole lines (a torn last
line, should the machine die mid-write, is cut off when the campaign runs again).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from statistics import NormalDist

import numpy as np

from fxswarm.runtime import campaign_folder
from fxswarm.runtime.campaign_folder import RESULT, RUNS, SPEC, FolderError
from fxswarm.runtime.files import write_atomic
from fxswarm.study.campaign_plan import CampaignError, Plan

#: Quantiles of the minimum distance reported per cell.
DISTANCE_QUANTILES = (0.05, 0.5)


def claim_folder(out: Path, plan: Plan) -> None:
    """Make ``out`` this campaign's folder, or check that it already is: a folder that holds
    another campaign is refused, naming what differs."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / SPEC
    if path.is_file():
        try:
            held = json.loads(path.read_text())
        except ValueError:
            raise CampaignError(f"{path}: not a campaign's spec (invalid JSON); use another --out") from None
        if held != plan.spec:
            keys = sorted(k for k in set(held) | set(plan.spec) if held.get(k) != plan.spec.get(k))
            diff = "; ".join(f"{k}: this folder's {held.get(k)!r}, this command's {plan.spec.get(k)!r}" for k in keys)
            raise CampaignError(f"{out} holds another campaign's runs ({diff}); use another --out, or the "
                                "same options to finish that one")
    else:
        write_atomic(path, json.dumps(plan.spec, indent=2) + "\n")


def read_runs(out: Path, fingerprint: str) -> dict[str, dict]:
    """The runs already in ``out/runs.jsonl`` by id. A torn last line is cut off the file; a
    line of another campaign is refused."""
    try:
        return campaign_folder.read_runs(out, fingerprint, repair=True)
    except FolderError as exc:
        raise CampaignError(str(exc)) from None


class RunLog:
    """``runs.jsonl``, open for appending whole lines."""

    def __init__(self, out: Path) -> None:
        self.fd = os.open(out / RUNS, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def append(self, record: dict) -> None:
        line = (json.dumps(record, separators=(",", ":")) + "\n").encode()
        written = os.write(self.fd, line)  # one write: the line is whole or absent
        if written != len(line):
            raise OSError(f"{RUNS}: wrote {written} of {len(line)} bytes")
        os.fsync(self.fd)

    def close(self) -> None:
        os.close(self.fd)


def wilson_interval(successes: int, runs: int, confidence: float = 0.95) -> tuple[float, float] | None:
    """The Wilson score interval of a success rate (Wilson 1927, the formula scipy's
    ``binomtest(...).proportion_ci(method="wilson")`` uses, which the tests check it against);
    None without runs. The normal quantile is the standard library's: importing scipy.stats
    here cost a second at the end of every campaign."""
    if runs == 0:
        return None
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p, z2 = successes / runs, z * z
    centre = (p + z2 / (2 * runs)) / (1 + z2 / runs)
    half = z / (1 + z2 / runs) * math.sqrt(p * (1 - p) / runs + z2 / (4 * runs * runs))
    return max(0.0, centre - half), min(1.0, centre + half)


def _quantiles(values: list[float], qs: tuple[float, ...]) -> dict[str, float] | None:
    if not values:
        return None
    return {f"p{round(q * 100):02d}": float(np.quantile(values, q)) for q in qs}


def cell_stats(plan: Plan, records: dict[str, dict]) -> list[dict]:
    """One entry per law and grid cell, in plan order: runs done, successes, errors, success
    rate with its 95 % Wilson interval, settling-time median and p95 (settled runs), and the
    minimum distance's quantiles."""
    groups: dict[str, dict] = {}
    for run in plan.runs:
        key = json.dumps([run.law, run.cell], sort_keys=True)
        g = groups.setdefault(key, {"law": run.law, "cell": run.cell, "planned": 0, "records": []})
        g["planned"] += 1
        if run.id in records:
            g["records"].append(records[run.id])
    out = []
    for g in groups.values():
        recs = g["records"]
        done = [r for r in recs if r["status"] == "done"]
        successes = sum(1 for r in done if r["success"])
        settle = [r["metrics"]["formation_settle_s"] for r in done if r["metrics"]["formation_settle_s"] is not None]
        dist = [r["metrics"]["min_distance_m"] for r in done if r["metrics"]["min_distance_m"] is not None]
        failed: dict[str, int] = {}
        for r in done:
            for name in r["failed"]:
                failed[name] = failed.get(name, 0) + 1
        ci = wilson_interval(successes, len(recs))
        out.append({
            "law": g["law"], "cell": g["cell"], "planned": g["planned"], "runs": len(recs),
            "successes": successes, "errors": len(recs) - len(done),
            "success_rate": successes / len(recs) if recs else None,
            "success_rate_ci95": list(ci) if ci else None,
            "failed_criteria": dict(sorted(failed.items())),
            "formation_settle_s": {"median": float(np.median(settle)) if settle else None,
                                   "p95": float(np.quantile(settle, 0.95)) if settle else None,
                                   "unsettled": len(done) - len(settle)},
            "min_distance_m": ({"min": float(min(dist))} | _quantiles(dist, DISTANCE_QUANTILES)) if dist else None,
            "error_messages": sorted({r["error"] for r in recs if r["status"] != "done"})[:3],
        })
    return out


def campaign_document(plan: Plan, records: dict[str, dict]) -> dict:
    """The whole ``campaign.json``. Only what the runs determine goes in (no wall times, no
    executor), so a campaign gives the same file on any machine and any executor."""
    cells = cell_stats(plan, records)
    done = [r for r in records.values() if r["status"] == "done"]
    return {
        "format": "fxswarm-campaign-result/1",
        "spec": plan.spec,
        "axes": {a.name: list(a.values) for a in plan.axes},
        "laws": list(plan.laws),
        "criteria": plan.criteria.as_dict(),
        "complete": all(r.id in records for r in plan.runs),
        "totals": {"planned": len(plan.runs), "runs": len(records), "successes": sum(1 for r in done if r["success"]),
                   "errors": len(records) - len(done)},
        "cells": cells,
    }


def write_document(out: Path, doc: dict) -> Path:
    return write_atomic(out / RESULT, json.dumps(doc, indent=2) + "\n")
