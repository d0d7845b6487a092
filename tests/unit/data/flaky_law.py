"""A law that fails at run time, for the law_error tests (tests/unit/test_laws.py and
tests/integration/test_laws_zenoh.py copy it beside a scenario)."""

import math
import numpy as np


class Flaky:
    """Tether-like, but robot 2 raises from t = 0.5 s to 0.8 s, robot 3 returns NaN from its
    estimator at t >= 1 s, robot 5 returns 2 numbers as its velocity at 0.3 s <= t < 0.4 s."""

    def __init__(self, params, robot_id, scenario):
        self.id = robot_id

    def estimate_rate(self, view):
        if self.id == 3 and view.t >= 1.0:
            return [math.nan, 0.0, 0.0]
        rate = np.zeros(3)
        for a, ph in zip(view.weights, view.rows):
            rate += a * (ph - view.ph)
        return 4.0 * rate

    def velocity(self, view, rate):
        if self.id == 2 and 0.5 <= view.t < 0.8:
            raise RuntimeError(f"robot 2 gave up at t = {view.t:.2f}")
        if self.id == 5 and 0.3 <= view.t < 0.4:
            return [1.0, 2.0]
        return rate + view.offset_rate - 2.0 * (view.p - view.ph - view.offset)
