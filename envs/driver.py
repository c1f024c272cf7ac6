"""A tiny rule-following driver for MapEnv: IDM behind leaders and before the stop point the
traffic rules impose (red/amber signals, stop signs in arrival order, pedestrians, conflicting
junction traffic). Use it with a longitudinal-only ContinuousAction (steering follows the
route); `ignore` breaks chosen rules on purpose (e.g. {"signal"} runs red lights).
"""
from __future__ import annotations

from typing import Iterable

import numpy as np

from .rules import idm

DRIVER_ACTION_CONFIG = {"type": "ContinuousAction", "longitudinal": True, "lateral": False,
                        "acceleration_range": [-8.0, 4.0]}


class ScriptedDriver:
    """Acceleration commands for the ego of a MapEnv configured with DRIVER_ACTION_CONFIG."""

    def __init__(self, env, ignore: Iterable[str] = ()) -> None:
        self.env = env.unwrapped
        self.ignore = frozenset(ignore)

    def acceleration(self) -> float:
        env = self.env
        stop = env.claim(self.ignore)
        return idm(env.vehicle, env.leader_gaps(), stop)

    def act(self) -> np.ndarray:
        lo, hi = self.env.action_type.acceleration_range
        a = float(np.clip(self.acceleration(), lo, hi))
        return np.array([2 * (a - lo) / (hi - lo) - 1], dtype=np.float32)
