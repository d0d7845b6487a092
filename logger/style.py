"""What the recording looks like: entity paths, colours, the default blueprint.

Colours are packed ``0xRRGGBBAA`` uint32 (the cheapest form Rerun takes).
"""

from __future__ import annotations

import numpy as np

APP_ID = "fxswarm"  # no '.' or '/': Rerun renames those
TIMELINE = "sim_time"  # seconds of simulation time
TICK_TIMELINE = "tick"  # lock-step tick

# 3D entities, under one origin so the blueprint's 3D view shows them all.
ROBOTS = "world/robots"
LAW = "run/law"  # the scenario's [controller] law, a text
TRAILS = "world/trails"
LEADER = "world/leader"
ESTIMATES = "world/estimates"
SLOTS = "world/slots"
OBSTACLES = "world/obstacles"
EDGES = "world/edges"
VELOCITIES = "world/velocities"
HEADINGS = "world/headings"  # a unicycle's heading (docs/robots.md), an arrow of HEADING_LENGTH m
HEADING_LENGTH = 0.8

# Time series: one entity per plot, all robots in one Scalars (one series each).
FORMATION_ERROR = "metrics/formation_error"
NEAREST_DISTANCE = "metrics/nearest_distance"  # robots' series plus the d line as the last one
ESTIMATE_ERROR = "metrics/estimate_error"
AVOID_ACTIVE = "metrics/avoid_active"
LINK_DROPS = "metrics/links/drops"
LINK_STALE = "metrics/links/stale"
REAL_TIME_FACTOR = "metrics/timing/real_time_factor"
TICK_RATE = "metrics/timing/tick_rate"
LOGGER_DROPPED = "metrics/timing/logger_dropped"

# Tableau 10: distinct, readable on the viewer's dark background and on white paper.
_PALETTE = [0x4E79A7, 0xF28E2B, 0xE15759, 0x76B7B2, 0x59A14F, 0xEDC948, 0xB07AA1, 0xFF9DA7, 0x9C755F, 0xBAB0AC]
LEADER_COLOUR = 0xFFFFFFFF
OBSTACLE_COLOUR = 0xC8503C50  # translucent red: the repulsive zone of radius d
LINK_OK = 0x59A14FFF
LINK_BAD = 0xE15759FF
D_LINE_COLOUR = 0xE15759FF


def robot_rgb(i: int) -> int:
    """0xRRGGBB of robot index ``i`` (0-based); the same colour in the viewer and the report."""
    return _PALETTE[i % len(_PALETTE)]


def robot_colours(n: int, alpha: int = 0xFF) -> np.ndarray:
    """(n,) uint32 RGBA colours, one per robot."""
    return np.array([(robot_rgb(i) << 8) | alpha for i in range(n)], dtype=np.uint32)


def robot_hex(i: int) -> str:
    """Matplotlib colour of robot index ``i`` (0-based)."""
    return f"#{robot_rgb(i):06x}"


def blueprint():
    """The first screen: the 3D swarm beside stacked time series, on ``sim_time``."""
    import rerun.blueprint as rrb

    legend = rrb.PlotLegend(corner=rrb.Corner2D.RightTop)

    def plot(origin: str, name: str):
        return rrb.TimeSeriesView(origin=origin, name=name, plot_legend=legend)

    series = rrb.Vertical(
        plot(FORMATION_ERROR, "formation error |e_i| (m)"),
        plot(NEAREST_DISTANCE, "distance to nearest object (m), d"),
        plot(ESTIMATE_ERROR, "estimate error |ph_i - p0| (m)"),
        rrb.Tabs(
            plot(AVOID_ACTIVE, "avoidance active"),
            plot("metrics/links", "links: drops, stale frames"),
            plot("metrics/timing", "real-time factor, ticks/s"),
        ),
    )
    # The camera follows the leader from behind and above, so the swarm stays in view as it climbs.
    eye = rrb.EyeControls3D(position=(14.0, -14.0, 9.0), look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 0.0, 1.0),
                            tracking_entity=LEADER)
    swarm = rrb.Spatial3DView(origin="world", name="swarm", eye_controls=eye)
    return rrb.Blueprint(
        rrb.Horizontal(swarm, series, column_shares=[3, 2]),
        rrb.TimePanel(timeline=TIMELINE),  # without it the viewer opens on another timeline
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )
