"""The package's control law equals the numpy oracle (tests/oracle.py) on random inputs.

Both discretisations, with and without a sensed object (inside and outside the repulsive
zone), a speed limit, and extrapolation (the estimate's rate given). The two implementations
round differently, so they agree to rounding and make the same discrete choices (avoidance
on, speed limited) except within rounding of a switch, which the inputs keep away from.
"""

import numpy as np
import pytest
from hypothesis import assume, event, given, settings
from hypothesis import strategies as st

import oracle
from fxswarm.core import control, paper_law
from fxswarm.core.control import BehaviourGains, ControlParameters, EstimatorGains

FORMATION = BehaviourGains(lam=1.0, b1=0.6, b2=0.6, r0=0.9, r1=1.2, r2=0.6)
AVOIDANCE = BehaviourGains(lam=2.0, b1=0.6, b2=0.6, r0=0.9, r1=1.2, r2=0.6)
ASYMPTOTIC = BehaviourGains(lam=1.0, b1=0.6, b2=0.6, r0=1.0, r1=1.0, r2=1.0)
PAIRWISE = EstimatorGains(K1=0.4, K2=0.6, K3=1.0, r3=6, r4=5, r5=3, r6=5)
AGGREGATE = EstimatorGains(K1=0.4, K2=0.6, K3=1.0, r3=6, r4=5, r5=3, r6=5, power="aggregate")
LINEAR = EstimatorGains(K1=0.4, K2=0.6, K3=1.5, r3=1, r4=1, r5=1, r6=1)

coord = st.floats(-20, 20, allow_nan=False)
vec = st.tuples(coord, coord, coord).map(list)
near = st.floats(-3, 3, allow_nan=False)


@st.composite
def inputs(draw):
    m = draw(st.integers(0, 4))
    p = draw(vec)
    law = ControlParameters(
        formation=draw(st.sampled_from([FORMATION, ASYMPTOTIC])),
        avoidance=AVOIDANCE,
        estimator=draw(st.sampled_from([PAIRWISE, AGGREGATE, LINEAR])),
        d=2.0,
        v_max=draw(st.none() | st.floats(0.2, 8.0)),
        semi_implicit=draw(st.booleans()),
    )
    po = draw(st.none() | st.tuples(near, near, near).map(lambda o: [p[0] + o[0], p[1] + o[1], p[2] + o[2]]))
    return dict(
        p=p, ph=draw(vec), rows=[draw(vec) for _ in range(m)],
        ws=[draw(st.floats(0.1, 2.0)) for _ in range(m)],
        p0=draw(vec), dp0=draw(st.tuples(near, near, near).map(list)),
        po=po, vo=None if po is None else draw(st.tuples(near, near, near).map(list)),
        law=law, dt=draw(st.sampled_from([0.001, 0.01, 0.05])),
        dph=draw(st.none() | st.tuples(near, near, near).map(list)),  # given: extrapolating
        feedforward=draw(st.none() | st.tuples(near, near, near).map(list)),  # eq. (11ff)
    )


def close(a, b, scale: float) -> bool:
    return np.allclose(np.asarray(a), np.asarray(b), rtol=1e-8, atol=1e-9 * scale)


@settings(max_examples=200, deadline=None)
@given(x=inputs())
def test_the_law_equals_the_oracle(x):
    want = oracle.robot_control(**x)
    assume(want.margin > 1e-6)  # not within rounding of a switch
    got = paper_law.robot_control(**x)
    event("semi-implicit" if x["law"].semi_implicit else "explicit Euler")
    event(f"avoiding={want.avoid_active} speed_limited={want.speed_limited} extrapolating={x['dph'] is not None}")
    event(f"feedforward={x['feedforward'] is not None}")
    assert isinstance(got.v, list) and isinstance(got.dph, list)
    assert (got.avoid_active, got.speed_limited) == (want.avoid_active, want.speed_limited)
    scale = 1.0 + max(np.abs(np.concatenate([want.v, want.dph, want.e])).max(), 1.0 / x["dt"])
    assert close(got.dph, want.dph, scale), (got.dph, want.dph)
    assert close(got.e, want.e, scale)
    assert close(got.v, want.v, scale), (got.v, want.v)


@pytest.mark.parametrize("semi", [False, True])
def test_the_oracle_catches_a_wrong_law(semi):
    """The comparison can fail: a law with the sign term's gain off by 1 % is told apart."""
    law = ControlParameters(FORMATION, AVOIDANCE, PAIRWISE, 2.0, semi_implicit=semi)
    wrong = ControlParameters(FORMATION, AVOIDANCE, EstimatorGains(0.4, 0.6, 1.01, 6, 5, 3, 5), 2.0, semi_implicit=semi)
    args = dict(p=[1.0, 2.0, 3.0], ph=[0.5, -1.0, 2.0], rows=[[3.0, 1.0, -2.0], [-1.0, 0.0, 4.0]], ws=[1.0, 0.5],
                p0=[0.0, 1.0, 0.0], dp0=[0.1, 0.0, 0.0], po=None, vo=None, dt=0.01)
    want = oracle.robot_control(law=law, **args)
    assert close(paper_law.robot_control(law=law, **args).dph, want.dph, 100.0)
    assert not close(paper_law.robot_control(law=wrong, **args).dph, want.dph, 100.0)


def test_semi_implicit_snaps_to_consensus_in_both():
    """Within one step of the neighbours' consensus the semi-implicit estimate lands on it."""
    law = ControlParameters(FORMATION, AVOIDANCE, PAIRWISE, 2.0, semi_implicit=True)
    args = dict(p=[0.0, 0.0, 0.0], ph=[1.0, 1.0, 1.0], rows=[[1.004, 1.0, 0.998]], ws=[1.0],
                p0=[0.0, 0.0, 0.0], dp0=[0.0, 0.0, 0.0], po=None, vo=None, dt=0.01)
    got, want = paper_law.robot_control(law=law, **args), oracle.robot_control(law=law, **args)
    ph_next = [x + 0.01 * r for x, r in zip(args["ph"], got.dph)]
    assert ph_next == pytest.approx([1.004, 1.0, 0.998], abs=1e-15)
    assert close(got.dph, want.dph, 100.0)
