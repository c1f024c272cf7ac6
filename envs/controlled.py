"""Views of controlled rows: the ego of the single and batched envs and the multi-agent env's
agents are rows of the arrays core (core.py) that drive our kinematic bicycle (`sim/vehicle.py`,
`TrafficCore.drive`); these are the objects highway-env's action and observation types, the
rules, planners and the renderer hold for them. A view keeps no state of its own but what an
action decodes to: the decision is written into the row (`command`, `target`, `keeps`,
`cmd_steer`), and the core turns it into steering and acceleration every frame, for all rows at
once."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from highway_env.vehicle.controller import MDPVehicle

from ..invariants import lane_changes
from .core import ArrayVehicle
from .sim.vehicle import VehicleModel

if TYPE_CHECKING:
    from .tracking import TrajectoryTracker


class ControlledRow(ArrayVehicle):
    """A controlled row's view: the config's `vehicle` (`model`), commanded as highway-env's
    ContinuousAction commands a vehicle (`act` with {"acceleration", "steering"}): the
    acceleration is held until the next decision; with `auto_steer` (no lateral action) lane
    keeping steers it along its route every frame, else the steering is held. Where it is
    (`lane_index`, `lane_s`, `lane_lat`) is the lane it is located on (`TrafficCore.locate`).
    TimeToCollision predicts for `target_speeds` (the current one the nearest to the speed)."""

    color = (50, 200, 0)  # drawn as highway-env draws its ego (traffic is blue)
    target_speeds = np.array([0.0, 4.5, 9.0])
    model: VehicleModel
    _auto_steer = True
    _tracker: "TrajectoryTracker | None" = None

    @property
    def MAX_STEERING_ANGLE(self) -> float:  # noqa: N802 (highway-env's name)
        return self.model.max_steering

    @property
    def heading(self) -> float:
        return float(self._core.heading[self._row])

    @heading.setter
    def heading(self, value) -> None:  # a bicycle turns where it is turned
        self._core.heading[self._row] = float(value)

    def on_state_update(self) -> None:
        """Located again (after user code moved or turned it)."""
        self._core.relocate(self._row, np.array([self._core.x[self._row], self._core.y[self._row]]))

    @property
    def action(self) -> dict:
        """The last frame's command: the steering it drove and its acceleration."""
        c, i = self._core, self._row
        return {"steering": float(c.steer[i]), "acceleration": float(c.acc[i])}

    @action.setter
    def action(self, value) -> None:
        pass

    @property
    def auto_steer(self) -> bool:
        """Lane keeping steers it while no tracker does (else its held steering command)."""
        return self._auto_steer

    @auto_steer.setter
    def auto_steer(self, value: bool) -> None:
        self._auto_steer = bool(value)
        self._steering_source()

    @property
    def tracker(self) -> "TrajectoryTracker | None":
        """An external planner's trajectory: while set, it commands the row every frame (`track`)."""
        return self._tracker

    @tracker.setter
    def tracker(self, value: "TrajectoryTracker | None") -> None:
        self._tracker = value
        self._steering_source()

    def _steering_source(self) -> None:
        """The row's `keeps`: lane keeping steers it with `auto_steer` and no tracker."""
        self._core.keeps[self._row] = self._auto_steer and self._tracker is None

    # ---- where it is: located, not only projected on its route lane ---------------------------
    def _ignore(self, value) -> None:  # (set by the core alone)
        pass

    lane_index = property(lambda self: self._core.net._indices[self._core.at_lane[self._row]], _ignore)
    lane = property(lambda self: self._core.net._lanes[self._core.at_lane[self._row]], _ignore)
    lane_s = property(lambda self: float(self._core.at_s[self._row]), _ignore)
    lane_lat = property(lambda self: float(self._core.at_lat[self._row]), _ignore)

    # ---- commands ------------------------------------------------------------------------------
    def act(self, action: Any = None) -> None:
        """A decision (highway-env's ContinuousAction hands a dict): the acceleration, and the
        steering unless lane keeping steers."""
        if isinstance(action, dict):
            c, i = self._core, self._row
            c.command[i] = float(action.get("acceleration", 0.0))
            c.cmd_steer[i] = float(action.get("steering", 0.0))

    def track(self) -> None:
        """This frame's command from the tracker (an external planner's trajectory)."""
        c, i = self._core, self._row
        assert self._tracker is not None
        a = self._tracker.command((c.x[i], c.y[i]), float(c.heading[i]), float(c.speed[i]))
        c.command[i], c.cmd_steer[i] = a["acceleration"], a["steering"]

    def index_to_speed(self, index: int) -> float:
        return float(self.target_speeds[index])

    @property
    def speed_index(self) -> int:
        return int(np.argmin(np.abs(self.target_speeds - self.speed)))


class MetaRow(ControlledRow):
    """A controlled row under DiscreteMetaAction, as highway-env's MDPVehicle takes it (FASTER /
    SLOWER: the target speed one step from the one nearest the speed, held by speed control;
    LANE_LEFT / LANE_RIGHT: onto the neighbour lane of its route lane where it is reachable and
    the line between them is dashed (`invariants.lane_changes`), the rest of the route re-planned
    from there), steered by lane keeping."""

    speed_to_index = MDPVehicle.speed_to_index
    speed_index: int = 0  # type: ignore[assignment]

    @property
    def target_speed(self) -> float:
        return float(self._core.target[self._row])

    @target_speed.setter
    def target_speed(self, value: float) -> None:
        self._core.target[self._row] = float(value)

    def act(self, action: Any = None) -> None:
        if action in ("FASTER", "SLOWER"):
            index = self.speed_to_index(self.speed) + (1 if action == "FASTER" else -1)
            self.speed_index = int(min(max(index, 0), self.target_speeds.size - 1))
            self.target_speed = self.index_to_speed(self.speed_index)
        elif action in ("LANE_LEFT", "LANE_RIGHT"):
            self.change_lane(-1 if action == "LANE_LEFT" else 1)

    def change_lane(self, side: int) -> None:
        """Onto the neighbour lane on `side` (-1 left, +1 right: highway-env's lane order on the
        road edge) of the route lane, where reachable from here across a dashed line and the
        route's destination is reachable from it."""
        net = self.net
        here = self.target_lane_index
        _from, _to, _id = here
        index = (_from, _to, int(min(max(_id + side, 0), len(net.graph[_from][_to]) - 1)))
        old, new = net.id_of.get(here), net.id_of.get(index)
        if index == here or new is None or not net.get_lane(index).is_reachable_from(self.position) or (
                old is not None and new not in lane_changes(net.hdmap.lanes[old])):
            return
        path = self.parallel_route(new) or net.lane_route(new, self.lane_route[-1])
        if path:
            pos = self.route_pos
            self._core.reroute(self._row, self.lane_route[:pos] + path, pos)
