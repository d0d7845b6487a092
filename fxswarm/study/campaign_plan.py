"""A campaign's runs, planned: the grid, the fault templates it fills, the laws, the seeds, and
for each run the scenario file and the exact ``fxswarm sim`` command line it equals.

Nothing here runs a simulation. Every derived scenario and every filled fault spec is
validated while planning, so a wrong grid value or template is refused (exit 2) before any
run starts, naming the axis or template and what was expected.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import re
import shlex
import shutil
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from fxswarm.core.laws import LawError, resolve_law
from fxswarm.core.scenario import Scenario, ScenarioError, ScenarioWarning, parse
from fxswarm.core.tomltext import dump_toml
from fxswarm.faults.plan import resolve
from fxswarm.runtime.files import write_atomic

#: ``{name}`` in a fault template: filled by the grid axis ``name``.
PLACEHOLDER = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*)\}")


class CampaignError(ValueError):
    """A campaign's options are wrong; the message names the option and what was expected."""


@dataclass(frozen=True)
class Criteria:
    """What a run must show to count as a success (all three).

    min_distance_m: closest approach to any object (obstacle or teammate) must stay above it;
    settle_within_s: the formation (against the true leader) must settle by then (None: at
    any time within the run); final_error_m: the final formation error must be below it.
    """

    min_distance_m: float
    settle_within_s: float | None
    final_error_m: float

    def as_dict(self) -> dict:
        return {"min_distance_m": self.min_distance_m, "settle_within_s": self.settle_within_s,
                "final_error_m": self.final_error_m}


@dataclass(frozen=True)
class Axis:
    """One ``--grid NAME=V1,V2,...``: a fault-template placeholder, or a scenario value
    (``table.key``, e.g. ``scenario.dt``). ``texts`` are the values as typed (what a template
    gets), ``values`` the same parsed (numbers where they are numbers)."""

    name: str
    texts: tuple[str, ...]
    values: tuple

    @property
    def scenario_key(self) -> tuple[str, str] | None:
        return tuple(self.name.split(".", 1)) if "." in self.name else None


@dataclass(frozen=True)
class Run:
    """One run of the campaign."""

    id: str
    law: str
    cell: dict  # axis name -> value
    replicate: int
    seed: int  # its fault seed (``--fault seed=N``)
    scenario: str  # its scenario file (DIR/scenarios/...)
    faults: tuple[str, ...]
    argv: tuple[str, ...]  # the `fxswarm sim` command line it equals

    @property
    def command(self) -> str:
        return shlex.join(self.argv)


@dataclass
class Plan:
    spec: dict  # what identifies the campaign (DIR/spec.json)
    fingerprint: str
    axes: tuple[Axis, ...]
    laws: tuple[str, ...]
    criteria: Criteria
    runs: list[Run]
    tables: dict[str, dict] = field(repr=False, default_factory=dict)  # scenario file -> its TOML
    files: dict[str, Path] = field(default_factory=dict)  # law module copied beside the scenarios -> its source


def value_of(text: str):
    """A grid value as typed: an int, a float, true/false, else the text."""
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text, text)


def parse_axis(text: str) -> Axis:
    """``NAME=V1,V2,...`` -> :class:`Axis`."""
    name, sep, values = text.partition("=")
    name = name.strip()
    texts = tuple(v.strip() for v in values.split(",") if v.strip())
    if not sep or not texts or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)?", name):
        raise CampaignError(f"--grid {text!r}: expected NAME=V1,V2,... (NAME a template placeholder, "
                            "or table.key for a scenario value, e.g. scenario.dt)")
    if len(set(texts)) != len(texts):
        raise CampaignError(f"--grid {text!r}: expected distinct values")
    return Axis(name, texts, tuple(value_of(t) for t in texts))


def scenario_table_with_law(base: Scenario, spec: str) -> dict:
    """A deep copy of scenario ``base``'s TOML table flying law ``spec``: any name the scenario's
    ``[controller] law`` accepts (a registered name, or ``module:Class``, looked for beside the
    scenario file first), checked here so that a bad name is refused before anything runs.

    The one place a campaign chooses a law: ``[controller] law``, the law API's own key
    (docs/controllers.md), so a campaign flies every law as ``fxswarm sim`` does. The
    base's ``variant``/``estimator_variant`` go: the law's name says its family. The
    scenario's ``[controller.params]`` are its own law's: a law named in ``--laws`` that is
    not the scenario's own gets none (docs/campaigns.md).
    """
    try:
        resolve_law(spec, base.law_folder)
    except LawError as exc:
        raise CampaignError(f"--laws {spec!r}: {exc}") from None
    out = copy.deepcopy(base.raw)
    if spec == base.law:
        return out
    drop = ("variant", "estimator_variant", "params")
    controller = {k: v for k, v in (out.get("controller") or {}).items() if k not in drop}
    out["controller"] = dict(controller, law=spec)
    return out


def fault_seed(seed: int, cell: dict, replicate: int) -> int:
    """The fault seed of replicate ``replicate`` of grid cell ``cell`` (not of the law: every
    law meets the same faults in the same cell and replicate, a paired comparison)."""
    text = json.dumps([seed, sorted(cell.items()), replicate], sort_keys=True)
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "big") & 0x7FFFFFFF


def fill(template: str, texts: dict[str, str]) -> str:
    return PLACEHOLDER.sub(lambda m: texts[m.group(1)], template)


def _digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


def make_plan(config: str, base: Scenario, out: Path, templates: list[str], axes: list[Axis], laws: list[str],
              seeds: int, seed: int, criteria: Criteria) -> Plan:
    """Every run of the campaign, validated; raises :class:`CampaignError` or ScenarioError."""
    names = [a.name for a in axes]
    if len(set(names)) != len(names):
        raise CampaignError(f"--grid: expected each axis once, got {names}")
    placeholders = {m for t in templates for m in PLACEHOLDER.findall(t)}
    missing = sorted(placeholders - set(names))
    if missing:
        raise CampaignError(f"--fault: placeholders {missing} have no --grid axis (give --grid NAME=V1,V2,...)")
    unused = sorted(a.name for a in axes if a.scenario_key is None and a.name not in placeholders)
    if unused:
        raise CampaignError(f"--grid: axes {unused} fill no --fault placeholder (a scenario value is table.key)")
    if seeds < 1:
        raise CampaignError(f"--seeds: expected a count >= 1, got {seeds}")
    law_specs = list(dict.fromkeys(laws)) or [None]
    config_bytes = Path(config).read_bytes()
    files = law_modules(config, out, [base.law] + [s for s in law_specs if s is not None])
    spec = {
        "format": "fxswarm-campaign/1", "config": config, "config_sha256": hashlib.sha256(config_bytes).hexdigest(),
        "faults": list(templates), "grid": {a.name: list(a.texts) for a in axes},
        "laws": [base.law if s is None else s for s in law_specs], "seeds": seeds, "seed": seed,
        "criteria": criteria.as_dict(),
        "law_modules": {Path(dest).name: _file_digest(src) for dest, src in files.items()},
    }
    fingerprint = _digest(spec)[:16]
    scenario_axes = [a for a in axes if a.scenario_key is not None]
    tables: dict[str, dict] = {}
    checked: set[tuple] = set()
    runs: list[Run] = []
    for law_spec in law_specs:
        law = base.law if law_spec is None else law_spec
        with_law = copy.deepcopy(base.raw) if law_spec is None else scenario_table_with_law(base, law_spec)
        for combo in itertools.product(*(range(len(a.values)) for a in axes)):
            cell = {a.name: a.values[k] for a, k in zip(axes, combo)}
            texts = {a.name: a.texts[k] for a, k in zip(axes, combo)}
            table = copy.deepcopy(with_law)
            if any(a.scenario_key[0] == "swarm" for a in scenario_axes):
                if base.swarm is None:
                    raise CampaignError(f"--grid {next(a.name for a in scenario_axes if a.scenario_key[0] == 'swarm')}: "
                                        f"{config} has no [swarm] table (its robots are listed)")
                # a generated swarm: the cell's [swarm] table, expanded when the run parses it
                table = {k: v for k, v in table.items() if k not in ("robots", "graph")}
                table["swarm"] = copy.deepcopy(base.swarm)
            for a in scenario_axes:
                section, key = a.scenario_key
                table.setdefault(section, {})
                if not isinstance(table[section], dict):
                    raise CampaignError(f"--grid {a.name}: {section} is not a table of the scenario")
                table[section] = dict(table[section], **{key: cell[a.name]})
            name = f"{_safe(law)}-{_digest(table)[:10]}.toml"
            path = str(out / "scenarios" / name)
            if path not in tables:
                tables[path] = table
            faults = [fill(t, texts) for t in templates]
            key = (path, tuple(faults))
            if key not in checked:  # each scenario and fault plan once, before any run starts
                # Parsed as the user's file (its errors name it, a law module beside it imports);
                # the run parses the same table from its copy in DIR/scenarios/.
                sc = _parse(table, config, law, cell)
                try:
                    resolve(sc, faults)
                except ScenarioError as exc:
                    raise CampaignError(f"cell {cell_text(cell)}: {exc}") from None
                checked.add(key)
            for r in range(seeds):
                s = fault_seed(seed, cell, r)
                run_faults = (*faults, f"seed={s}")
                run_id = _digest([law, sorted(cell.items()), r])[:12]
                argv = ("fxswarm", "sim", path, *itertools.chain.from_iterable(("--fault", f) for f in run_faults),
                        "--quiet", "--out", str(out / "replay" / run_id))
                runs.append(Run(run_id, law, cell, r, s, path, run_faults, argv))
    return Plan(spec, fingerprint, tuple(axes), tuple(spec["laws"]), criteria, runs, tables, files)


def law_modules(config: str, out: Path, law_specs: list[str]) -> dict[str, Path]:
    """The module files (``NAME.py`` or a package folder) beside the scenario file that
    ``module:Class`` laws name (the scenario's own and those of ``--laws``): a run's scenario sits
    in DIR/scenarios/, so they are copied there, where the law API looks (beside the scenario),
    the campaign folder keeps the code it flew, and a Dask campaign uploads them to every worker."""
    found = {}
    for spec in law_specs:
        if ":" not in spec:
            continue
        top = spec.split(":", 1)[0].split(".")[0]
        for src in (Path(config).parent / f"{top}.py", Path(config).parent / top):
            if src.exists():
                found[str(out / "scenarios" / src.name)] = src
                break
    return found


def _file_digest(path: Path) -> str:
    paths = sorted(p for p in path.rglob("*.py")) if path.is_dir() else [path]
    return hashlib.sha256(b"".join(p.read_bytes() for p in paths)).hexdigest()[:16]


def _parse(table: dict, path: str, law: str, cell: dict) -> Scenario:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ScenarioWarning)  # the base scenario's warnings are shown once
        try:
            return parse(table, path)
        except ScenarioError as exc:
            raise CampaignError(f"law {law}, cell {cell_text(cell)}: {exc}") from None


def cell_text(cell: dict) -> str:
    """``loss=0.2 delay=0.1``."""
    return " ".join(f"{k}={v}" for k, v in cell.items()) or "(no grid)"


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)


def write_scenarios(plan: Plan) -> None:
    """Write each run's scenario file (the ``fxswarm sim`` command lines name them) and the law
    modules beside them (:func:`law_modules`); a file
    written is read back and must give the same TOML, so the command line runs the same run."""
    for dest, src in plan.files.items():
        Path(dest).parent.mkdir(parents=True, exist_ok=True)
        if src.is_dir():
            shutil.copytree(src, dest, dirs_exist_ok=True)
        else:
            shutil.copy2(src, dest)
    for path, table in plan.tables.items():
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        text = dump_toml(table)
        if tomllib.loads(text) != table:
            raise CampaignError(f"{path}: the scenario does not survive writing as TOML")
        if not p.is_file() or p.read_text() != text:
            write_atomic(p, text)
