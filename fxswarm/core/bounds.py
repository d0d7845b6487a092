"""Settling-time functions of SPEC section 6.

For a task function obeying ``x' = -lam*(b1*x^r1 + b2*x^r2)^r0`` (``x >= 0``)
the exact settling time from ``x0`` is the integral below; the paper's
Lemma 1 (second form) bounds it independently of ``x0``.
"""

from __future__ import annotations

import math

import numpy as np

from fxswarm.core.control import BehaviourGains, EstimatorGains


def settling_time(x0: float, g: BehaviourGains) -> float:
    """Exact settling time ``T(x0) = int_0^x0 dx / (lam*(b1 x^r1 + b2 x^r2)^r0)``, s.

    Computed by substituting ``x = exp(s)`` (the integrand spans many decades)
    and integrating with the trapezoid rule on a fine log grid, plus the
    analytic head ``int_0^xa`` where the ``x^r2`` term dominates.
    Finite for every ``x0`` when ``r2*r0 < 1``; infinite otherwise.
    """
    if x0 <= 0.0:
        return 0.0
    if g.r2 * g.r0 >= 1.0:
        return math.inf
    xa = min(x0, 1e-12)
    # Near 0 the integrand is ~ 1/(lam*(b2 x^r2)^r0); integrate that exactly.
    head = xa ** (1.0 - g.r2 * g.r0) / (g.lam * g.b2**g.r0 * (1.0 - g.r2 * g.r0))
    if x0 <= xa:
        return head
    s = np.linspace(math.log(xa), math.log(x0), 20001)
    x = np.exp(s)
    integrand = x / (g.lam * (g.b1 * x**g.r1 + g.b2 * x**g.r2) ** g.r0)
    return head + float(np.trapezoid(integrand, s))


def settling_time_limit(g: BehaviourGains) -> float:
    """``lim_{x0 -> inf} T(x0)``: finite iff ``r1*r0 > 1`` and ``r2*r0 < 1``, s."""
    if g.r1 * g.r0 <= 1.0 or g.r2 * g.r0 >= 1.0:
        return math.inf
    # Beyond x = 1e12 the x^r1 term dominates: its tail is analytic.
    xb = 1e12
    tail = xb ** (1.0 - g.r1 * g.r0) / (g.lam * g.b1**g.r0 * (g.r1 * g.r0 - 1.0))
    return settling_time(xb, g) + tail


def fixed_time_bound(g: BehaviourGains) -> float:
    """The paper's closed-form bound (Lemma 1, second form), s.

    ``1/(lam*b1^r0*(r1 r0 - 1)) + 1/(lam*b2^r0*(1 - r2 r0))``; infinite when
    the exponents do not make the law fixed-time.
    """
    if g.r1 * g.r0 <= 1.0 or g.r2 * g.r0 >= 1.0:
        return math.inf
    return 1.0 / (g.lam * g.b1**g.r0 * (g.r1 * g.r0 - 1.0)) + 1.0 / (
        g.lam * g.b2**g.r0 * (1.0 - g.r2 * g.r0)
    )


def estimator_bound_printed(H: np.ndarray, g: EstimatorGains) -> float:
    """The paper's printed estimator bound ``T_E`` (proof of its Lemma 4), s.

    SPEC section 6 warns this figure is suspect (about 0.29 s for the paper
    scenario, while the estimator takes tens of seconds from large errors):
    report it, never assert against it.
    """
    eig = np.linalg.eigvalsh(H)
    lmin, lmax = float(eig[0]), float(eig[-1])
    c = 2.0 * lmax**2 / lmin
    k1 = g.K1 * c ** (2.0 * g.r4 / (g.r3 + g.r4))
    k2 = g.K2 * c ** (2.0 * g.r6 / (g.r5 + g.r6))
    i1 = (g.r3 + g.r4) / (2.0 * g.r4)
    i2 = (g.r5 + g.r6) / (2.0 * g.r6)
    if i1 <= 1.0 or i2 >= 1.0:
        return math.inf
    return 1.0 / (k1 * (i1 - 1.0)) + 1.0 / (k2 * (1.0 - i2))
