"""W-MSR trimming and the graph conditions (fxswarm.core.resilience, docs/resilience.md), checked
against direct implementations written from the definitions."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fxswarm.core.resilience import check_graph, leader_reach, robustness, wmsr_trim
from fxswarm.core.scenario import load
from support import CONFIGS

# --- trimming -------------------------------------------------------------------------------


def direct_trim(own, rows, f, trusted):
    """W-MSR per axis, as LeBlanc et al. state it, one axis and one value at a time: of the values
    above own, drop the f largest (all if fewer), of those below the f smallest; equal values: the
    later row first. A dropped value becomes own's."""
    m = len(rows) - trusted
    out = [list(r) for r in rows]
    dropped = 0
    for c in range(3):
        higher = [j for j in range(m) if rows[j][c] > own[c]]
        lower = [j for j in range(m) if rows[j][c] < own[c]]
        for _ in range(min(f, len(higher))):
            top = max(higher, key=lambda j: (rows[j][c], j))
            higher.remove(top)
            out[top][c] = own[c]
            dropped += 1
        for _ in range(min(f, len(lower))):
            bottom = min(lower, key=lambda j: (rows[j][c], -j))
            lower.remove(bottom)
            out[bottom][c] = own[c]
            dropped += 1
    return out, dropped


# Few distinct values, so that ties with each other and with own are common.
value = st.one_of(st.sampled_from([-1.0, 0.0, 0.5, 1.0]), st.floats(-1e3, 1e3, allow_nan=False))
vec = st.lists(value, min_size=3, max_size=3)


@settings(max_examples=200, deadline=None)
@given(own=vec, rows=st.lists(vec, max_size=9), f=st.integers(0, 4), trusted=st.booleans())
def test_trimming_equals_the_direct_definition(own, rows, f, trusted):
    trusted = int(trusted and len(rows) > 0)
    got, n = wmsr_trim(own, rows, f, trusted)
    want, n_want = direct_trim(own, rows, f, trusted)
    assert got == want and n == n_want


@settings(max_examples=100, deadline=None)
@given(own=vec, rows=st.lists(vec, min_size=1, max_size=9), f=st.integers(1, 4))
def test_kept_values_lie_within_the_honest_range_whatever_f_liars_say(own, rows, f):
    """W-MSR's guarantee: with at most f liars among the rows, every value kept lies within the
    range of own and the honest rows' values (per axis); here the first f rows lie wildly."""
    liars = min(f, len(rows))
    told = [[1e9 * (-1) ** (j + c) for c in range(3)] for j in range(liars)] + rows[liars:]
    kept, _ = wmsr_trim(own, told, f)
    for c in range(3):
        honest = [own[c]] + [r[c] for r in rows[liars:]]
        assert all(min(honest) <= r[c] <= max(honest) for r in kept)


def test_fewer_neighbours_than_2f_drops_every_value_off_own():
    own = [0.0, 0.0, 0.0]
    rows = [[1.0, -1.0, 0.0], [2.0, 3.0, 0.0], [5.0, 5.0, 5.0]]  # last: the leader, trusted
    kept, n = wmsr_trim(own, rows, 2, trusted=1)
    assert kept == [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [5.0, 5.0, 5.0]] and n == 4
    assert rows[0] == [1.0, -1.0, 0.0]  # the input is left as it was


def test_f_zero_or_no_rows_is_the_identity():
    rows = [[1.0, 2.0, 3.0]]
    assert wmsr_trim([0.0] * 3, rows, 0) == (rows, 0)
    assert wmsr_trim([0.0] * 3, [], 1) == ([], 0)


# --- graph conditions -----------------------------------------------------------------------


def random_graph(rng, n, p):
    a = np.triu((rng.random((n, n)) < p).astype(float), 1)
    return a + a.T


def direct_condition(a, b, r):
    """Every nonempty set of robots holds one that is pinned or has r neighbours outside it."""
    n = len(b)
    for size in range(1, n + 1):
        for c in itertools.combinations(range(n), size):
            inside = set(c)
            if not any(b[i] > 0 or sum(1 for j in range(n) if a[i, j] > 0 and j not in inside) >= r for i in c):
                return False
    return True


def direct_robustness(a):
    """Largest r with: of any two disjoint nonempty sets, one has a robot with r outside neighbours."""
    n = len(a)

    def reach(s):
        return max(sum(1 for j in range(n) if a[i, j] > 0 and j not in s) for i in s)

    best = n
    for labels in itertools.product((0, 1, 2), repeat=n):
        s1 = {i for i in range(n) if labels[i] == 1}
        s2 = {i for i in range(n) if labels[i] == 2}
        if s1 and s2:
            best = min(best, max(reach(s1), reach(s2)))
    return best


@pytest.mark.parametrize("seed", range(12))
def test_the_leader_condition_is_the_definition_checked_set_by_set(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 9))
    a = random_graph(rng, n, float(rng.uniform(0.3, 0.9)))
    b = (rng.random(n) < 0.35).astype(float)
    for r in (1, 2, 3):
        assert (not leader_reach(a, b, r)) == direct_condition(a, b, r), (seed, r)


@pytest.mark.parametrize("seed", range(8))
def test_robustness_is_the_definition_checked_pair_by_pair(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(2, 8))
    a = random_graph(rng, n, float(rng.uniform(0.3, 1.0)))
    assert robustness(a) == direct_robustness(a)


def test_known_graphs():
    line = np.diag(np.ones(4), 1)
    line = line + line.T
    assert robustness(line) == 1
    complete = np.ones((6, 6)) - np.eye(6)
    assert robustness(complete) == 3  # K_n is ceil(n/2)-robust
    assert robustness(np.zeros((25, 25))) is None  # past the exact limit: unknown


def test_the_shipped_liar_scenario_meets_the_condition_and_the_paper_ring_does_not():
    liar = load(CONFIGS / "liar-8.toml")
    assert check_graph(liar.a, liar.b, 1)["meets"]
    assert not check_graph(liar.a, liar.b, 2)["meets"]  # 5 links into the pinned three: no one has them
    ring = load(CONFIGS / "paper-fast.toml")
    got = check_graph(ring.a, ring.b, 1)
    assert not got["meets"] and got["unreached"] == [2, 3, 5, 6] and got["robustness"] == 1


def test_fxswarm_check_says_it_and_exits_0_or_1(capsys):
    from fxswarm.cli import main

    assert main(["check", str(CONFIGS / "liar-8.toml")]) == 0
    out = capsys.readouterr().out
    assert "meets the condition" in out and "3-robust (exact)" in out
    assert main(["check", str(CONFIGS / "paper-fast.toml")]) == 1
    assert "robots 2, 3, 5, 6 are neither pinned nor linked to 3" in capsys.readouterr().out
    assert main(["check", str(CONFIGS / "liar-8.toml"), "--tolerate", "2", "--json"]) == 1
    got = json.loads(capsys.readouterr().out)
    assert got["r"] == 5 and got["unreached"] == [4, 5, 6, 7, 8] and got["pinned"] == [1, 2, 3]
    with pytest.raises(SystemExit) as exc:
        main(["check", "no-such.toml"])
    assert exc.value.code == 2
