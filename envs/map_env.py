"""Gymnasium environments on feat2map maps, following highway-env's conventions.

`MapEnv` drives an ego along a route of junction manoeuvres (or an explicit lane route, or a
sampled lane walk on maps without junctions such as a closed ring road) through a map with
signals, stop signs, crosswalk pedestrians and IDM traffic. Subclasses only say where the map comes
from: `JunctionGridEnv` (generated from a feature space) and `MapFileEnv` (a file or an HDMap).

Config keys: `config.SETTINGS` (key, default, check, doc); info keys: `info.INFO_KEYS` (key,
type, doc): envs/README.md's tables are made from them.
"""
from __future__ import annotations

import functools
import math
import numbers
import operator
from collections import OrderedDict
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.action import DiscreteMetaAction, action_factory

from ..config import (EGO_CLEARANCE_M, EGO_RESPAWN_CLEARANCE_M, MAX_LEGS, STOP_LINE_RANGE_M, TRAFFIC_LANE_END_M,
                      TRAFFIC_SPAWN_GAP_M, TRAFFIC_SPAWN_TRIES)
from ..errors import Feat2MapError
from ..semantics import assert_sound
from . import info_columns, task
from .config import MAP_ENV, checked_copy, defaults, merge_config, validate_config
from .control import TrafficControl
from .controlled import ControlledRow, MetaRow
from .network import MapNetwork, StopLine, release_memory
from .observation import TrafficControlObservation, make_observation
from .road import MapRoad
from .routes import ego_route, first_line_distance, random_walk, start_place, traffic_traps
from .rules import EgoJudge, TrafficRules, braking_distance
from .sim.vehicle import VehicleModel
from .task import REWARD_TERMS
from .vehicles import TrafficVehicle

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


class EgoTask:
    """The ego's task over explicit pieces: route completion, reward terms, infos and the
    scripted-driver API (what planners, `ScriptedDriver` and `DriverView` ask an env), read from
    `vehicle`, `net`, `control`, `config`, `judge`, `time` and the progress fields below. MapEnv
    is one; each agent of the multi-agent env is another (`multi_agent.AgentView`, over the
    shared world)."""

    vehicle: Any
    road: Any
    net: MapNetwork
    control: TrafficControl
    config: dict
    judge: EgoJudge
    time: float
    action_space: spaces.Space
    _last_rewards: dict[str, float]

    @property
    def rules(self) -> TrafficRules:
        """The rules' questions (`rules.TrafficRules`: pure queries), answered from this episode's
        signals, queues and reservations, for planners; what the ego takes is `claim`'s."""
        return self.control

    @property
    def violations(self) -> dict[str, int]:
        """{kind: count} of the episode's violations (the judge's)."""
        return self.judge.violations

    @property
    def new_violations(self) -> list[str]:
        return self.judge.new

    @property
    def off_road(self) -> bool:
        return self.judge.off_road

    # ---- task ----------------------------------------------------------------------------
    def route_completed(self) -> bool:
        """Whether the ego has reached its goal (`task.completed`, a batch of one)."""
        return bool(task.completed(self.road.core, self.vehicle.row))

    def start_task(self) -> None:
        """The ego's task starts where it stands (`task.start`): its progress, its goal."""
        task.start(self.road.core, self.vehicle.row, self.config["goal_distance"])

    def goal_s(self, lane) -> float:
        """The goal on the route's last lane (`task.goal_s`)."""
        return task.goal_s(self.net, lane, self.config["goal_distance"])

    @staticmethod
    def _reward_terms() -> tuple[str, ...]:
        return REWARD_TERMS

    def _rewards(self, action) -> dict[str, float]:
        # the ego's own terms, by name (an agent's view adds its judge's two: multi_agent.py)
        return dict(zip(REWARD_TERMS, EgoTask._reward_row(self, self.vehicle.route_distance_done(),
                                                          self.route_completed())))

    def _reward_row(self, done: float, completed: bool) -> tuple[float, ...]:
        """This step's reward terms (`_reward_terms` order) given the route metres `done` and
        whether the route is completed (`task.reward_terms`, a batch of one)."""
        return tuple(task.reward_terms(self.road.core, self.vehicle.row, done, completed, self.off_road).tolist())

    def _info(self, obs, action=None) -> dict:
        """A new dict every step whose keys keep their types (no None: "", NaN, -1 or empty
        instead), so that vector envs can stack them: `info.INFO_KEYS`; its values are the ego's
        row's (`info_columns.columns`, a batch of one)."""
        return info_dict(info_columns.columns(self.road.core, self.vehicle.row, [self], [action]), self.action_space)

    # ---- scripted-driver API -----------------------------------------------------------------
    @property
    def route_lanes(self) -> list[str]:
        """The ego's route as map lane ids."""
        return list(self.vehicle.lane_route)

    def next_stop_line(self) -> tuple[StopLine | None, str | None, str | None, float]:
        """(stop line, incoming lane, junction lane, distance) of the ego's next junction entry
        (`rules.line_ahead`, no range)."""
        return self.control.line_ahead(self.vehicle)

    def junction_ahead(self) -> tuple[str | None, str | None]:
        """(junction id, manoeuvre) of the junction the ego is in or will enter next ((None, None)
        without one): its row's route fact (`info_columns.RouteFacts`, what its info gives)."""
        core = self.road.core
        jid, turn = core.route_facts.facts[info_columns.facts_of(core, self.vehicle.row)][:2]
        return jid or None, turn or None

    def rule_stop_distance(self, ignore: Sequence[str] = ()) -> float:
        """Where the traffic rules make the ego stop (metres from its centre; inf if free), a pure
        question. `ignore` may name "signal", "stop", "pedestrian", "conflict" to break those rules."""
        return self.control.stop_distance(self.vehicle, ignore=frozenset(ignore))

    # ---- the ego's claims: what its driver means to do at junctions and narrow passages ------
    def claim(self, ignore: Sequence[str] = ()) -> float:
        """The ego goes where the rules (less `ignore`) let it: it takes its place at the narrow
        passages ahead and reserves its junction lanes within commit distance of their line, as a
        traffic car in its place would (`control.TrafficControl.claim`, the same update);
        returns `rule_stop_distance`'s answer as the claim finds it."""
        return self.control.claim(self.vehicle, ignore=frozenset(ignore))

    def claim_passages(self) -> float:
        """The ego takes its place at the narrow passages ahead (first come first served) without
        claiming junction lanes; returns where it waits for them (inf: free)."""
        return self.control.claim_passages(self.vehicle)

    def give_up(self, junction_lane: str) -> None:
        """The ego will not enter `junction_lane` now: it gives up its reservation of the lane and
        of the lanes chained after it, so that the traffic it waits for can go."""
        self.control.release(self.vehicle, junction_lane)

    def leader_gaps(self) -> list[tuple[float, float]]:
        """(bumper gap [m], speed [m/s]) of road users ahead on the ego's route."""
        return self.vehicle.leader_gaps()

    def traffic_control_vector(self) -> np.ndarray:
        """observation.TRAFFIC_CONTROL_FEATURES of the ego's next stop line (a mid-block
        crossing's light's included)."""
        ego, rules = self.vehicle, self.control
        sl, _, _, d = rules.line_ahead(ego)
        state = rules.signal_state(sl.control_id) if sl is not None and sl.kind == "signal" else None
        mid = rules.midblock_ahead(ego, d)
        if mid is not None:
            sl, state, d = None, rules.signal_state(mid[0]), mid[1]
        ped = rules.stop_distance(ego, ignore=frozenset({"signal", "stop", "conflict"}))
        return np.array([state == "green", state == "amber", state == "red",
                         sl is not None and sl.kind == "stop", min(d, STOP_LINE_RANGE_M) / STOP_LINE_RANGE_M,
                         ped < math.inf], dtype=np.float32)


class MapEnv(EgoTask, AbstractEnv):
    """Drive a route of junction manoeuvres on a feat2map map (info keys: `info.INFO_KEYS`)."""

    metadata = {"render_modes": ["human", "rgb_array"], "autoreset_mode": AutoresetMode.NEXT_STEP}
    core_slot: tuple[Any, int] | None = None  # (shared TrafficCore, slot) of a sub-env of a batch (vector.py)
    shared_net: MapNetwork | None = None  # the batch's map, which every episode of a sub-env drives (`share`)
    _checked: dict | None = None  # the config as last checked (`configure` checks the values changed since)

    def __init__(self, config: dict | None = None, render_mode: str | None = None) -> None:
        self.metadata = dict(type(self).metadata)  # highway-env writes render_fps into it: one per env
        super().__init__(config, render_mode)

    @classmethod
    def default_config(cls) -> dict:
        """highway-env's keys (less `other_vehicles_type`) and MapEnv's: `config.SETTINGS`."""
        config = super().default_config()
        config.pop("other_vehicles_type", None)  # it names highway-env's traffic class; the traffic here is the env's
        config.update(defaults(MAP_ENV))
        return config

    def configure(self, config: dict) -> None:
        """Merge `config` into the current config; unknown keys and bad values are errors."""
        merged = merge_config(dict(self.config), config)
        validate_config(merged, self._checked)
        self.config.clear()
        self.config.update(merged)
        if self.config["offscreen_rendering"] is None:
            self.config["offscreen_rendering"] = self.render_mode != "human"
        self._checked = checked_copy(self.config)

    # ---- map -----------------------------------------------------------------------------
    def _network(self) -> MapNetwork:
        raise NotImplementedError

    def share(self, core: Any, slot: int, net: MapNetwork) -> None:
        """Make this env slot `slot` of `core` (a `TrafficCore` of several envs: a batch's
        sub-envs, the multi-agent env's worlds) driving `net`, the map of them all, from its next
        reset on."""
        self.core_slot, self.shared_net = (core, slot), net

    def network(self) -> MapNetwork:
        """The map of the next episode: the shared one (`share`), else the env's own (`_network`)."""
        return self.shared_net if self.shared_net is not None else self._network()

    def define_spaces(self) -> None:
        self.observation_type = make_observation(self, self.config["observation"])
        self.action_type = action_factory(self, self.config["action"])
        if self.config["observe_traffic_control"]:
            self.observation_type = TrafficControlObservation(self, self.observation_type)
        self.observation_space = self.observation_type.space()
        self.action_space = self.action_type.space()

    # ---- episode -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """highway-env's reset, with `options` checked first (`check_options`); the info's action
        is the no-op (`noop_action`: no action was taken), not highway-env's unseeded sample."""
        check_options(options)
        obs, info = super().reset(seed=seed, options=options)
        info["action"] = action_array(self.action_space, noop_action(self.action_type, self.action_space))
        return obs, info

    def _reset(self) -> None:
        self.net = self.network()
        rng = self.np_random
        self.net.memo("semantics", lambda: assert_sound(self.net.hdmap))  # the map is safe to drive, once per map
        self.control = TrafficControl(self.net, rng, self.config)
        slot = {"slot": self.core_slot} if self.core_slot is not None else {}
        self.road = MapRoad(self.net, self.control, rng, record_history=self.config["show_trajectories"], **slot)
        route, extend = self._ego_route()
        self._make_ego(route, extend)
        route = self.vehicle.lane_route
        route_junctions = {j for l in route if (j := self.net.hdmap.lanes[l].junction_id) is not None}
        by_junction, order = self.net.memo("crosswalks", lambda: group_by(self.net.hdmap.crosswalks.values(),
                                                                          "junction_id"))
        # the crosswalks of the route's junctions and the mid-block ones its road lanes cross, in map order
        crossed = {c for lid in route for c, _, _ in self.net.crossings.get(lid, ()) if c in by_junction.get(None, ())}
        self.control.active_crosswalks = sorted({c for j in route_junctions for c in by_junction.get(j, ())} | crossed,
                                                key=order.__getitem__)
        self._spawn_lanes = self._traffic_spawn_lanes(route, route_junctions)
        for _ in range(int(self.config["traffic_vehicles"])):
            self._spawn_traffic()
        self.control.update(self.road, 0.0)
        self.judge = EgoJudge(self.control, self.vehicle, arrives=True)
        self.start_task()
        self._last_rewards = dict.fromkeys(self._reward_terms(), 0.0)

    def _ego_route(self) -> tuple[list[str], bool]:
        """The ego's lane route, and whether it may be extended (`routes.ego_route`)."""
        return ego_route(self.net, self.np_random, self.config)

    def _make_ego(self, route: list[str], extend: bool) -> None:
        """The ego `ego_start_distance` before the end of its first lane (walking back over road
        lanes before a short first lane), at least its braking distance before the first stop
        line (slower where the road before the line is too short)."""
        c = self.config
        model = VehicleModel.of(c["vehicle"])
        route, s0, speed = start_place(self.net, route, extend, float(c["ego_start_distance"]),
                                       float(c["goal_distance"]), float(c["ego_initial_speed"]), model.length)
        meta = isinstance(self.action_type, DiscreteMetaAction)
        ego = self.road.core.add_traffic(self.road, route[0], s0, speed, route, model=model,
                                         view=MetaRow if meta else ControlledRow)
        if meta:
            ego.target_speeds = self.action_type.target_speeds
            ego.speed_index = ego.speed_to_index(speed)
            ego.target_speed = ego.index_to_speed(ego.speed_index)
        else:
            ego.auto_steer = not getattr(self.action_type, "lateral", True)
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
        trapped = traffic_traps(self.net)  # no route starts in a junction, nor where it cannot leave
        return sorted({l for l in lanes if m.lanes[l].junction_id is None and l not in trapped})

    def _spawn_traffic(self, min_ego_distance: float = EGO_CLEARANCE_M) -> TrafficVehicle | None:
        """A traffic vehicle on a random spawn lane and random walk, clear of other vehicles (and
        `min_ego_distance` from the controlled ones: the ego, or the agents of multi_agent), at
        least its braking distance before the first stop line of its route and not head-on with
        the holder of a narrow passage (None if no place)."""
        if not self._spawn_lanes:
            return None
        rng = self.np_random
        speed = float(self.config["traffic_initial_speed"])
        controlled, others = (np.array([v.position for v in vs], dtype=float).reshape(-1, 2)
                              for vs in (self.controlled_vehicles, self.road.vehicles))
        for _ in range(TRAFFIC_SPAWN_TRIES):
            lid = self._spawn_lanes[int(rng.integers(len(self._spawn_lanes)))]
            lane = self.net.lane_of[lid]
            s = float(rng.uniform(0.0, max(lane.length - TRAFFIC_LANE_END_M, 0.1)))
            pos = lane.position(s, 0.0)
            if too_near(pos, controlled, min_ego_distance) or too_near(pos, others, TRAFFIC_SPAWN_GAP_M):
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
        self.begin_step(action)
        self._simulate(action)
        return self.end_step(action)

    def begin_step(self, action, checked: bool = False) -> None:
        """What `AbstractEnv.step` does before simulating, with the action checked (unless
        `checked`: a batch checks every action first)."""
        if not checked:
            check_action(self.action_space, action)
        if self.road is None or self.vehicle is None:
            raise NotImplementedError("The road and vehicle must be initialized in the environment implementation")
        self.time += 1 / self.config["policy_frequency"]

    def end_step(self, action, obs=None):
        """What `AbstractEnv.step` does after simulating: (obs, reward, terminated, truncated, info);
        `obs` when already made (a batch observes all its sub-envs at once, envs/vector.py)."""
        obs = self.observation_type.observe() if obs is None else obs
        if self.keeps_step_hooks():  # the task's arrays, a batch of one
            rewards, ended, cut, values = step_ends([self], [action])
            reward, terminated, truncated = float(rewards[0]), bool(ended[0]), bool(cut[0])
            info = info_dict(values, self.action_space)
        else:
            reward = self._reward(action)
            terminated = self._is_terminated()
            truncated = self._is_truncated()
            info = self._info(obs, action)
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, info

    def keeps_step_hooks(self) -> bool:
        """Whether this env's class keeps MapEnv's reward, termination and info hooks, so that its
        step's end is `step_ends`' (with the other sub-envs of a batch: `vector.MapVectorEnv.end_steps`)."""
        return keeps_hooks(type(self))

    def _simulate(self, action=None) -> None:
        simulate([self], [action])

    def respawn_traffic(self) -> None:
        """Traffic that finished its route or crashed leaves (never a controlled vehicle: the ego,
        the multi-agent env's agents); as many new vehicles spawn. A frame asks it only of the
        envs whose slot may hold such traffic (`TrafficCore.may_leave`)."""
        if self.config["traffic_respawn"]:
            keep = [v for v in self.road.vehicles if isinstance(v, ControlledRow)
                    or not (isinstance(v, TrafficVehicle) and (v.finished or v.crashed))]
            removed = len(self.road.vehicles) - len(keep)
            self.road.vehicles = keep
            for _ in range(removed):
                self._spawn_traffic(min_ego_distance=EGO_RESPAWN_CLEARANCE_M)

    def _reward_weights(self) -> tuple[float, ...]:
        """The config's weights of `_reward_terms`, in their order."""
        return tuple(map(self.config.__getitem__, weight_keys(self._reward_terms())))

    def _reward(self, action) -> float:
        r = self._last_rewards = self._rewards(action)
        terms = np.array([[r[k] for k in self._reward_terms()]])
        return float(task.weighted(terms, [self._reward_weights()])[0])

    def _is_terminated(self, completed: bool | None = None) -> bool:
        return bool(task.ended(self.vehicle.crashed, self.route_completed() if completed is None else completed,
                               self.off_road, bool(self.config["offroad_terminal"])))

    def _is_truncated(self) -> bool:
        return bool(self.time >= self.config["duration"])

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
    their actions, frame by frame together: the traffic of all roads that share a core moves in
    one call per frame (`TrafficCore.act` / `step`)."""
    if not envs:
        return
    c = envs[0].config
    frames = int(c["simulation_frequency"] // c["policy_frequency"])
    dt = 1 / c["simulation_frequency"]
    groups: dict[int, tuple[Any, list, list, list]] = {}  # roads, envs, egos' rows by their core (one group: one batch)
    acting: list[list[tuple[MapEnv, Any]]] = [[] for _ in range(frames)]  # who decides on each frame
    tracked, viewed = [], []  # egos following an external planner's trajectory; envs with a viewer
    for env, action in zip(envs, actions):  # (one pass over the envs)
        road, ego = env.road, env.vehicle
        group = groups.get(id(road.core))
        if group is None:
            group = groups[id(road.core)] = (road.core, [], [], [])
        group[1].append(road)
        group[2].append(env)
        group[3].append(ego.row)
        if action is not None and not env.config["manual_control"]:
            if isinstance(env.action_space, spaces.Discrete):
                action = discrete_index(action)  # (highway-env's action types take int() of it)
            acting[-env.steps % frames].append((env, action))
        if ego.tracker is not None:
            tracked.append(ego)
        if env.viewer is not None:
            viewed.append(env)
    egos: dict[int, tuple[int, np.ndarray]] = {}  # per core, (its `layout`, the members' egos' rows then)
    for core, _, _, ego_rows in groups.values():
        egos[id(core)] = (core.layout, np.array(ego_rows, dtype=np.int64))
        core.new_violations[egos[id(core)][1]] = 0  # (this step's violations)
    for frame in range(frames):
        for env, action in acting[frame]:
            env.action_type.act(action)
        for ego in tracked:  # (commands every frame)
            ego.track()
        for core, roads, _, _ in groups.values():
            core.act(roads)
            core.step(roads, dt)
        for core, _, members, _ in groups.values():
            if egos[id(core)][0] != core.layout:  # (rows came or went)
                egos[id(core)] = (core.layout, np.array([env.vehicle.row for env in members], dtype=np.int64))
            rows = egos[id(core)][1]
            core.judge(rows[core.judge_due(rows)])
        if frame < frames - 1:
            for env in viewed:
                env._automatic_rendering()
    for env in envs:
        env.steps += frames
    for env in viewed:
        env.enable_auto_render = False
    for core, roads, members, _ in groups.values():  # respawns where traffic may have left (`TrafficCore.may_leave`)
        maybe = core.may_leave()[[road.slot for road in roads]]
        for k in maybe.nonzero()[0].tolist():
            members[k].respawn_traffic()
        core.sync(roads)  # the respawns taken in (of every sub-env at once): what observations read


def too_near(pos: np.ndarray, places: np.ndarray, gap: float) -> bool:
    """Whether any of `places` ([k, 2]) lies within `gap` of `pos`."""
    d = pos - places
    return bool((np.hypot(d[:, 0], d[:, 1]) < gap).any())


def group_by(items, attribute: str) -> tuple[dict[Any, list[str]], dict[str, int]]:
    """({value: ids of the items whose `attribute` has it}, {id: the item's place}), in order."""
    groups: dict[Any, list[str]] = {}
    order: dict[str, int] = {}
    for k, x in enumerate(items):
        groups.setdefault(getattr(x, attribute), []).append(x.id)
        order[x.id] = k
    return groups, order


def check_options(options: Any) -> None:
    """Reset options as Gymnasium passes them: None or a dict whose "config", when given, is a
    mapping; else a Feat2MapError saying what was expected (not an AttributeError later)."""
    if options is None:
        return
    if not isinstance(options, Mapping):
        raise Feat2MapError(f"must be a dict (such as {{'config': {{...}}}}) or None, got {type(options).__name__}",
                            "options")
    if "config" in options and not isinstance(options["config"], Mapping):
        raise Feat2MapError(f"must be a dict of config keys, got {type(options['config']).__name__}", "options.config")


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


def discrete_index(action: Any) -> int:
    """A checked discrete action (an int, or an array or numpy integer of one value) as an int
    (`check_action` lets all of them in)."""
    return action if type(action) is int else int(np.asarray(action).reshape(-1)[0])


def noop_action(action_type: Any, space: spaces.Space) -> Any:
    """The action that asks for nothing new: a meta-action's IDLE, else the space's first value
    (a Discrete space's start; zeros, within a Box's bounds)."""
    indexes = getattr(action_type, "actions_indexes", None)
    if indexes and "IDLE" in indexes:
        return indexes["IDLE"]
    if isinstance(space, spaces.Discrete):
        return int(space.start)
    if isinstance(space, spaces.Box):
        return np.clip(np.zeros(space.shape), space.low, space.high).astype(space.dtype)
    return space.sample()  # (no first value: highway-env's)


def action_array(space: spaces.Space, action: Any) -> np.ndarray:
    """A copy of the action in the action space's dtype (a 0-d array for discrete actions)."""
    return np.array(action, dtype=space.dtype if space.dtype is not None else None, copy=True)


@functools.cache
def weight_keys(terms: tuple[str, ...]) -> tuple[str, ...]:
    """The config keys of reward terms' weights ("reward_<term>")."""
    return tuple(f"reward_{k}" for k in terms)


# what `step_ends` reads of each env's config: the reward weights (`REWARD_TERMS` order), then
# offroad_terminal and duration
_STEP_END_CONFIG = operator.itemgetter(*weight_keys(REWARD_TERMS), "offroad_terminal", "duration")
_KEEPS_HOOKS: dict[type, bool] = {}  # `keeps_hooks` of each class asked
# the hooks whose MapEnv versions `step_ends` stands in for
_STEP_HOOKS = ("_reward", "_rewards", "_reward_terms", "_reward_weights", "_is_terminated", "_is_truncated", "_info")


def keeps_hooks(cls: type) -> bool:
    """`MapEnv.keeps_step_hooks` of the envs of class `cls` (found once per class)."""
    keeps = _KEEPS_HOOKS.get(cls)
    if keeps is None:
        keeps = _KEEPS_HOOKS[cls] = all(getattr(cls, name) is getattr(MapEnv, name) for name in _STEP_HOOKS)
    return keeps


def step_ends(envs: Sequence["MapEnv"], actions: Sequence, batch: bool = False) -> tuple[np.ndarray, np.ndarray,
                                                                                      np.ndarray, dict]:
    """What `end_step` works out for each of `envs` (one core's, keeping MapEnv's hooks:
    `keeps_step_hooks`), their tasks and infos asked at once (`task`, `info_columns`): (rewards,
    terminated, truncated, the info columns; of one env, unless `batch`, its info values); the
    reward terms are the info's "rewards" (a batch's one table, `info_columns.Records`)."""
    core = envs[0].road.core
    one = len(envs) == 1 and not batch  # a single env: its row an int, its values numpy scalars (the same operations)
    row, weights, offroad_terminal, cut = [], [], [], []  # of each env, in one pass
    for env in envs:
        values = _STEP_END_CONFIG(env.config)  # (the envs keep MapEnv's `_reward_weights`: `keeps_hooks`)
        row.append(env.vehicle.row)
        weights.append(values[:-2])
        offroad_terminal.append(bool(values[-2]))
        cut.append(env.time >= values[-1])
    rows = row[0] if one else np.array(row)
    done, completed = task.route_state(core, rows)
    off_road = core.off_road[rows]
    terms = task.reward_terms(core, rows, done, completed, off_road)
    terms = terms.reshape(len(envs), len(REWARD_TERMS))
    rewards = task.weighted(terms, weights)
    terminated = task.ended(core.crashed[rows], completed, off_road,
                            offroad_terminal[0] if one else np.array(offroad_terminal))
    truncated = cut[0] if one else np.array(cut)
    progress = task.route_progress(core, rows, done)
    if one:
        envs[0]._last_rewards = dict(zip(REWARD_TERMS, terms[0].tolist()))
    info = info_columns.columns(core, rows, envs, actions, completed, progress, off_road,
                                None if one else info_columns.Records(REWARD_TERMS, terms))
    return (rewards, np.array([terminated]), np.array([truncated]), info) if one else \
        (rewards, terminated, truncated, info)


def info_dict(values: dict[str, Any], action_space: spaces.Space) -> dict[str, Any]:
    """`MapEnv._info`'s dict of one row's info values (`info_columns.columns`): new containers,
    the action as an array."""
    out = dict(values)
    out["action"] = action_array(action_space, values["action"])
    for key, copy in _INFO_COPIES.items():
        out[key] = copy(values[key])
    return out


def info_dicts(cols: dict[str, Any], action_space: spaces.Space, at: list[int] | None = None) -> list[dict[str, Any]]:
    """`info_dict` of each row of a batch's `columns` (of the rows `at` only, when given), in one
    pass: the containers converted column by column, then one dict per row."""
    made = info_columns.DICT_COLUMNS  # (columns whose `dicts` are new dicts)
    if at is not None:
        cols = {k: col[at] if isinstance(col, np.ndarray) else col.at(at) if isinstance(col, made)
                else [col[i] for i in at] for k, col in cols.items()}
    out = {k: col.tolist() if isinstance(col, np.ndarray) else col.dicts() if isinstance(col, made)
           else col for k, col in cols.items()}
    out["action"] = [action_array(action_space, a) for a in out["action"]]
    for key, copy in _INFO_COPIES.items():
        if not isinstance(cols[key], made):
            out[key] = [copy(v) for v in out[key]]
    return [dict(zip(out, values)) for values in zip(*out.values())]


def feature_info(feature) -> dict[str, Any]:
    """A junction feature as a dict of fixed keys, types and shapes (n_roads -1 without one);
    new arrays each call (from one conversion per feature)."""
    held = held_feature_info(feature)
    out = dict(held[1])
    for k in held[2]:
        out[k] = out[k].copy()
    return out


# the info values that are containers a view holds (or a feature): each info gets its own copy
_INFO_COPIES: dict[str, Callable[[Any], Any]] = {"junction_feature": feature_info, "violations": dict,
                                                 "new_violations": list, "rewards": dict}


def held_feature_info(feature) -> tuple[Any, dict[str, Any], list[str]]:
    """(feature, its info dict, the keys of its arrays), converted once per feature: not to be changed."""
    held = _FEATURE_INFO.get(id(feature))
    if held is None or held[0] is not feature:
        if len(_FEATURE_INFO) > 4096:
            _FEATURE_INFO.clear()
        info = _feature_info(feature)
        held = _FEATURE_INFO[id(feature)] = (feature, info, [k for k, v in info.items() if isinstance(v, np.ndarray)])
    return held


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
