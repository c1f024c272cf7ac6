"""Crosswalk pedestrians of every slot: who steps out (one program over the active crosswalks of
the stepped slots, with counter-based draws) and who has got across (let go). Walking is
`TrafficCore.walk`; `vehicles.Pedestrian` is a walker row's view, which the rules
(`TrafficControl.pedestrians`, per crosswalk) and highway-env (`road.objects`) read."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...config import PEDESTRIAN_CLEARANCE_M, PEDESTRIAN_SPAWN_HORIZON_S
from ..network import MapNetwork
from ..vehicles import Pedestrian
from . import random

if TYPE_CHECKING:
    from ..core import TrafficCore

SPAWN, SIDE, OFFSET, SPEED = range(4)  # the draw streams (`random.uniform`)
SIDE_OFFSET = 0.3  # a pedestrian steps out within this fraction of the crosswalk's width of its axis
SPEED_SPREAD = 0.15  # ... at the configured speed times 1 +- this


@dataclass(frozen=True)
class Crosswalks:
    """The network's crosswalk axes as arrays (`MapNetwork.crosswalk_axes`): ends a, b, width."""
    ids: list[str]
    index: dict[str, int]
    a: np.ndarray  # [K, 2]
    b: np.ndarray
    width: np.ndarray


def crosswalks(net: MapNetwork) -> Crosswalks:
    """The crosswalk table of `net` (a memo of the network's)."""
    def build() -> Crosswalks:
        ids = list(net.crosswalk_axes)
        axes = [net.crosswalk_axes[c] for c in ids]
        return Crosswalks(ids, {c: k for k, c in enumerate(ids)}, np.array([a for a, _, _ in axes]).reshape(-1, 2),
                          np.array([b for _, b, _ in axes]).reshape(-1, 2), np.array([w for _, _, w in axes]))
    return net.memo("crosswalk table", build)


def update(core: "TrafficCore", dt: float, slots: np.ndarray) -> None:
    """One frame of the crosswalks of `slots` (a mask over slots): the pedestrians across let go;
    at each active crosswalk with room (`pedestrians_per_crosswalk`) one steps out with probability
    `pedestrian_rate` / 60 * dt, from a random end, up to `SIDE_OFFSET` of the width beside its
    axis, unless a road user is within `PEDESTRIAN_CLEARANCE_M` plus `PEDESTRIAN_SPAWN_HORIZON_S`
    of its own travel of that place; each slot's frame counter moves on."""
    changed: dict[int, list] = {}
    across = (core.p_left <= 1e-6) & slots[core.p_env] if len(core.p_env) else np.zeros(0, dtype=bool)
    if across.any():
        gone = across.nonzero()[0].tolist()
        for i in gone:
            p = core.p_objs[i]
            core.roads[core.p_env[i]].control.pedestrians[p.crosswalk_id].remove(p)
            changed.setdefault(int(core.p_env[i]), [])
        core.drop_walkers([core.p_objs[i] for i in gone])
    slot, cw, k = core.crosswalk_pairs()
    on = slots[slot]
    if on.any():
        slot, cw, k = slot[on], cw[on], k[on]
        ncw = len(core.crosswalks.ids)
        walking = np.sort(core.p_env * ncw + core.p_cw)
        pair = slot * ncw + cw
        room = np.searchsorted(walking, pair, side="right") - np.searchsorted(walking, pair) < core.ped_max[slot]
        key, frame = core.ped_key[slot], core.ped_frame[slot]
        steps = room & (random.uniform(key, frame, SPAWN, k) < core.ped_rate[slot] / 60.0 * dt)
        for i in steps.nonzero()[0].tolist():
            s = int(slot[i])
            p = _step_out(core, s, int(cw[i]), *random.uniform(key[i], frame[i], np.array([SIDE, OFFSET, SPEED]), k[i]))
            if p is not None:
                changed.setdefault(s, []).append(p)
    core.ped_frame[slots] += 1
    for s, new in changed.items():
        control = core.roads[s].control
        for p in new:
            control.pedestrians.setdefault(p.crosswalk_id, []).append(p)
        road = core.roads[s]
        road.objects = [o for o in road.objects if not isinstance(o, Pedestrian)] + \
            [p for c in control.active_crosswalks for p in control.pedestrians.get(c, ())]


def _step_out(core: "TrafficCore", slot: int, cw: int, side: float, offset: float, speed: float) -> Pedestrian | None:
    """A pedestrian of slot `slot` stepping out onto crosswalk `cw` (its draws in [0, 1) given),
    or None where a road user is too close."""
    t = core.crosswalks
    a, b = (t.b[cw], t.a[cw]) if side < 0.5 else (t.a[cw], t.b[cw])
    d = (b - a) / max(float(np.hypot(*(b - a))), 1e-9)
    off = np.array([-d[1], d[0]]) * (2 * offset - 1) * SIDE_OFFSET * t.width[cw]
    rows = core.slot_rows(slot)
    near = np.hypot(core.x[rows] - (a + off)[0], core.y[rows] - (a + off)[1]) \
        < PEDESTRIAN_CLEARANCE_M + PEDESTRIAN_SPAWN_HORIZON_S * np.maximum(core.speed[rows], 0.0)
    if near.any():
        return None
    road = core.roads[slot]
    v = float(road.control.cfg["pedestrian_speed"]) * (1 + (2 * speed - 1) * SPEED_SPREAD)
    return Pedestrian(road, a + off, b + off, v, t.ids[cw])
