"""``[estimator] estimator_graph = "oriented"`` (docs/estimator.md "A turning leader on a long
chain"): eq. (11) summed over the upstream neighbours only."""

from __future__ import annotations

import json
import tomllib
import warnings

import pytest

from fxswarm.agents.node import AgentNode
from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.launch.sim import Simulation
from support import CONFIGS

HELIX = CONFIGS / "line-16-helix.toml"


def raw(path=HELIX) -> dict:
    return tomllib.loads(path.read_text())


def test_the_choice_defaults_to_the_papers_graph_and_is_checked():
    assert load(CONFIGS / "line-16.toml").estimator_graph == "undirected"
    assert load(HELIX).estimator_graph == "oriented"
    data = raw()
    data["estimator"]["estimator_graph"] = "sideways"
    with pytest.raises(ScenarioError, match="estimator.estimator_graph"):
        parse(data, "x.toml")
    data["estimator"] |= {"estimator_graph": "oriented", "resilience": "w-msr"}
    with pytest.raises(ScenarioError, match="with resilience"):
        parse(data, "x.toml")


def test_downstream_rows_weigh_nothing_the_leader_keeps_its_weight():
    sc = load(HELIX)
    assert AgentNode(sc, 5)._weight_list == [1.0, 0.0]  # neighbours 4 (upstream) and 6
    assert AgentNode(sc, 1)._weight_list == [0.0, 1.0]  # neighbour 2, then the leader (b_1)
    undirected = load(CONFIGS / "line-16.toml")
    assert AgentNode(undirected, 5)._weight_list == [1.0, 1.0]


def short_chain(graph: str, duration: float = 12.0):
    """The first 6 robots of line-16-helix, the leader starting 5 m off: a quick chain."""
    data = raw()
    data["robots"] = data["robots"][:6]
    data["scenario"]["duration"] = duration
    data["estimator"]["estimator_graph"] = graph
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse(data, "chain")


def test_on_a_short_chain_the_oriented_estimator_settles_where_the_undirected_one_still_lags():
    """Measured at 12 s: oriented 0.011 m, undirected 0.052 m (worst robot, 5 m initial error)."""
    oriented = Simulation(short_chain("oriented")).run()["estimate_error_final_m"]
    undirected = Simulation(short_chain("undirected")).run()["estimate_error_final_m"]
    assert oriented < 0.02 and undirected > 3 * oriented, (oriented, undirected)


@pytest.mark.slow
@pytest.mark.parametrize("radius, rate, climb", [(5.0, 0.1, 1.0), (2.0, 0.05, 0.1)])
def test_line_16_behind_a_helix_ends_within_0_2_m_and_line_16_keeps_0_1_m(radius, rate, climb):
    """The issue's claim: 16 robots on a line pinned at one end, a helix leader, dt = 0.01 s:
    final estimate error <= 0.2 m (feedforward alone: 0.82 and 0.71 m); configs/line-16.toml's
    constant-velocity leader stays <= 0.1 m with the same choice."""
    data = raw()
    data["leader"] |= {"radius": radius, "rate": rate, "climb": climb}
    assert Simulation(parse(data, "helix")).run()["estimate_error_final_m"] <= 0.2
    if radius == 5.0:
        line = raw(CONFIGS / "line-16.toml")
        line["estimator"] |= {"tracking": "feedforward", "estimator_graph": "oriented"}
        assert Simulation(parse(json.loads(json.dumps(line)), "line")).run()["estimate_error_final_m"] <= 0.1
