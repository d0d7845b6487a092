"""The batch path of ``fxswarm sim``: every robot's law stepped at once, on arrays.

The per-robot path runs an :class:`~fxswarm.agents.node.AgentNode` per robot and the world on
an in-memory bus. When every robot flies a law with a batch form (the built-in laws:
:class:`fxswarm.core.paper_law.BehaviouralBatch`) and the run needs nothing the batch form
cannot do exactly, this module steps the same world (:class:`~fxswarm.world.node.WorldNode`:
its sensing, integration and record) with one batch call per tick instead of n agents and
their messages. Its trajectories equal the per-robot path's bit for bit (tests/unit/test_batch.py).

What it takes (else :func:`batch_plan` says why, and the simulator steps per robot):
lock-step, no fault plan, a law with a batch form of its own.
Its assumptions in a healthy lock-step run (every robot holds every neighbour's estimate of
the current tick, so delay compensation, staleness and extrapolation never act) are those
of the per-robot path without faults.
"""

from __future__ import annotations

import math
import time

import numpy as np

from fxswarm.core.laws import BatchUnsupported, resolve_law
from fxswarm.core.motion import offset_groups
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FaultPlan
from fxswarm.world.node import WorldNode

PATHS = ("auto", "batch", "per-robot")


def neighbour_slots(sc: Scenario) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(slots, weights, valid)``, (n, S): robot i's rows in the order its node sums them
    (neighbours in ascending id, then the leader, index n, if pinned), padded to S."""
    n = sc.n
    rows = []
    for r in sc.robots:
        ids = [j - 1 for j in sc.neighbours(r.id)]
        ws = sc.weights(r.id)
        if sc.is_pinned(r.id):
            ids.append(n)
            ws.append(float(sc.b[r.id - 1]))
        rows.append((ids, ws))
    width = max(len(ids) for ids, _ in rows)
    slots = np.full((n, width), n, dtype=np.intp)
    weights = np.zeros((n, width))
    valid = np.zeros((n, width), dtype=bool)
    for i, (ids, ws) in enumerate(rows):
        slots[i, :len(ids)] = ids
        weights[i, :len(ws)] = ws
        valid[i, :len(ids)] = True
    return slots, weights, valid


def batch_plan(sc: Scenario, plan: FaultPlan | None):
    """The law's batch form for this run, or :class:`BatchUnsupported` saying why not."""
    if plan is not None and (plan.rules or plan.cuts or plan.processes or plan.lies):
        raise BatchUnsupported("the run has faults (the batch path takes none yet)")
    if sc.world is not None:  # drive models and sensing live in the agents' view and the world's Sense
        raise BatchUnsupported("the scenario has a [world] table (drive models or sensing: per robot only)")
    if sc.resilience != "none":
        raise BatchUnsupported(f"[estimator] resilience = {sc.resilience!r} (W-MSR trims per robot only)")
    if sc.estimator_graph != "undirected":
        raise BatchUnsupported(f"[estimator] estimator_graph = {sc.estimator_graph!r} (per robot only)")
    cls = resolve_law(sc.law, sc.law_folder)
    form = vars(cls).get("batch")  # the class's own: a subclass that changes the law must say its batch form
    if form is None:
        raise BatchUnsupported(f"law {sc.law!r} has no batch form" +
                               (" of its own (it inherits one)" if getattr(cls, "batch", None) else ""))
    if sc.law_params:
        raise BatchUnsupported("the law has [controller.params]")
    slots, weights, valid = neighbour_slots(sc)
    if not valid.any(axis=1).all():
        raise BatchUnsupported("a robot hears nobody")
    return form(sc, slots, weights, valid)


class _Offsets:
    """Every robot's formation offset and its rate at time t, (n, 3) each, computed as
    :meth:`fxswarm.core.motion.Offset.state_lists` does, once per distinct sinusoid."""

    def __init__(self, sc: Scenario) -> None:
        self.base, self.groups = offset_groups(sc.robots)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        pos, vel = self.base.copy(), np.zeros_like(self.base)
        for (amp, omega, phase), ids in self.groups:
            for k in range(3):
                a = amp[k]
                if a:  # as state_lists: pos[k] += a * sin(angle), vel[k] = a * omega * cos(angle)
                    angle = omega[k] * t + phase[k]
                    pos[ids, k] = pos[ids, k] + a * math.sin(angle)
                    vel[ids, k] = a * omega[k] * math.cos(angle)
        return pos, vel


class BatchRun:
    """Steps ``world`` with the batch form ``law`` to the end (:meth:`run`)."""

    def __init__(self, sc: Scenario, world: WorldNode, law) -> None:
        self.sc, self.world, self.law = sc, world, law
        self.ph = np.array([r.estimate for r in sc.robots], dtype=float)
        self.offsets = _Offsets(sc)
        self.speed_limited = 0
        self.vh = np.zeros((sc.n, 3))  # tracking = "feedforward": each robot's estimate of the leader's velocity

    def run(self, progress=None) -> float:
        """Every tick; returns the stepping wall time, s. ``progress(world, ticks_per_s)`` about
        twice a second and at the end. Raises :class:`BatchUnsupported` if a robot's law gives a
        non-finite value (the per-robot path's law_error, which the batch path does not model)."""
        sc, world, law = self.sc, self.world, self.law
        dt, v_max = sc.dt, sc.v_max
        start = last = time.perf_counter()
        po, vo, dist = world._sense_now()
        while True:
            k = world.tick
            t = world.t
            p = world.p
            sensed = np.isfinite(dist)
            p0 = np.asarray(sc.leader.position(t), dtype=float)
            offset, offset_rate = self.offsets.at(t)
            ph = self.ph
            try:
                # eqs. (11ff), (v2ff) on vh(k) with feedforward; then eq. (obs) steps vh, as AgentNode.act
                vh = self.vh if law.feedforward else None
                # an overflow (a power, where ** raises OverflowError) raises here, as per robot
                with np.errstate(over="raise"):
                    dph = law.estimate_rates(ph, p0, dt, vh)
                    reference = vh if vh is not None and not law.semi_implicit else None  # eq. (v2ff): explicit only
                    v, avoid = law.velocities(p, ph, dph, offset, offset_rate, po, vo, sensed, reference, dt)
                    if vh is not None:  # eq. (obs) on vh(k), for tick k + 1
                        vh_next = vh + dt * law.observer_rates(vh, np.asarray(sc.leader.velocity(t), dtype=float))
            except ArithmeticError as exc:  # per robot, that robot's law_error
                what = "an overflow" if isinstance(exc, FloatingPointError) else type(exc).__name__
                raise BatchUnsupported(f"a law raised {what} at tick {k} (law_error)") from None
            if not (np.isfinite(dph).all() and np.isfinite(v).all()):
                raise BatchUnsupported(f"a law gave a non-finite value at tick {k} (law_error)")
            if v_max is not None:  # the node's speed limit, as limit_speed
                speed = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2])
                over = speed > v_max
                if over.any():
                    v[over] = v[over] * (v_max / speed[over])[:, None]
                    self.speed_limited += int(over.sum())
            # the world closing tick k, as WorldNode._finish_tick with every command in
            world.v, world.ph, world.avoid = v, ph, avoid
            world._record()
            world.move(dt)
            world.tick += 1
            self.ph = ph + dt * dph  # explicit Euler (SPEC 7), as AgentNode.act
            if vh is not None:
                self.vh = vh_next
            now = time.perf_counter()
            if progress is not None and now - last > 0.5:
                progress(world, world.tick / (now - start))
                last = now
            if world.tick >= sc.ticks:
                world.done = True
                break
            po, vo, dist = world._sense_now()
        wall = time.perf_counter() - start
        if progress is not None:
            progress(world, world.tick / max(wall, 1e-9))
        return wall
