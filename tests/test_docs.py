"""What the README tells users to type is accepted by the code."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from fxswarm.core.scenario import load, parse
from fxswarm.faults.plan import plan_of, with_cli_faults

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def readme_fault_specs() -> list[str]:
    specs = re.findall(r"--fault '([^']*)'|--fault \"([^\"]*)\"", README)
    out = [a or b for a, b in specs]
    for group in re.findall(r"FXSWARM_FAULTS='([^']*)'", README):  # compose: ';'-separated
        out += [s.strip() for s in group.split(";") if s.strip()]
    return out


def test_every_fault_spec_in_the_readme_parses():
    specs = readme_fault_specs()
    assert len(specs) >= 5, specs  # the extraction still finds the examples
    sc = load(ROOT / "configs" / "paper-fast.toml")
    for spec in specs:
        with_cli_faults(sc, [spec])  # raises ScenarioError naming the field on a wrong one


def test_every_toml_example_in_the_readme_is_a_valid_part_of_a_scenario():
    blocks = re.findall(r"```toml\n(.*?)```", README, flags=re.S)
    assert len(blocks) >= 2, blocks
    base = tomllib.loads((ROOT / "configs" / "paper-fast.toml").read_text())
    for n, block in enumerate(blocks):
        sc = parse({**base, **tomllib.loads(block)}, f"README.md toml example {n + 1}")  # raises on a wrong field
        plan_of(sc)  # [faults] is checked by its own parser
