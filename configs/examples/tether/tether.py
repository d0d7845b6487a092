"""Tether: a user's formation law for fxswarm, written against the law API (docs/controllers.md).

Linear consensus on the leader's position, a proportional pull into the formation slot, and a
spring that pushes away from the nearest object inside the repulsive zone:

    d ph_i/dt = kc * (sum_j a_ij (ph_j - ph_i) + b_i (p0 - ph_i))
    v_i       = d ph_i/dt + d p_i0/dt - kf * (p_i - ph_i - p_i0)
                + ka * (d - |u|) * u / |u|      if |u| < d,  u = p_i - po

The estimate converges only asymptotically and lags a moving leader (no sign term): the
paper's fixed-time law is the reference it is flown against.
"""

import numpy as np


class Tether:
    def __init__(self, params: dict, robot_id: int, scenario):
        unknown = set(params) - {"kc", "kf", "ka"}
        if unknown:
            raise ValueError(f"unknown parameters {sorted(unknown)} (known: ka, kc, kf)")
        self.kc = float(params.get("kc", 2.0))
        self.kf = float(params.get("kf", 1.5))
        self.ka = float(params.get("ka", 2.0))
        if self.kc <= 0 or self.kf <= 0 or self.ka < 0:
            raise ValueError(f"expected kc > 0, kf > 0, ka >= 0, got kc={self.kc}, kf={self.kf}, ka={self.ka}")

    def estimate_rate(self, view):
        pull = np.zeros(3)
        for a, ph_j in zip(view.weights, view.rows):  # neighbours, then the leader if pinned and heard
            pull += a * (ph_j - view.ph)
        return self.kc * pull

    def velocity(self, view, estimate_rate):
        v = estimate_rate + view.offset_rate - self.kf * (view.p - view.ph - view.offset)
        if view.nearest is not None:
            po, _ = view.nearest
            u = view.p - po
            dist = np.linalg.norm(u)
            if 0.0 < dist < view.d:
                v = v + self.ka * (view.d - dist) * u / dist
        return v
