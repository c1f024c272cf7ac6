"""Crosswalk pedestrians of every slot: who steps out (one test over the active crosswalks of the
stepped slots for a step-out due, each drawn from a geometric wait with counter-based draws when
the one before it is: no draw in a frame without one) and who has got across (let go). Walking is
`TrafficCore.walk`; `vehicles.Pedestrian` is a walker row's view, which the rules
(`TrafficControl.pedestrians`, per crosswalk) and highway-env (`road.objects`) read."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...config import PEDESTRIAN_CLEARANCE_M, PEDESTRIAN_SIDE_OFFSET, PEDESTRIAN_SPAWN_HORIZON_S, PEDESTRIAN_SPEED_SPREAD
from ..network import MapNetwork
from ..vehicles import Pedestrian
from . import random

if TYPE_CHECKING:
    from ..core import TrafficCore

WAIT, SIDE, OFFSET, SPEED = range(4)  # the draw streams (`random.uniform`)


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


def start(core: "TrafficCore", slot: int, active: list[int], key: int, chance: float, most: int) -> None:
    """Slot `slot` starts an episode with crosswalks `active` (indices): with `chance` a frame
    someone steps out on each (at most `most` on one), drawn from `key`; frame 0."""
    if len(active) > core.cw_of.shape[1]:  # room for this many
        grow = len(active) - core.cw_of.shape[1]
        core.cw_of = np.hstack([core.cw_of, np.full((len(core.cw_of), grow), -1, dtype=np.int64)])
        core.ped_due = np.hstack([core.ped_due, np.full((len(core.ped_due), grow), np.inf)])
    core.cw_of[slot], core.ped_due[slot] = -1, np.inf
    core.cw_of[slot, :len(active)] = active
    core.ped_key[slot], core.ped_frame[slot], core.ped_chance[slot], core.ped_max[slot] = key, 0, chance, most
    if active:
        core.ped_due[slot, :len(active)] = _next(key, 0, np.arange(len(active)), chance)


def _next(key, frame, k, chance) -> np.ndarray:
    """The frame after `frame` on which someone next steps out on crosswalk `k` of a slot: a
    geometric wait of success `chance` a frame (what a draw every frame would give, drawn once;
    never where `chance` is 0). Arrays, elementwise."""
    u = random.uniform(key, frame, WAIT, k)
    chance = np.minimum(chance, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        wait = np.floor(np.log1p(-u) / np.log1p(-chance))
    return np.where(chance > 0, frame + 1 + wait, np.inf)


def update(core: "TrafficCore", dt: float, slots: np.ndarray) -> None:
    """One frame of the crosswalks of `slots` (a mask over slots): the pedestrians across let go;
    on each active crosswalk whose step-out is due (`start`, `_next`) one steps out if there is
    room (`pedestrians_per_crosswalk`), from a random end, up to `PEDESTRIAN_SIDE_OFFSET` of the
    width beside its axis, unless a road user is within `PEDESTRIAN_CLEARANCE_M` plus
    `PEDESTRIAN_SPAWN_HORIZON_S` of its own travel of that place, and the next one is drawn; each
    slot's frame counter moves on.
    A frame of `dt` 0 (a reset's bookkeeping) lets nobody out."""
    if not len(core.p_env) and not core.ped_due.shape[1]:  # no walker, no crosswalk ever active
        core.ped_frame[slots] += 1
        return
    changed: dict[int, list] = {}
    across = (core.p_left <= 1e-6) & slots[core.p_env] if len(core.p_env) else np.zeros(0, dtype=bool)
    if across.any():
        gone = across.nonzero()[0].tolist()
        for i in gone:
            p = core.p_objs[i]
            core.roads[core.p_env[i]].control.pedestrians[p.crosswalk_id].remove(p)
            changed.setdefault(int(core.p_env[i]), [])
        core.drop_walkers([core.p_objs[i] for i in gone])
    due_s, due_k = np.nonzero(core.ped_due <= core.ped_frame[:, None])
    on = slots[due_s]
    due_s, due_k = due_s[on], due_k[on]
    if len(due_s):  # (a few: a step out is rare) their draws at once, then each steps out in turn
        frame, key = core.ped_frame[due_s], core.ped_key[due_s]
        draws = random.uniform(key[:, None], frame[:, None], np.array([[SIDE, OFFSET, SPEED]]), due_k[:, None])
        for s, k, drawn in zip(due_s.tolist(), due_k.tolist(), draws.tolist()):
            c = int(core.cw_of[s, k])
            if dt > 0 and np.count_nonzero((core.p_env == s) & (core.p_cw == c)) < core.ped_max[s]:
                p = _step_out(core, s, c, *drawn)
                if p is not None:
                    changed.setdefault(s, []).append(p)
        core.ped_due[due_s, due_k] = _next(key, frame, due_k, core.ped_chance[due_s])
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
    off = np.array([-d[1], d[0]]) * (2 * offset - 1) * PEDESTRIAN_SIDE_OFFSET * t.width[cw]
    rows = core.slot_rows(slot)
    near = np.hypot(core.x[rows] - (a + off)[0], core.y[rows] - (a + off)[1]) \
        < PEDESTRIAN_CLEARANCE_M + PEDESTRIAN_SPAWN_HORIZON_S * np.maximum(core.speed[rows], 0.0)
    if near.any():
        return None
    road = core.roads[slot]
    v = float(road.control.cfg["pedestrian_speed"]) * (1 + (2 * speed - 1) * PEDESTRIAN_SPEED_SPREAD)
    return Pedestrian(road, a + off, b + off, v, t.ids[cw])
