"""Digests of short "paper"-tracking runs, to show the default stays bit-identical (issue 20).

``python tests/unit/paper_digests.py > tests/unit/data/paper_tracking_digests.json`` wrote the
stored file at commit 05e4489, before ``[estimator] tracking`` existed.
"""

from __future__ import annotations

import copy
import hashlib
import json
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
#: (name, config, duration s, changes to the TOML): explicit Euler, semi-implicit, a fault plan,
#: a long chain.
CASES = (
    ("paper-fast", "configs/paper-fast.toml", 3.0, {}),
    ("paper-fast-semi-implicit", "configs/paper-fast.toml", 1.0, {"controller": {"discretisation": "semi-implicit"}}),
    ("faults-lossy", "configs/faults-lossy.toml", 3.0, {}),
    ("line-16", "configs/line-16.toml", 2.0, {}),
)


def case_raw(config: str, duration: float, changes: dict) -> dict:
    import tomllib

    raw = tomllib.loads((ROOT / config).read_text())
    raw = copy.deepcopy(raw)
    raw["scenario"]["duration"] = duration
    for table, values in changes.items():
        raw.setdefault(table, {}).update(values)
    return raw


def digests(raw: dict, source: str) -> dict[str, str]:
    """sha256 of every trajectory array (dtype, shape and bytes) of an in-process run."""
    from fxswarm.core.scenario import ScenarioWarning, parse
    from fxswarm.launch.sim import Simulation

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ScenarioWarning)
        sim = Simulation(parse(raw, source))
    sim.run()
    out = {}
    for key, arr in sorted(sim.trajectory().items()):
        arr = np.ascontiguousarray(arr)
        h = hashlib.sha256(f"{arr.dtype.str}{arr.shape}".encode())
        h.update(arr.tobytes())
        out[key] = h.hexdigest()
    return out


if __name__ == "__main__":
    json.dump({name: digests(case_raw(cfg, dur, ch), cfg) for name, cfg, dur, ch in CASES}, sys.stdout, indent=1)
    print()
