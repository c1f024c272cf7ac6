"""Gymnasium environments on feat2map maps, following highway-env's conventions.

`MapEnv` drives an ego along a route of junction manoeuvres (or an explicit lane route, or a
sampled lane walk on maps without junctions such as a closed ring road) through a map with
signals, stop signs, crosswalk pedestrians and IDM traffic. Subclasses only say where the map comes
from: `JunctionGridEnv` (generated from a feature space) and `MapFileEnv` (a file or an HDMap).

info keys (every step and reset; a new dict each time, each key of one type and shape in every
step and env, so that vector envs stack them: "", -1, inf or empty stand for "none"; never NaN,
which Gymnasium's determinism checks cannot compare):
  junction            id of the junction the ego is in, else the next one on its route ("")
  junction_feature    that junction's feature: {"n_roads" (-1 without one), "control", "crosswalk",
                      "rotation" (MAX_LEGS socket angles, inf padded), "lanes_in", "lanes_out" (-1 padded)}
  manoeuvre           the ego's turn there: "left" | "straight" | "right" | "uturn" ("")
  control_ahead       "signal" | "stop" | "bare" for the next stop line on the route ("" past the last)
  signal_id / signal_state / signal_time_to_change   the signal governing the ego's next stop line
                      ("" / "" / inf without one)
  distance_to_stop_line   metres along the route from the ego centre to the next stop line (the
                      junction entry where bare; inf if none)
  violations          counts {"red_light", "stop_sign", "pedestrian_yield"} so far this episode
  new_violations      violations committed during this step, e.g. ["red_light"]
  collision, off_road, route_progress (0..1), route_completed, lane_id, time, speed, crashed
  action              the action taken, as an array of the action space's dtype
  rewards             the reward terms of this step (zeros after reset)
  signal_states       {signal id: state} of the next junction's signals
"""
from __future__ import annotations

import math
import numbers
from collections import OrderedDict
from typing import Any, Mapping, Sequence

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.action import DiscreteMetaAction, action_factory

from ..config import SIGNAL_ALL_RED_S, SIGNAL_AMBER_S, SIGNAL_GREEN_S
from ..errors import Feat2MapError
from ..semantics import assert_sound
from .config import merge_config, validate_config
from .control import TrafficControl
from .network import MapNetwork, release_memory
from .observation import STOP_LINE_RANGE_M, TrafficControlObservation, make_observation
from .road import ArrayRoad, MapRoad
from .rules import SPAWN_BRAKE_MPS2, SPAWN_MARGIN_M, TURN_NAMES, VIOLATIONS, EgoJudge, braking_distance
from .vehicles import EgoMDPVehicle, EgoVehicle, TrafficVehicle

MAX_LEGS = 8  # info["junction_feature"] arrays have this many socket slots (inf / -1 beyond a junction's legs)
TRAFFIC_SPAWN_TRIES = 10
TRAFFIC_SPAWN_GAP_M = 12.0  # a traffic vehicle spawns this far from any other
TRAFFIC_LANE_END_M = 8.0  # ... and not within this of its lane's end
EGO_CLEARANCE_M, EGO_RESPAWN_CLEARANCE_M = 25.0, 40.0  # ... and this far from the ego (at reset, on respawn)
_NETWORK_CACHE: "OrderedDict[Any, MapNetwork]" = OrderedDict()
_CACHE_SIZE = 8


def cached_network(key: Any, build) -> MapNetwork:
    """Road networks are immutable during episodes: share them between resets and envs."""
    net = _NETWORK_CACHE.get(key)
    if net is None:
        net = MapNetwork.from_map(build())
        release_memory()
        _NETWORK_CACHE[key] = net
        while len(_NETWORK_CACHE) > _CACHE_SIZE:
            _NETWORK_CACHE.popitem(last=False)
    _NETWORK_CACHE.move_to_end(key)
    return net


class MapEnv(AbstractEnv):
    """Drive a route of junction manoeuvres on a feat2map map (see module docstring for info)."""

    metadata = {"render_modes": ["human", "rgb_array"], "autoreset_mode": AutoresetMode.NEXT_STEP}
    core_slot: tuple[Any, int] | None = None  # (shared TrafficCore, slot) of a sub-env of a batch (vector.py)

    def __init__(self, config: dict | None = None, render_mode: str | None = None) -> None:
        self.metadata = dict(type(self).metadata)  # highway-env writes render_fps into it: one per env
        super().__init__(config, render_mode)

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
            "traffic_core": "arrays",  # "arrays": all traffic in arrays (core.py); "objects": one object each
            "duration": 60.0,  # [s] truncation
            "route": None,  # [(junction id, entry road, exit road), ...], {"lanes": [...]},
            # {"from_lane": a, "to_lane": b}, or None to sample
            "route_junctions": 2,  # junctions on a sampled route (0: a lane walk of route_length)
            "route_length": 200.0,  # [m] driven on a sampled lane walk (maps without junctions)
            "ego_start_distance": 30.0,  # [m] before the end of the first lane (the first stop line)
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
        """Merge `config` into the current config; unknown keys and bad values are errors."""
        merged = merge_config(dict(self.config), config)
        validate_config(merged)
        self.config.clear()
        self.config.update(merged)
        if self.config["offscreen_rendering"] is None:
            self.config["offscreen_rendering"] = self.render_mode != "human"

    # ---- map -----------------------------------------------------------------------------
    def _network(self) -> MapNetwork:
        raise NotImplementedError

    def define_spaces(self) -> None:
        self.observation_type = make_observation(self, self.config["observation"])
        self.action_type = action_factory(self, self.config["action"])
        if self.config["observe_traffic_control"]:
            self.observation_type = TrafficControlObservation(self, self.observation_type)
        self.observation_space = self.observation_type.space()
        self.action_space = self.action_type.space()

    @property
    def rules(self) -> TrafficControl:
        """The traffic rules of this episode (`rules.TrafficRules`), for planners."""
        return self.control

    # ---- episode -------------------------------------------------------------------------
    def _reset(self) -> None:
        self.net = self._network()
        rng = self.np_random
        self.net.memo("semantics", lambda: assert_sound(self.net.hdmap))  # the map is safe to drive, once per map
        self.control = TrafficControl(self.net, rng, self.config)
        road = ArrayRoad if self.config["traffic_core"] == "arrays" else MapRoad
        slot = {"slot": self.core_slot} if self.core_slot is not None else {}
        self.road = road(self.net, self.control, rng, record_history=self.config["show_trajectories"], **slot)
        route, extend = self._ego_route()
        self._make_ego(route, extend)
        route = self.vehicle.lane_route
        route_junctions = {self.net.hdmap.lanes[l].junction_id for l in route} - {None}
        by_junction, order = self.net.memo("crosswalks", lambda: group_by(self.net.hdmap.crosswalks.values(),
                                                                          "junction_id"))
        self.control.active_crosswalks = sorted((c for j in route_junctions for c in by_junction.get(j, ())),
                                                key=order.__getitem__)  # in map order
        self._spawn_lanes = self._traffic_spawn_lanes(route, route_junctions)
        for _ in range(int(self.config["traffic_vehicles"])):
            self._spawn_traffic()
        self.control.update(self.road, 0.0)
        self.judge = EgoJudge(self.control, self.vehicle)
        self.violations = self.judge.violations
        self._progress = self.vehicle.route_distance_done()
        last = self.net.lane_of[route[-1]]
        self._route_len = self.vehicle.route_length() - last.length + self._goal_s(last)
        self._last_rewards = dict.fromkeys(self._reward_terms(), 0.0)

    def _ego_route(self) -> tuple[list[str], bool]:
        """The ego's lane route, and whether it may be extended over neighbouring road lanes (a
        route of junction manoeuvres, not a lane route given or walked lane by lane)."""
        spec = self.config["route"]
        if isinstance(spec, Mapping):
            return lane_route_from_config(self.net, spec), False
        if spec:
            return manoeuvres_to_lanes(self.net, spec), True
        if int(self.config["route_junctions"]) <= 0 or not self.net.hdmap.junctions:
            c = self.config
            return sample_lane_walk(self.net, self.np_random, float(c["route_length"]),
                                    float(c["ego_start_distance"]), float(c["goal_distance"])), False
        for _ in range(100):
            r = sample_route(self.net, self.np_random, int(self.config["route_junctions"]))
            if r:
                return r, True
        raise Feat2MapError("no route through a junction could be sampled", "map")

    def _make_ego(self, route: list[str], extend: bool) -> None:
        """The ego `ego_start_distance` before the end of its first lane (walking back over road
        lanes before a short first lane), at least its braking distance before the first stop
        line (slower where the road before the line is too short)."""
        c = self.config
        route, s0, speed = start_place(self.net, route, extend, float(c["ego_start_distance"]),
                                       float(c["goal_distance"]), float(c["ego_initial_speed"]), EgoVehicle.LENGTH)
        lane = self.net.lane_of[route[0]]
        pos, heading = lane.position(s0, 0.0), lane.heading_at(s0)
        if isinstance(self.action_type, DiscreteMetaAction):
            ego = EgoMDPVehicle(self.road, pos, heading, speed, target_speeds=self.action_type.target_speeds)
            ego.init_route(route)
            ego.speed_index = ego.speed_to_index(speed)
            ego.target_speed = ego.index_to_speed(ego.speed_index)
        else:
            ego = EgoVehicle(self.road, pos, heading, speed)
            ego.auto_steer = not getattr(self.action_type, "lateral", True)
            ego.init_route(route)
        ego.cache_projections = self.config["traffic_core"] == "arrays"
        self.road.vehicles.append(ego)
        self.control.passage_start(ego)  # the first on the road: it holds the passages it starts in
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
        return sorted({l for l in lanes if m.lanes[l].junction_id is None})  # no route starts in a junction

    def _spawn_traffic(self, min_ego_distance: float = EGO_CLEARANCE_M) -> TrafficVehicle | None:
        """A traffic vehicle on a random spawn lane and random walk, clear of other vehicles (and
        `min_ego_distance` from the controlled ones: the ego, or the agents of multi_agent), at
        least its braking distance before the first stop line of its route and not head-on with
        the holder of a narrow passage (None if no place)."""
        if not self._spawn_lanes:
            return None
        rng = self.np_random
        speed = float(self.config["traffic_initial_speed"])
        for _ in range(TRAFFIC_SPAWN_TRIES):
            lid = self._spawn_lanes[int(rng.integers(len(self._spawn_lanes)))]
            lane = self.net.lane_of[lid]
            s = float(rng.uniform(0.0, max(lane.length - TRAFFIC_LANE_END_M, 0.1)))
            pos = lane.position(s, 0.0)
            if any(np.hypot(*(pos - v.position)) < min_ego_distance for v in self.controlled_vehicles):
                continue
            if any(np.hypot(*(pos - v.position)) < TRAFFIC_SPAWN_GAP_M for v in self.road.vehicles):
                continue
            route = random_walk(self.net, rng, lid, 3)
            if first_line_distance(self.net, route, s) < braking_distance(speed, TrafficVehicle.LENGTH):
                continue
            v = self.road.spawn(lid, s, speed, route)
            if self.control.passage_start(v):
                return v
            self.road.vehicles.remove(v)  # head-on with a holder of a narrow passage
        return None

    # ---- stepping ------------------------------------------------------------------------
    def step(self, action):
        self._begin_step(action)
        self._simulate(action)
        return self._end_step(action)

    def _begin_step(self, action) -> None:
        """What `AbstractEnv.step` does before simulating (with the action checked)."""
        check_action(self.action_space, action)
        if self.road is None or self.vehicle is None:
            raise NotImplementedError("The road and vehicle must be initialized in the environment implementation")
        self.time += 1 / self.config["policy_frequency"]

    def _end_step(self, action):
        """What `AbstractEnv.step` does after simulating: (obs, reward, terminated, truncated, info)."""
        obs = self.observation_type.observe()
        reward = self._reward(action)
        terminated = self._is_terminated()
        truncated = self._is_truncated()
        info = self._info(obs, action)
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, info

    def _simulate(self, action=None) -> None:
        simulate([self], [action])

    def _respawn_traffic(self) -> None:
        """Traffic that finished its route or crashed leaves; as many new vehicles spawn."""
        if self.config["traffic_respawn"]:
            keep = [v for v in self.road.vehicles if not (isinstance(v, TrafficVehicle) and (v.finished or v.crashed))]
            removed = len(self.road.vehicles) - len(keep)
            self.road.vehicles = keep
            for _ in range(removed):
                self._spawn_traffic(min_ego_distance=EGO_RESPAWN_CLEARANCE_M)

    def _check_ego(self) -> None:
        """Judge the ego after a frame (`rules.EgoJudge`)."""
        self.judge.check()

    @property
    def new_violations(self) -> list[str]:
        return self.judge.new

    @property
    def off_road(self) -> bool:
        return self.judge.off_road

    # ---- task ----------------------------------------------------------------------------
    def route_completed(self) -> bool:
        ego = self.vehicle
        if ego.route_pos < len(ego.lane_route) - 1:
            return False
        lane = self.net.lane_of[ego.lane_route[-1]]
        return ego.s_on(ego.lane_route[-1]) >= self._goal_s(lane)

    def _goal_s(self, lane) -> float:
        return min(float(self.config["goal_distance"]), lane.length - 1.0)

    @staticmethod
    def _reward_terms() -> tuple[str, ...]:
        return ("progress", "arrived", "collision", "off_road", *VIOLATIONS)

    def _rewards(self, action) -> dict[str, float]:
        done = self.vehicle.route_distance_done()
        delta = (done - self._progress) / max(self._route_len, 1e-6)
        self._progress = done
        new = self.judge.new
        return {"progress": float(delta), "arrived": float(self.route_completed()),
                "collision": float(self.vehicle.crashed), "off_road": float(self.off_road),
                **({v: float(new.count(v)) for v in VIOLATIONS} if new else _NO_VIOLATIONS)}

    def _reward(self, action) -> float:
        r = self._last_rewards = self._rewards(action)
        c = self.config
        return float(sum(c[f"reward_{k}"] * r[k] for k in self._reward_terms()))

    def _is_terminated(self) -> bool:
        return bool(self.vehicle.crashed or self.route_completed()
                    or (self.config["offroad_terminal"] and self.off_road))

    def _is_truncated(self) -> bool:
        return bool(self.time >= self.config["duration"])

    def _info(self, obs, action=None) -> dict:
        """A new dict every step whose keys keep their types (no None: "", NaN, -1 or empty
        instead), so that vector envs can stack them (see the module docstring)."""
        ego, net, m, rules = self.vehicle, self.net, self.net.hdmap, self.control
        jid, turn = self.junction_ahead()
        sl, in_lane, j_lane, d = rules.line_ahead(ego)
        control = "" if in_lane is None else (sl.kind if sl else "bare")
        sig_state = rules.signal_state(sl.control_id) if sl is not None and sl.kind == "signal" else ""
        plan = rules.plans.get(sl.control_id) if sl is not None else None
        feature = m.junctions[jid].feature if jid in m.junctions else None
        return {
            "speed": float(ego.speed), "crashed": bool(ego.crashed), "action": action_array(self.action_space, action),
            "junction": jid or "", "junction_feature": feature_info(feature),
            "manoeuvre": turn or "", "control_ahead": control,
            "signal_id": sl.control_id if sig_state else "", "signal_state": sig_state,
            "signal_time_to_change": float(plan.time_to_change(sl.control_id, rules.t)) if plan else math.inf,
            "signal_states": rules.signal_states(m.lanes[j_lane].junction_id) if j_lane else {},
            "distance_to_stop_line": float(d),
            "violations": dict(self.violations), "new_violations": list(self.judge.new),
            "collision": bool(ego.crashed), "off_road": bool(self.off_road),
            "route_progress": float(min(ego.route_distance_done() / max(self._route_len, 1e-6), 1.0)),
            "route_completed": bool(self.route_completed()),
            "lane_id": net.id_of.get(ego.lane_index) or "", "time": float(self.time),
            "rewards": dict(self._last_rewards),
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
                return ln.junction_id, TURN_NAMES.get(ln.turn, ln.turn)
        return None, None

    def rule_stop_distance(self, ignore: Sequence[str] = (), commit: bool = True) -> float:
        """Where the traffic rules make the ego stop (metres from its centre; inf if free).
        `ignore` may name "signal", "stop", "pedestrian", "conflict" to break those rules."""
        return self.control.stop_distance(self.vehicle, commit=commit, ignore=frozenset(ignore))

    def leader_gaps(self) -> list[tuple[float, float]]:
        """(bumper gap [m], speed [m/s]) of road users ahead on the ego's route."""
        return self.vehicle.leader_gaps()

    def traffic_control_vector(self) -> np.ndarray:
        """observation.TRAFFIC_CONTROL_FEATURES of the ego's next stop line."""
        ego, rules = self.vehicle, self.control
        sl, _, _, d = rules.line_ahead(ego)
        state = rules.signal_state(sl.control_id) if sl is not None and sl.kind == "signal" else None
        ped = rules.stop_distance(ego, commit=False, ignore=frozenset({"signal", "stop", "conflict"}))
        return np.array([state == "green", state == "amber", state == "red",
                         sl is not None and sl.kind == "stop", min(d, STOP_LINE_RANGE_M) / STOP_LINE_RANGE_M,
                         ped < math.inf], dtype=np.float32)

    # ---- rendering ---------------------------------------------------------------------------
    def render(self):
        from .render import MapViewer

        if self.render_mode is None:
            return super().render()
        if self.viewer is None:
            self.viewer = MapViewer(self)
        return super().render()


def simulate(envs: Sequence[MapEnv], actions: Sequence[Any]) -> None:
    """One policy step of `envs` (one env, or the sub-envs of a batch, all of one config) with
    their actions, frame by frame together: on the arrays core the traffic of all roads that
    share a core moves in one call per frame (`TrafficCore.act` / `step`); on the object core
    each road steps its own."""
    if not envs:
        return
    c = envs[0].config
    frames = int(c["simulation_frequency"] // c["policy_frequency"])
    dt = 1 / c["simulation_frequency"]
    groups: dict[int, tuple[Any, list]] = {}  # roads by their core (one group: one batch)
    for env in envs:
        core = getattr(env.road, "core", None)
        groups.setdefault(id(core) if core is not None else id(env.road), (core, []))[1].append(env.road)
    for env in envs:
        env.judge.new = []
    for frame in range(frames):
        for env, action in zip(envs, actions):
            if action is not None and not env.config["manual_control"] and env.steps % frames == 0:
                env.action_type.act(action)
        for core, roads in groups.values():
            if core is not None:
                core.act(roads)
                core.step(roads, dt)
            else:
                roads[0].act()
                roads[0].step(dt)
        for env in envs:
            env.steps += 1
            env.judge.check()
            if frame < frames - 1:
                env._automatic_rendering()
    for env in envs:
        env.enable_auto_render = False
        env._respawn_traffic()


def group_by(items, attribute: str) -> tuple[dict[Any, list[str]], dict[str, int]]:
    """({value: ids of the items whose `attribute` has it}, {id: the item's place}), in order."""
    groups: dict[Any, list[str]] = {}
    order: dict[str, int] = {}
    for k, x in enumerate(items):
        groups.setdefault(getattr(x, attribute), []).append(x.id)
        order[x.id] = k
    return groups, order


def check_action(space: spaces.Space, action: Any) -> None:
    """An action of the right kind, shape and value for `space`, else a Feat2MapError naming it."""
    if type(action) is int and type(space) is spaces.Discrete and 0 <= action - int(space.start) < space.n:
        return  # the common case first (one check per agent per step in the multi-agent env)
    if isinstance(space, spaces.Discrete):
        value = action.item() if isinstance(action, np.ndarray) and action.shape in ((), (1,)) else action
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Integral, np.integer)):
            raise Feat2MapError(f"must be an integer in [0, {space.n}), got {type(action).__name__} {action!r:.40}",
                                "action")
        if not 0 <= int(value) - int(space.start) < space.n:
            raise Feat2MapError(f"must be in [{space.start}, {space.start + space.n}), got {value}", "action")
        return
    if isinstance(space, spaces.Box):
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise Feat2MapError(f"must be an array of shape {space.shape}, got {type(action).__name__}", "action") from None
        if action is None or a.shape != space.shape:
            raise Feat2MapError(f"must be an array of shape {space.shape}, got {type(action).__name__} of shape "
                                f"{getattr(a, 'shape', None)}", "action")
        if not np.all(np.isfinite(a)):
            raise Feat2MapError(f"must be finite, got {a.tolist()}", "action")


def action_array(space: spaces.Space, action: Any) -> np.ndarray:
    """A copy of the action in the action space's dtype (a 0-d array for discrete actions)."""
    return np.array(action, dtype=space.dtype if space.dtype is not None else None, copy=True)


def feature_info(feature) -> dict[str, Any]:
    """A junction feature as a dict of fixed keys, types and shapes (n_roads -1 without one);
    new arrays each call (from one conversion per feature)."""
    held = _FEATURE_INFO.get(id(feature))
    if held is None or held[0] is not feature:
        if len(_FEATURE_INFO) > 4096:
            _FEATURE_INFO.clear()
        info = _feature_info(feature)
        held = _FEATURE_INFO[id(feature)] = (feature, info, [k for k, v in info.items() if isinstance(v, np.ndarray)])
    out = dict(held[1])
    for k in held[2]:
        out[k] = out[k].copy()
    return out


_NO_VIOLATIONS = dict.fromkeys(VIOLATIONS, 0.0)  # the violation reward terms of a step without one
# id -> (feature, its info, the keys of its arrays): features are frozen
_FEATURE_INFO: dict[int, tuple[Any, dict[str, Any], list[str]]] = {}


def _feature_info(feature) -> dict[str, Any]:
    rot = np.full(MAX_LEGS, np.inf)
    lanes_in = np.full(MAX_LEGS, -1, dtype=np.int64)
    lanes_out = np.full(MAX_LEGS, -1, dtype=np.int64)
    if feature is None:
        return {"n_roads": -1, "control": "", "crosswalk": False, "rotation": rot, "lanes_in": lanes_in,
                "lanes_out": lanes_out}
    d = feature.to_dict()
    for arr, key in ((rot, "rotation"), (lanes_in, "lanes_in"), (lanes_out, "lanes_out")):
        vals = list(d.get(key) or [])[:MAX_LEGS]
        arr[:len(vals)] = vals
    return {"n_roads": int(d["n_roads"]), "control": str(d["control"]), "crosswalk": bool(d["crosswalk"]),
            "rotation": rot, "lanes_in": lanes_in, "lanes_out": lanes_out}


def extend_route(net: MapNetwork, route: list[str], start_distance: float, goal_distance: float,
                 min_room: float = 0.0) -> list[str]:
    """A manoeuvre route extended over road lanes (never into a junction) where its ends are
    short: predecessors before the first lane until `start_distance` fits before the first
    lane's end, successors after the last until the goal `goal_distance` into it fits. Where
    the road before the first junction is shorter than `min_room` (netconvert's 0.2 m approach
    lanes right after another junction: a car started there stands across the stop line), the
    route starts before that other junction instead, through one of its junction lanes (straight
    on where one is, never a U-turn)."""
    m = net.hdmap
    route = list(route)
    room = net.lane_of[route[0]].length
    while room < start_distance:
        prev = road_neighbour(m, route[0], m.lanes[route[0]].predecessors, set(route))
        if prev is None and room < min_room and len(route) > 1:
            through = sorted((j for j in m.lanes[route[0]].predecessors if j in m.lanes and j not in route
                              and m.lanes[j].junction_id is not None and m.lanes[j].turn != "uturn"),
                             key=lambda j: (m.lanes[j].turn != "none", j))  # straight on, never a U-turn
            before = road_neighbour(m, through[0], m.lanes[through[0]].predecessors, set(route)) if through else None
            if before is not None:
                route[:0] = [before, through[0]]
                room = net.lane_of[before].length
                continue
        if prev is None:
            break
        route.insert(0, prev)
        room += net.lane_of[prev].length
    while net.lane_of[route[-1]].length < goal_distance + 1.0:
        nxt = road_neighbour(m, route[-1], m.lanes[route[-1]].successors, set(route))
        if nxt is None:
            break
        route.append(nxt)
    return route


def start_place(net: MapNetwork, route: list[str], extend: bool, start_distance: float, goal_distance: float,
                speed: float, length: float) -> tuple[list[str], float, float]:
    """(route, s on its first lane, speed) of a vehicle starting `start_distance` before the end
    of its route's first lane (a manoeuvre route, `extend`: walking back over the road lanes
    before a short first lane, the route extended at both ends), at most at the speed whose
    braking distance fits before the first stop line. The ego's start (MapEnv) and the agents'
    (multi_agent) both come from here."""
    if extend:
        route = extend_route(net, route, start_distance, goal_distance, length / 2)
    s0 = max(0.0, route_start_s(net, route, start_distance) if extend else net.lane_of[route[0]].length - start_distance)
    d_line = first_line_distance(net, route, s0)
    if d_line < braking_distance(speed, length):
        speed = fitting_speed(d_line, length)
    return route, s0, speed


def road_neighbour(m, lane_id: str, candidates: Sequence[str], exclude: set[str]) -> str | None:
    """The road lane (not in a junction, not in `exclude`) among `candidates` to extend a route
    with: one of the same road first, then the longest, ties by id."""
    road = m.lanes[lane_id].road_id
    cands = [c for c in candidates if c in m.lanes and m.lanes[c].junction_id is None and c not in exclude]
    if not cands:
        return None
    return min(cands, key=lambda c: (m.lanes[c].road_id != road, -m.lanes[c].length, c))


def route_start_s(net: MapNetwork, route: list[str], start_distance: float) -> float:
    """s on the route's first lane of the point `start_distance` before the end of the first
    lane that is not an extension (the approach): with lanes prepended, it walks back over them."""
    m = net.hdmap
    first_junction = next((k for k, l in enumerate(route) if m.lanes[l].junction_id is not None), len(route))
    k = max(first_junction - 1, 0)
    remaining = start_distance
    while k > 0 and remaining > net.lane_of[route[k]].length:
        remaining -= net.lane_of[route[k]].length
        k -= 1
    if k > 0:  # the start falls on a later lane: drop the lanes before it
        del route[:k]
    return net.lane_of[route[0]].length - remaining


def first_line_distance(net: MapNetwork, route: Sequence[str], s0: float) -> float:
    """Distance along `route` from s0 on its first lane to the first junction entry's stop line
    (the entry itself when bare; inf without a junction)."""
    m = net.hdmap
    d = -s0
    for k, lid in enumerate(route):
        if k and m.lanes[lid].junction_id is not None and m.lanes[route[k - 1]].junction_id is None:
            sl = net.stop_lines.get(route[k - 1])
            return d - (net.lane_of[route[k - 1]].length - sl.s if sl is not None else 0.0)
        d += net.lane_of[lid].length
    return math.inf


def fitting_speed(distance: float, length: float) -> float:
    """The highest speed whose braking distance fits in `distance` (0 when none does)."""
    room = distance - length / 2 - SPAWN_MARGIN_M
    return math.sqrt(2 * SPAWN_BRAKE_MPS2 * room) if room > 0 else 0.0


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
    starts = net.memo("route starts", lambda: [
        ln.id for ln in m.lanes.values() if ln.junction_id is None
        and any(m.lanes[s].junction_id is not None for s in ln.successors if s in m.lanes)])
    if not starts:
        return []
    start = starts[int(rng.integers(len(starts)))]
    path = random_walk(net, rng, start, max(1, junctions))
    if m.lanes[path[-1]].junction_id is not None or not any(m.lanes[l].junction_id for l in path):
        return []
    return path
