"""Gymnasium environments on feat2map maps, following highway-env's conventions.

`MapEnv` drives an ego along a route of junction manoeuvres (or an explicit lane route, or a
sampled lane walk on maps without junctions such as a closed ring road) through a map with
signals, stop signs, crosswalk pedestrians and IDM traffic. Subclasses only say where the map comes
from: `JunctionGridEnv` (generated from a feature space) and `MapFileEnv` (a file or an HDMap).

info keys (every step and reset):
  junction            id of the junction the ego is in, else the next one on its route (or None)
  junction_feature    that junction's feature as a dict (n_roads, rotation, control, crosswalk, ...)
  manoeuvre           the ego's turn there: "left" | "straight" | "right" | "uturn" (or None)
  control_ahead       "signal" | "stop" | "bare" for the next stop line on the route (None past the last)
  signal_id / signal_state / signal_time_to_change   the signal governing the ego's next stop line
  distance_to_stop_line   metres from the ego centre to the next junction entry (inf if none)
  violations          counts {"red_light", "stop_sign", "pedestrian_yield"} so far this episode
  new_violations      violations committed during this step, e.g. ["red_light"]
  collision, off_road, route_progress (0..1), route_completed, lane_id, time
  signal_states       {signal id: state} of the next junction's signals
"""
from __future__ import annotations

import math
from collections import OrderedDict
from typing import Any, Mapping, Sequence

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.action import DiscreteMetaAction
from highway_env.envs.common.observation import ObservationType

from ..config import SIGNAL_ALL_RED_S, SIGNAL_AMBER_S, SIGNAL_GREEN_S
from ..errors import Feat2MapError
from .network import MapNetwork
from .traffic import (PEDESTRIAN_IN_PATH_M, STOP_ZONE_M, STOPPED_SPEED_MPS, EgoMDPVehicle, EgoVehicle, MapRoad,
                      TrafficControl, TrafficVehicle)

VIOLATIONS = ("red_light", "stop_sign", "pedestrian_yield")
_TURN_NAMES = {"none": "straight", "left": "left", "right": "right", "uturn": "uturn"}
_NETWORK_CACHE: "OrderedDict[Any, MapNetwork]" = OrderedDict()
_CACHE_SIZE = 8


def cached_network(key: Any, build) -> MapNetwork:
    """Road networks are immutable during episodes: share them between resets and envs."""
    net = _NETWORK_CACHE.get(key)
    if net is None:
        net = MapNetwork.from_map(build())
        _NETWORK_CACHE[key] = net
        while len(_NETWORK_CACHE) > _CACHE_SIZE:
            _NETWORK_CACHE.popitem(last=False)
    _NETWORK_CACHE.move_to_end(key)
    return net


def merge_config(base: dict, delta: Mapping | None) -> dict:
    """Merge `delta` into the defaults; observation/action dicts merge when their type is kept."""
    for key, val in (delta or {}).items():
        cur = base.get(key)
        if key in ("observation", "action") and isinstance(val, Mapping) and isinstance(cur, Mapping):
            base[key] = {**cur, **val} if val.get("type", cur.get("type")) == cur.get("type") else dict(val)
        else:
            base[key] = val
    return base


class TrafficControlObservation(ObservationType):
    """Wraps any highway-env observation into {"observation", "traffic_control"}; the latter is
    [green, amber, red, stop sign, distance to stop line / 100 (clipped), pedestrian ahead]."""

    def __init__(self, env: "MapEnv", inner: ObservationType) -> None:
        super().__init__(env)
        self.inner = inner

    def space(self) -> spaces.Space:
        return spaces.Dict({"observation": self.inner.space(),
                            "traffic_control": spaces.Box(0.0, 1.0, (6,), dtype=np.float32)})

    def observe(self):
        return {"observation": self.inner.observe(), "traffic_control": self.env.traffic_control_vector()}


class MapEnv(AbstractEnv):
    """Drive a route of junction manoeuvres on a feat2map map (see module docstring for info)."""

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update({
            "observation": {
                "type": "Kinematics", "vehicles_count": 10,
                "features": ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h"],
                "features_range": {"x": [-100, 100], "y": [-100, 100], "vx": [-20, 20], "vy": [-20, 20]},
                "absolute": False, "see_behind": True,
            },
            "action": {"type": "DiscreteMetaAction", "longitudinal": True, "lateral": False,
                       "target_speeds": [0.0, 4.5, 9.0]},
            "simulation_frequency": 15, "policy_frequency": 1,
            "duration": 60.0,  # [s] truncation
            "route": None,  # [(junction id, entry road, exit road), ...], {"lanes": [...]},
            # {"from_lane": a, "to_lane": b}, or None to sample
            "route_junctions": 2,  # junctions on a sampled route (0: a lane walk of route_length)
            "route_length": 200.0,  # [m] driven on a sampled lane walk (maps without junctions)
            "ego_start_distance": 30.0,  # [m] before the first stop line
            "ego_initial_speed": 4.5,
            "goal_distance": 15.0,  # [m] into the last lane of the route
            "traffic_vehicles": 8, "traffic_respawn": True, "traffic_initial_speed": 5.0,
            "signal_green": SIGNAL_GREEN_S, "signal_amber": SIGNAL_AMBER_S, "signal_all_red": SIGNAL_ALL_RED_S,  # [s]
            "signal_phases": "paired",  # "paired": opposite approaches together; "single": one at a time
            "right_turn_on_red": False,  # a right turn past a red signal after a full stop is legal
            "signal_offsets": {},  # {junction or signal id: phase plan offset [s]}; others drawn from np_random
            "pedestrian_rate": 3.0,  # per crosswalk per minute
            "pedestrian_speed": 1.4, "pedestrians_per_crosswalk": 3,
            "observe_traffic_control": False,
            "reward_progress": 1.0, "reward_arrived": 1.0, "reward_collision": -5.0,
            "reward_red_light": -2.0, "reward_stop_sign": -1.0, "reward_pedestrian_yield": -2.0,
            "reward_off_road": -1.0,
            "offroad_terminal": True,
            "screen_width": 600, "screen_height": 600, "centering_position": [0.5, 0.5], "scaling": 5.5,
            "show_route": True,
        })
        return config

    def configure(self, config: dict) -> None:
        merge_config(self.config, config)
        if self.config["offscreen_rendering"] is None:
            self.config["offscreen_rendering"] = self.render_mode != "human"

    # ---- map -----------------------------------------------------------------------------
    def _network(self) -> MapNetwork:
        raise NotImplementedError

    def define_spaces(self) -> None:
        super().define_spaces()
        if self.config.get("observe_traffic_control"):
            self.observation_type = TrafficControlObservation(self, self.observation_type)
            self.observation_space = self.observation_type.space()

    # ---- episode -------------------------------------------------------------------------
    def _reset(self) -> None:
        self.net = self._network()
        rng = self.np_random
        self.control = TrafficControl(self.net, rng, self.config)
        self.road = MapRoad(self.net, self.control, rng, record_history=self.config["show_trajectories"])
        route = self._ego_route()
        self._make_ego(route)
        route_junctions = {self.net.hdmap.lanes[l].junction_id for l in route} - {None}
        self.control.active_crosswalks = [c.id for c in self.net.hdmap.crosswalks.values()
                                          if c.junction_id in route_junctions]
        self._spawn_lanes = self._traffic_spawn_lanes(route, route_junctions)
        for _ in range(int(self.config["traffic_vehicles"])):
            self._spawn_traffic()
        self.control.update(self.road, 0.0)
        self.violations = {k: 0 for k in VIOLATIONS}
        self.new_violations: list[str] = []
        self._ego_lane = self.net.id_of.get(self.vehicle.lane_index)
        self._stopped: set[str] = set()
        self._crossed: set[str] = set()
        self._ped_flags: set[str] = set()
        self._progress = self.vehicle.route_distance_done()
        last = self.net.lane_of[route[-1]]
        self._route_len = self.vehicle.route_length() - last.length + self._goal_s(last)
        self.off_road = False

    def _ego_route(self) -> list[str]:
        spec = self.config["route"]
        if isinstance(spec, Mapping):
            return lane_route_from_config(self.net, spec)
        if spec:
            return manoeuvres_to_lanes(self.net, spec)
        if int(self.config["route_junctions"]) <= 0 or not self.net.hdmap.junctions:
            c = self.config
            return sample_lane_walk(self.net, self.np_random, float(c["route_length"]),
                                    float(c["ego_start_distance"]), float(c["goal_distance"]))
        for _ in range(100):
            r = sample_route(self.net, self.np_random, int(self.config["route_junctions"]))
            if r:
                return r
        raise Feat2MapError("no route through a junction could be sampled", "map")

    def _make_ego(self, route: list[str]) -> None:
        lane = self.net.lane_of[route[0]]
        s0 = max(0.0, lane.length - float(self.config["ego_start_distance"]))
        pos, heading = lane.position(s0, 0.0), lane.heading_at(s0)
        speed = float(self.config["ego_initial_speed"])
        if isinstance(self.action_type, DiscreteMetaAction):
            ego = EgoMDPVehicle(self.road, pos, heading, speed, target_speeds=self.action_type.target_speeds)
            ego.init_route(route)
            ego.speed_index = ego.speed_to_index(speed)
            ego.target_speed = ego.index_to_speed(ego.speed_index)
        else:
            ego = EgoVehicle(self.road, pos, heading, speed)
            ego.auto_steer = not getattr(self.action_type, "lateral", True)
            ego.init_route(route)
        self.road.vehicles.append(ego)
        self.controlled_vehicles = [ego]

    def _traffic_spawn_lanes(self, route: list[str], junctions: set[str]) -> list[str]:
        m = self.net.hdmap
        lanes = [l for l in route if m.lanes[l].junction_id is None]
        if not junctions:  # e.g. round a ring road: the same-direction lanes beside the route too
            edge = self.net.index_of
            lanes += [n for l in set(lanes) for n in m.lanes[l].left_neighbors + m.lanes[l].right_neighbors
                      if n in edge and edge[n][:2] == edge[l][:2]]
        for jid in sorted(junctions):  # approaches and exits of the junctions on the route
            for jl in m.lanes_by_junction.get(jid, []):
                lanes += [x for x in jl.predecessors + jl.successors if x in m.lanes]
        return sorted(set(lanes))

    def _spawn_traffic(self, min_ego_distance: float = 25.0) -> TrafficVehicle | None:
        if not self._spawn_lanes:
            return None
        rng = self.np_random
        for _ in range(10):
            lid = self._spawn_lanes[int(rng.integers(len(self._spawn_lanes)))]
            lane = self.net.lane_of[lid]
            s = float(rng.uniform(0.0, max(lane.length - 8.0, 0.1)))
            pos = lane.position(s, 0.0)
            if np.hypot(*(pos - self.vehicle.position)) < min_ego_distance:
                continue
            if any(np.hypot(*(pos - v.position)) < 12.0 for v in self.road.vehicles):
                continue
            route = random_walk(self.net, rng, lid, 3)
            v = TrafficVehicle(self.road, pos, lane.heading_at(s), float(self.config["traffic_initial_speed"]))
            v.init_route(route)
            v.target_speed = lane.speed_limit
            self.road.vehicles.append(v)
            return v
        return None

    # ---- stepping ------------------------------------------------------------------------
    def _simulate(self, action=None) -> None:
        self.new_violations = []
        frames = int(self.config["simulation_frequency"] // self.config["policy_frequency"])
        dt = 1 / self.config["simulation_frequency"]
        for frame in range(frames):
            if action is not None and not self.config["manual_control"] and \
                    self.steps % frames == 0:
                self.action_type.act(action)
            self.road.act()
            self.road.step(dt)
            self.steps += 1
            self._check_ego()
            if frame < frames - 1:
                self._automatic_rendering()
        self.enable_auto_render = False
        if self.config["traffic_respawn"]:
            keep = [v for v in self.road.vehicles if not (isinstance(v, TrafficVehicle) and (v.finished or v.crashed))]
            removed = len(self.road.vehicles) - len(keep)
            self.road.vehicles = keep
            for _ in range(removed):
                self._spawn_traffic(min_ego_distance=40.0)

    def _check_ego(self) -> None:
        ego, net, m = self.vehicle, self.net, self.net.hdmap
        lid = net.id_of.get(ego.lane_index)
        prev = self._ego_lane
        sl = net.stop_lines.get(lid)
        if sl is not None and (sl.kind == "stop" or self.config["right_turn_on_red"]) \
                and ego.speed <= STOPPED_SPEED_MPS and 0 <= sl.s - ego.lane_s <= STOP_ZONE_M:
            self._stopped.add(lid)
        if lid in m.lanes and m.lanes[lid].junction_id is None:  # stops and line crossings count until
            self._stopped &= {lid}                                 # the ego is on another road lane
            self._crossed &= {lid}
        if lid != prev and prev is not None and lid in m.lanes and m.lanes[lid].junction_id is not None \
                and prev not in self._crossed:  # flickering across the line is one crossing
            if m.lanes.get(prev) is not None and m.lanes[prev].junction_id is None:
                self._crossed.add(prev)
            psl = net.stop_lines.get(prev)
            if psl is not None and psl.kind == "signal" and self.control.signal_state(psl.control_id) == "red" \
                    and not (self.config["right_turn_on_red"] and prev in self._stopped and self._turn_after(prev) == "right"):
                self._violate("red_light")
            if psl is not None and psl.kind == "stop" and prev not in self._stopped:
                self._violate("stop_sign")
        self._ego_lane = lid
        # pedestrians: the ego on a crosswalk with a person next to its path
        for cw, s0, s1 in net.crossings.get(lid, ()):
            if s0 - 1.0 <= ego.lane_s <= s1 + 1.0 and ego.speed > 0.5 and (lid, cw) not in self._ped_flags:
                lane = net.lane_of[lid]
                for p in self.control.pedestrians.get(cw, ()):
                    sp, rp = lane.local_coordinates(p.position)
                    if abs(rp) < lane.width / 2 + PEDESTRIAN_IN_PATH_M and abs(sp - ego.lane_s) < ego.LENGTH:
                        self._ped_flags.add((lid, cw))
                        self._violate("pedestrian_yield")
                        break
        lane = net.get_lane(ego.lane_index)
        self.off_road = self.off_road or abs(ego.lane_lat) > lane.width / 2 + 1.5 or \
            ego.lane_s > lane.length + 3.0 and not m.lanes[lid].successors

    def _turn_after(self, lane_id: str) -> str | None:
        """The turn of the ego's route lane after `lane_id` (None when not on the route)."""
        route, pos = self.vehicle.lane_route, self.vehicle.route_pos
        # the latest occurrence at or before the ego (routes round a ring repeat lanes)
        k = next((i + 1 for i in range(min(pos, len(route) - 1), -1, -1) if route[i] == lane_id), len(route))
        return self.net.hdmap.lanes[route[k]].turn if k < len(route) else None

    def _violate(self, kind: str) -> None:
        self.violations[kind] += 1
        self.new_violations.append(kind)

    # ---- task ----------------------------------------------------------------------------
    def route_completed(self) -> bool:
        ego = self.vehicle
        if ego.route_pos < len(ego.lane_route) - 1:
            return False
        lane = self.net.lane_of[ego.lane_route[-1]]
        s, _ = lane.local_coordinates(ego.position)
        return s >= self._goal_s(lane)

    def _goal_s(self, lane) -> float:
        return min(float(self.config["goal_distance"]), lane.length - 1.0)

    def _rewards(self, action) -> dict[str, float]:
        done = self.vehicle.route_distance_done()
        delta = (done - self._progress) / max(self._route_len, 1e-6)
        self._progress = done
        return {"progress": float(delta), "arrived": float(self.route_completed()),
                "collision": float(self.vehicle.crashed), "off_road": float(self.off_road),
                **{v: float(self.new_violations.count(v)) for v in VIOLATIONS}}

    def _reward(self, action) -> float:
        r = self._last_rewards = self._rewards(action)
        c = self.config
        return float(c["reward_progress"] * r["progress"] + c["reward_arrived"] * r["arrived"]
                     + c["reward_collision"] * r["collision"] + c["reward_off_road"] * r["off_road"]
                     + sum(c[f"reward_{v}"] * r[v] for v in VIOLATIONS))

    def _is_terminated(self) -> bool:
        return bool(self.vehicle.crashed or self.route_completed()
                    or (self.config["offroad_terminal"] and self.off_road))

    def _is_truncated(self) -> bool:
        return bool(self.time >= self.config["duration"])

    def _info(self, obs, action=None) -> dict:
        ego, net, m = self.vehicle, self.net, self.net.hdmap
        jid, turn = self.junction_ahead()
        in_lane, j_lane, d = ego.next_junction_lane()
        sl = net.stop_lines.get(in_lane) if in_lane else None
        control = None if in_lane is None else (sl.kind if sl else "bare")
        sig_state = self.control.signal_state(sl.control_id) if sl is not None and sl.kind == "signal" else None
        plan = self.control.plans.get(sl.control_id) if sl is not None else None
        feature = m.junctions[jid].feature if jid in m.junctions else None
        return {
            "speed": float(ego.speed), "crashed": bool(ego.crashed), "action": action,
            "junction": jid, "junction_feature": feature.to_dict() if feature else None,
            "manoeuvre": turn, "control_ahead": control,
            "signal_id": sl.control_id if sig_state else None, "signal_state": sig_state,
            "signal_time_to_change": float(plan.time_to_change(sl.control_id, self.control.t)) if plan else None,
            "signal_states": self.control.signal_states(m.lanes[j_lane].junction_id) if j_lane else {},
            "distance_to_stop_line": float(d),
            "violations": dict(self.violations), "new_violations": list(self.new_violations),
            "collision": bool(ego.crashed), "off_road": bool(self.off_road),
            "route_progress": float(min(ego.route_distance_done() / max(self._route_len, 1e-6), 1.0)),
            "route_completed": bool(self.route_completed()),
            "lane_id": net.id_of.get(ego.lane_index), "time": float(self.time),
            "rewards": dict(getattr(self, "_last_rewards", {})),
        }

    # ---- scripted-driver API -----------------------------------------------------------------
    @property
    def route_lanes(self) -> list[str]:
        """The ego's route as map lane ids."""
        return list(self.vehicle.lane_route)

    def junction_ahead(self) -> tuple[str | None, str | None]:
        """(junction id, manoeuvre) of the junction the ego is in or will enter next."""
        ego, m = self.vehicle, self.net.hdmap
        for lid in ego.lane_route[ego.route_pos:]:
            ln = m.lanes[lid]
            if ln.junction_id is not None:
                return ln.junction_id, _TURN_NAMES.get(ln.turn, ln.turn)
        return None, None

    def rule_stop_distance(self, ignore: Sequence[str] = (), commit: bool = True) -> float:
        """Where the traffic rules make the ego stop (metres from its centre; inf if free).
        `ignore` may name "signal", "stop", "pedestrian", "conflict" to break those rules."""
        return self.control.stop_distance(self.vehicle, commit=commit, ignore=frozenset(ignore))

    def leader_gaps(self) -> list[tuple[float, float]]:
        """(bumper gap [m], speed [m/s]) of road users ahead on the ego's route."""
        return self.vehicle.leader_gaps()

    def traffic_control_vector(self) -> np.ndarray:
        ego = self.vehicle
        in_lane, _, d = ego.next_junction_lane()
        sl = self.net.stop_lines.get(in_lane) if in_lane else None
        state = self.control.signal_state(sl.control_id) if sl is not None and sl.kind == "signal" else None
        ped = self.control.stop_distance(ego, commit=False, ignore=frozenset({"signal", "stop", "conflict"}))
        return np.array([state == "green", state == "amber", state == "red",
                         sl is not None and sl.kind == "stop", min(d, 100.0) / 100.0, ped < math.inf],
                        dtype=np.float32)

    # ---- rendering ---------------------------------------------------------------------------
    def render(self):
        from .render import MapViewer

        if self.render_mode is None:
            return super().render()
        if self.viewer is None:
            self.viewer = MapViewer(self)
        return super().render()


def manoeuvres_to_lanes(net: MapNetwork, spec: Sequence[Sequence[str]]) -> list[str]:
    """Explicit route -> lane ids: per (junction, entry road, exit road) a junction lane, joined
    by Dijkstra; starts on the first entry road's lane, ends on the last exit road's lane."""
    m = net.hdmap
    picks = []
    for i, item in enumerate(spec):
        jid, entry, exit_ = (str(x) for x in item)
        cands = [ln for ln in m.lanes_by_junction.get(jid, [])
                 if any(m.lanes[p].road_id == entry for p in ln.predecessors if p in m.lanes)
                 and any(m.lanes[s].road_id == exit_ for s in ln.successors if s in m.lanes)]
        if not cands:
            raise Feat2MapError(f"no lane of junction {jid} leads from road {entry} to road {exit_}", f"route[{i}]")
        picks.append(sorted(cands, key=lambda ln: ln.id)[0])
    lanes = [next(p for p in picks[0].predecessors if m.lanes[p].road_id == str(spec[0][1])), picks[0].id]
    for i, ln in enumerate(picks[1:], 1):
        best: list[str] = []
        for pred in ln.predecessors:
            path = net.lane_route(lanes[-1], pred)
            if path and (not best or len(path) < len(best)):
                best = path
        if not best:
            raise Feat2MapError(f"junction {ln.junction_id} is not reachable from the previous manoeuvre", f"route[{i}]")
        lanes += best[1:] + [ln.id]
    lanes.append(next(s for s in picks[-1].successors if m.lanes[s].road_id == str(spec[-1][2])))
    return lanes


def lane_route_from_config(net: MapNetwork, spec: Mapping[str, Any]) -> list[str]:
    """Explicit lane-level route: {"lanes": [ids]} (each lane a successor of the one before), or
    {"from_lane": a, "to_lane": b} (shortest by Dijkstra; a == b goes once round a loop, e.g. a
    lap of a ring road). Errors name the config element."""
    m = net.hdmap
    keys = set(spec)
    if keys == {"lanes"}:
        raw = spec["lanes"]
        if isinstance(raw, (str, bytes)) or not isinstance(raw, Sequence) or len(raw) < 2:
            raise Feat2MapError("needs a list of at least 2 lane ids (the ego starts on the first and "
                                "finishes in the last)", "route.lanes")
        lanes = [str(x) for x in raw]
        for i, lid in enumerate(lanes):
            if lid not in m.lanes:
                raise Feat2MapError(f"unknown lane {lid!r}", f"route.lanes[{i}]")
            if i and lid not in m.lanes[lanes[i - 1]].successors:
                succ = ", ".join(m.lanes[lanes[i - 1]].successors) or "none"
                raise Feat2MapError(f"lane {lid} does not follow lane {lanes[i - 1]} (its successors: {succ})",
                                    f"route.lanes[{i}]")
        return lanes
    if keys == {"from_lane", "to_lane"}:
        a, b = str(spec["from_lane"]), str(spec["to_lane"])
        for key, lid in (("from_lane", a), ("to_lane", b)):
            if lid not in m.lanes:
                raise Feat2MapError(f"unknown lane {lid!r}", f"route.{key}")
        if a != b:
            path = net.lane_route(a, b)
        else:  # round a loop back to the start lane: the shortest cycle through it
            loops = [[a] + p for p in (net.lane_route(s, a) for s in m.lanes[a].successors if s in m.lanes) if p]
            path = min(loops, key=lambda p: sum(net.lane_of[x].length for x in p), default=[])
        if not path:
            raise Feat2MapError(f"lane {b} cannot be reached from lane {a} along lane successors", "route.to_lane")
        return path
    raise Feat2MapError(f"expected {{'lanes': [...]}} or {{'from_lane': ..., 'to_lane': ...}}, got keys "
                        f"{sorted(map(str, keys))}", "route")


def sample_lane_walk(net: MapNetwork, rng: np.random.Generator, length: float, start_distance: float = math.inf,
                     goal_distance: float = 0.0, tries: int = 100, max_lanes: int = 10_000) -> list[str]:
    """A random walk along lane successors from a road lane, long enough that an ego starting
    `start_distance` before the end of its first lane and finishing `goal_distance` into its
    last (as MapEnv places them) drives >= `length` metres; a closed ring simply loops. Maps
    without junctions are driven on such routes. When no walk is that long (dead ends), the
    longest walk found."""
    m = net.hdmap
    starts = sorted(ln.id for ln in m.lanes.values()
                    if ln.junction_id is None and any(s in m.lanes for s in ln.successors))
    if not starts:
        raise Feat2MapError("no road lane with a successor to start a route on", "map")
    best: list[str] = []
    best_len = -math.inf
    for _ in range(tries):
        path = [starts[int(rng.integers(len(starts)))]]
        ahead = min(start_distance, net.lane_of[path[0]].length)  # ego start -> end of the last lane but one
        while len(path) < max_lanes:
            succ = [s for s in m.lanes[path[-1]].successors if s in m.lanes]
            if not succ:
                break
            path.append(succ[int(rng.integers(len(succ)))])
            last = net.lane_of[path[-1]].length
            driven = ahead + min(goal_distance, last - 1.0)
            if driven >= length:
                return path
            if driven > best_len:
                best, best_len = list(path), driven
            ahead += last
    return best


def random_walk(net: MapNetwork, rng: np.random.Generator, start: str, junctions: int) -> list[str]:
    """A route from `start` through up to `junctions` junctions, choosing successors at random."""
    m = net.hdmap
    path = [start]
    count = 0
    while True:
        succ = [s for s in m.lanes[path[-1]].successors if s in m.lanes]
        if not succ or len(path) > 200:
            break
        nxt = succ[int(rng.integers(len(succ)))]
        entering = m.lanes[nxt].junction_id is not None and m.lanes[path[-1]].junction_id is None
        if entering:
            if count >= junctions:
                break
            count += 1
        path.append(nxt)
    return path


def sample_route(net: MapNetwork, rng: np.random.Generator, junctions: int) -> list[str]:
    """A random route that starts on a lane entering a junction and crosses >= 1 junction."""
    m = net.hdmap
    starts = [ln.id for ln in m.lanes.values() if ln.junction_id is None
              and any(m.lanes[s].junction_id is not None for s in ln.successors if s in m.lanes)]
    if not starts:
        return []
    start = starts[int(rng.integers(len(starts)))]
    path = random_walk(net, rng, start, max(1, junctions))
    if m.lanes[path[-1]].junction_id is not None or not any(m.lanes[l].junction_id for l in path):
        return []
    return path
