"""Settling-time functions of SPEC section 6.

For a task function obeying ``x' = -lam*(b1*x^r1 + b2*x^r2)^r0`` (``x >= 0``)
the exact settling time from ``x0`` is the integral below; the paper's
Lemma 1 (second form) bounds it independently of ``x0``.
"""

from __future__ import annotations

import math

import numpy as np

from fxswarm.core.control import BehaviourGains, EstimatorGains
from fxswarm.core.graph import SparseGraph, graph_of, h_matrix


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


#: Above this size the extreme eigenvalues of H come from sparse iterations (ARPACK), not a
#: dense eigendecomposition (O(n^3): minutes at 10 000 robots).
DENSE_EIGEN_MAX = 400


#: Above this size a dense H is not solved (eigvalsh: hours) nor built (three n x n copies).
DENSE_EIGEN_LIMIT = 3000


def extreme_eigenvalues(H) -> tuple[float, float]:
    """``(lambda_min, lambda_max)`` of the symmetric ``H``: a dense ``H`` by eigvalsh (NaN above
    :data:`DENSE_EIGEN_LIMIT` rows, or for ``None``: :func:`h_of` without scipy there), a sparse
    one (:func:`h_of` above :data:`DENSE_EIGEN_MAX` robots, with scipy) by ARPACK (shift-invert
    at 0 for the smallest; a fixed start vector, so the same figures every run)."""
    if H is None:
        return math.nan, math.nan
    n = H.shape[0]
    if not hasattr(H, "tocsc"):
        if n > DENSE_EIGEN_LIMIT:
            return math.nan, math.nan
        eig = np.linalg.eigvalsh(H)
        return float(eig[0]), float(eig[-1])
    from scipy.sparse.linalg import eigsh

    S = H
    v0 = np.ones(n)
    lmax = eigsh(S, k=1, which="LA", v0=v0, return_eigenvectors=False)[0]
    lmin = eigsh(S, k=1, sigma=0.0, which="LM", v0=v0, return_eigenvectors=False)[0]
    return float(lmin), float(lmax)


def h_of(a: SparseGraph | np.ndarray, b: np.ndarray):
    """``H = L + diag(b)`` of weights ``a`` and pinning gains ``b`` (n,): dense up to
    :data:`DENSE_EIGEN_MAX` robots, sparse above (with scipy; without it dense up to
    :data:`DENSE_EIGEN_LIMIT`, else None: no n x n matrix is built at 10 000 robots)."""
    g, n = graph_of(a), len(b)
    if n <= DENSE_EIGEN_MAX:
        return h_matrix(g.dense(), b)
    try:
        from scipy.sparse import csr_matrix, diags
    except ImportError:  # without the scale extra: dense (slow at thousands of robots)
        return h_matrix(g.dense(), b) if n <= DENSE_EIGEN_LIMIT else None

    A = csr_matrix((g.weights, g.indices, g.indptr), shape=(n, n))
    return (diags(np.asarray(A.sum(axis=1)).ravel() + b) - A).tocsc()


def estimator_bound_printed(H: np.ndarray, g: EstimatorGains) -> float:
    """The paper's printed estimator bound ``T_E`` (proof of its Lemma 4), s.

    SPEC section 6 warns this figure is suspect (about 0.29 s for the paper
    scenario, while the estimator takes tens of seconds from large errors):
    report it, never assert against it.
    """
    lmin, lmax = extreme_eigenvalues(H)
    c = 2.0 * lmax**2 / lmin
    k1 = g.K1 * c ** (2.0 * g.r4 / (g.r3 + g.r4))
    k2 = g.K2 * c ** (2.0 * g.r6 / (g.r5 + g.r6))
    i1 = (g.r3 + g.r4) / (2.0 * g.r4)
    i2 = (g.r5 + g.r6) / (2.0 * g.r6)
    if i1 <= 1.0 or i2 >= 1.0:
        return math.inf
    return 1.0 / (k1 * (i1 - 1.0)) + 1.0 / (k2 * (1.0 - i2))


def estimator_lyapunov_decay(H: np.ndarray, g: EstimatorGains) -> tuple[float, float, float, float]:
    """``(a, p, b, q)`` with ``dV/dt <= -(a V^p + b V^q)`` for the estimator, per axis.

    Derivation (for eq. (11) in its ``aggregate`` form, the one the paper's
    proof uses; SPEC section 2). Per axis, stack the errors
    ``delta_i = ph_i - p0`` into ``delta`` (n,); then ``eta = H delta`` is the
    vector of the robots' ``eta3`` and each robot runs
    ``dph_i = -K1 sig(eta_i, al) - K2 sig(eta_i, be) - K3 sign(eta_i)``
    with ``al = r3/r4``, ``be = r5/r6``. Take ``V = delta^T H delta / 2``:

    1. ``dV/dt = eta^T (dph - 1 dp0/dt) <= -K1 sum|eta_i|^(1+al) - K2 sum|eta_i|^(1+be)``,
       since ``-K3 |eta|_1 - (dp0/dt) sum eta_i <= 0`` when ``K3 >= |dp0/dt|`` per axis.
    2. Norm inequalities: ``sum|eta_i|^s >= n^min(0, 1 - s/2) |eta|^s`` (Hoelder for
       ``s > 2``, monotonicity of p-norms for ``s <= 2``).
    3. ``V = eta^T H^-1 eta / 2 <= |eta|^2 / (2 lmin(H))``, so ``|eta|^2 >= 2 lmin V``.

    Hence ``a = K1 n^min(0,(1-al)/2) (2 lmin)^p``, ``p = (1+al)/2``, and
    ``b = K2 n^min(0,(1-be)/2) (2 lmin)^q``, ``q = (1+be)/2``. ``p`` and ``q``
    are the paper's ``i1`` and ``i2``; its printed ``k1``, ``k2`` use
    ``(2 lmax^2/lmin)^(2 r4/(r3+r4))`` instead, which is what makes its ``T_E``
    two orders of magnitude too small (SPEC section 6).
    """
    lmin = float(np.linalg.eigvalsh(H)[0])
    n = len(H)
    al, be = g.r3 / g.r4, g.r5 / g.r6
    p, q = (1.0 + al) / 2.0, (1.0 + be) / 2.0
    a = g.K1 * n ** min(0.0, (1.0 - al) / 2.0) * (2.0 * lmin) ** p
    b = g.K2 * n ** min(0.0, (1.0 - be) / 2.0) * (2.0 * lmin) ** q
    return a, p, b, q


def _decay_time(x1: float, x0: float, a: float, p: float, b: float, q: float) -> float:
    """``int_x1^x0 dx / (a x^p + b x^q)`` for ``0 < x1 <= x0 < inf``, s (log-grid trapezoid)."""
    if x0 <= x1:
        return 0.0
    s = np.linspace(math.log(x1), math.log(x0), 20001)
    x = np.exp(s)
    return float(np.trapezoid(x / (a * x**p + b * x**q), s))


def estimator_bound_derived(
    H: np.ndarray, g: EstimatorGains, delta0: np.ndarray | None = None, tol: float = 0.0
) -> float:
    """A settling-time bound for the estimator that we derived and check (SPEC section 6), s.

    Without ``delta0``: the uniform fixed-time bound, Lemma 1 (second form) applied to
    :func:`estimator_lyapunov_decay`, ``1/(a (p-1)) + 1/(b (1-q))`` (infinite unless
    ``r3/r4 > 1`` and ``r5/r6 < 1``). With ``delta0`` (n, 3), the initial errors
    ``ph_i(0) - p0(0)``, and ``tol > 0``: the time by which every ``|ph_i - p0| < tol``,
    ``max over axes of int_{V_tol}^{V_0} dV / (a V^p + b V^q)`` with
    ``V_0 = delta^T H delta / 2`` on that axis and ``V_tol = lmin (tol/sqrt 3)^2 / 2``
    (``V <= V_tol`` on every axis implies ``|delta_i| < tol``). Finite for every variant.
    Proven for ``power = "aggregate"``; for ``"pairwise"`` (eq. (11) as printed) the
    sweep checks it against measurements instead.
    """
    a, p, b, q = estimator_lyapunov_decay(H, g)
    if delta0 is None:
        if p <= 1.0 or q >= 1.0:
            return math.inf
        return 1.0 / (a * (p - 1.0)) + 1.0 / (b * (1.0 - q))
    lmin = float(np.linalg.eigvalsh(H)[0])
    v_tol = lmin * (tol / math.sqrt(3.0)) ** 2 / 2.0
    delta0 = np.asarray(delta0, dtype=float).reshape(len(H), 3)
    v0 = 0.5 * np.einsum("ic,ij,jc->c", delta0, H, delta0)
    return max(_decay_time(v_tol, float(v), a, p, b, q) if v_tol > 0 else math.inf for v in v0)
