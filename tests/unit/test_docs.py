"""What the README and docs/ tell users is true of the code: examples parse, links lead
somewhere, the README stays short and the reference lists every command option."""

from __future__ import annotations

import argparse
import importlib
import re
import tomllib
from pathlib import Path

import pytest

from fxswarm.cli import COMMANDS
from fxswarm.core.scenario import load, parse
from fxswarm.faults.plan import plan_of, resolve

# The repository root, wherever in tests/ this file sits (tests/ or tests/unit/).
ROOT = next(p for p in Path(__file__).resolve().parents if (p / "pyproject.toml").exists())
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, *DOCS]
README_MAX_LINES = 150


def text(page: Path) -> str:
    return page.read_text()


def name(page: Path) -> str:
    return str(page.relative_to(ROOT))


def fault_specs(md: str) -> list[str]:
    specs = re.findall(r"--fault '([^']*)'|--fault \"([^\"]*)\"", md)
    out = [a or b for a, b in specs]
    for group in re.findall(r"FXSWARM_FAULTS='([^']*)'", md):  # compose: ';'-separated
        out += [s.strip() for s in group.split(";") if s.strip()]
    return out


def toml_blocks(md: str) -> list[str]:
    return re.findall(r"```toml\n(.*?)```", md, flags=re.S)


def test_every_fault_spec_in_the_docs_parses():
    sc = load(ROOT / "configs" / "paper-fast.toml")
    found = 0
    for page in PAGES:
        for spec in fault_specs(text(page)):
            found += 1
            spec = re.sub(r"\{\w+\}", "0.1", spec)  # a campaign's template, filled as its grid would
            try:
                resolve(sc, [spec])  # raises ScenarioError naming the field on a wrong one
            except ValueError as exc:
                raise AssertionError(f"{name(page)}: --fault {spec!r}: {exc}") from None
    assert found >= 8, found  # the extraction still finds the examples


def test_every_toml_example_in_the_docs_is_a_valid_part_of_a_scenario():
    base = tomllib.loads((ROOT / "configs" / "paper-fast.toml").read_text())
    found = 0
    for page in PAGES:
        for n, block in enumerate(toml_blocks(text(page))):
            found += 1
            source = f"{name(page)} toml example {n + 1}"
            # a law named in an example is the shipped one (docs/controllers.md), found in its folder
            example = tomllib.loads(block)
            # a [swarm] example replaces the base's listed robots and graph
            kept = {k: v for k, v in base.items() if "swarm" not in example or k not in ("robots", "graph")}
            sc = parse({**kept, **example}, source, str(ROOT / "configs" / "examples" / "tether"))
            plan_of(sc)  # [faults] is checked by its own parser
    assert found >= 3, found


def test_a_wrong_toml_example_would_be_caught():
    # The check above can fail: a misspelt key in an example is refused.
    base = tomllib.loads((ROOT / "configs" / "paper-fast.toml").read_text())
    with pytest.raises(ValueError, match="controller.discretization"):
        parse({**base, **tomllib.loads('[controller]\ndiscretization = "euler"\n')}, "example")


def test_the_readme_is_short():
    lines = text(README).count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines; keep it to {README_MAX_LINES}, move the rest to docs/"


def test_the_readme_quick_start_is_the_two_make_targets_and_they_exist():
    md = text(README)
    block = re.search(r"## Quick start\n+```sh\n(.*?)```", md, flags=re.S)
    assert block is not None, "README.md: no Quick start sh block"
    assert block.group(1).split("\n")[:-1] == ["make run", "make test"]
    makefile = (ROOT / "Makefile").read_text()
    for target in ("run", "test"):
        assert re.search(rf"^{target}:", makefile, flags=re.M), f"Makefile has no '{target}' target"


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def anchors(md: str) -> set[str]:
    out: set[str] = set()
    seen: dict[str, int] = {}
    in_code = False
    for line in md.splitlines():
        if line.startswith("```"):
            in_code = not in_code
        if in_code:
            continue
        m = re.match(r"#{1,6} +(.*)", line)
        if m:
            base = slug(m.group(1))
            k = seen.get(base, 0)
            seen[base] = k + 1
            out.add(base if k == 0 else f"{base}-{k}")
    return out


def links(md: str) -> list[str]:
    md = re.sub(r"```.*?```", "", md, flags=re.S)  # code blocks hold no links
    return re.findall(r"\]\(([^)\s]+)\)", md)


def test_slug_follows_github():
    assert slug("Fault specs (--fault)") == "fault-specs---fault"
    assert slug("Role commands: world, leader, agent, logger") == "role-commands-world-leader-agent-logger"
    assert slug("`fxswarm sweep` and [scenario] (required)") == "fxswarm-sweep-and-scenario-required"


def test_every_relative_link_leads_to_a_file_and_heading_that_exist():
    checked = 0
    broken = []
    for page in PAGES:
        for target in links(text(page)):
            if re.match(r"[a-z]+:", target):  # http:, https:, mailto: ...
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            checked += 1
            if not dest.exists():
                broken.append(f"{name(page)}: {target}: no such file")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(text(dest)):
                broken.append(f"{name(page)}: {target}: no heading #{anchor} in {dest.name}")
    assert checked >= 10, checked
    assert not broken, "\n".join(broken)


def test_the_reference_lists_every_command_and_option():
    ref = text(ROOT / "docs" / "reference.md")
    missing = []
    for command, (module, _) in COMMANDS.items():
        if f"`{command}`" not in ref and f"fxswarm {command}" not in ref:
            missing.append(f"command {command}")
        parser = argparse.ArgumentParser()
        importlib.import_module(module).add_arguments(parser)
        for action in parser._actions:
            for option in action.option_strings:
                if option not in ("-h", "--help") and f"`{option}" not in ref:
                    missing.append(f"fxswarm {command} {option}")
    assert not missing, "docs/reference.md does not mention: " + ", ".join(missing)


def test_the_reference_lists_every_scenario_key():
    # Every key the loaders accept (their check_known sets) is named in the reference's schema.
    ref = text(ROOT / "docs" / "reference.md")
    keys: set[str] = set()
    for source in ("fxswarm/core/scenario.py", "fxswarm/faults/plan.py"):
        for group in re.findall(r"check_known\(\{([^}]*)\}\)", (ROOT / source).read_text()):
            keys |= set(re.findall(r'"(\w+)"', group))
    assert {"rate_hz", "lease_ms"} <= keys  # [logging] and [zenoh] are among them
    assert len(keys) >= 60, sorted(keys)  # the extraction still finds the loaders' sets
    missing = sorted(k for k in keys if f"`{k}`" not in ref and f"[{k}]" not in ref and f"faults.{k}]" not in ref)
    assert not missing, "docs/reference.md does not name these scenario keys: " + ", ".join(missing)
