"""Many learning agents through the same junctions: a PettingZoo `ParallelEnv` on any feat2map map.

`feat2map.envs.parallel_env(config)` (or `MultiAgentMapEnv(config)`) drives `agents` controlled
vehicles through a generated map (JunctionGrid-v0's keys: `features`, `feature_space`,
`map_seed`...) or any map file (`map_file`) or HDMap (`map`), among IDM/MOBIL traffic and
crosswalk pedestrians under the same rules as the single env (MapEnv's config keys, strict).

World. One `MapEnv` (a `_World`: the generated or file env with its config, network, traffic
control, arrays core, traffic and pedestrians) holds every agent: an agent is a controlled row of
the arrays core (`core.TrafficCore.controlled`): the ego's kinematic bicycle with the config's
`vehicle` (`sim/vehicle.py`), taking its acceleration from its action and steering by lane
keeping on its route (`TrafficCore.drive`, all agents at once), so traffic and agents are
advanced in one array program and traffic sees agents as road users where they are (leaders,
stop queues, conflicts, reservations, crosswalks). Traffic respawns as in the single env, away
from agents. An agent's `AgentView` is the single env's ego task (`map_env.EgoTask`) over its
vehicle, its judge and the shared world.

Worlds. With `worlds` = W > 1 the env holds W copies of the world on one map (for training:
more agents per step for the same Python overhead): each world is a slot of one shared arrays
core, whose frame advances the traffic and agents of every world in one call, and world w resets
with seed + w (its agents then drive exactly as the one-world env's reset with that seed). The
agents of world w are agent_{w*agents}..agent_{w*agents+agents-1}; a world whose agents are all
gone stands still until the episode ends (when no world has an agent left).

Agents. `possible_agents` are "agent_0".."agent_{n-1}" (n = agents x worlds). Each gets a route (`agent_routes`:
None = sampled through `route_junctions` junctions, as the single env samples the ego's;
"coverage" = the map's route-coverage routes, `feat2map.routes.coverage_routes`, dealt round
from a random start; or a list of routes in the single env's `route` format, dealt round) and
starts at its entry where the ego would (`ego_start_distance` before the first stop line), or
up to `agent_queue - 1` places of `agent_spacing` behind it; an agent whose place is taken waits
and enters at a later step (it then appears in `agents`: PettingZoo's lifecycle). An agent
finishes (terminated) on reaching its goal (`goal_distance` into its last lane) or in a crash,
and leaves the road; every agent left is truncated at `duration`, and an episode ends when no
agent is left.

Per agent: the observation of the config's `observation` (Kinematics, DriverView, any type the
single env takes; `observe_traffic_control` too), computed as the single env computes the ego's
(each agent sees every other road user, agents included); the action of `action`: "TargetSpeed"
(the default: discrete target speeds, the constant acceleration that reaches the chosen one by
the next decision), "DiscreteMetaAction" (SLOWER/IDLE/FASTER over target speeds) or
"ContinuousAction" (longitudinal acceleration in [-1, 1] over `acceleration_range`); the single
env's reward terms and weights; the single env's judge (`rules.EgoJudge`: red light, missed stop,
pedestrian yield) with two more violations (`AgentJudge`): `not_yielding` (entering a junction
lane while a conflicting one is occupied or reserved, or priority traffic is about to enter one:
`TrafficRules.junction_clear`, the rule traffic obeys, asked at the last moment the agent could
still stop comfortably before the line) and `stop_order` (entering from a stop sign
while a vehicle that stopped there earlier wants a conflicting lane: `TrafficRules.
stop_queue_allows`), unless it holds the junction lane's reservation (as `TrafficRules.may_enter`
lets a vehicle that committed go: the scripted driver reserves, agents choosing their own
speeds do not), weighted by `reward_not_yielding` / `reward_stop_order`; infos with the
single env's keys (`info.INFO_KEYS`; `violations` holds the two more) plus
`agent_collision` (the agent crashed into another agent; `collision` is any crash) and
`wait_time` (seconds stopped so far).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from ..config import AGENT_ACCELERATION_RANGE, AGENT_ENTRY_LOOK_M, AGENT_TARGET_SPEEDS, IDM_RANGE_MPS2
from ..errors import Feat2MapError
from . import info_columns, task
from .config import (MULTI, checks, defaults, multi_agent_defaults,
                     multi_agent_not_taken)
from .control import TrafficControl
from .controlled import ControlledRow
from .core import TrafficCore
from .junction_env import JunctionGridEnv, MapFileEnv
from .map_env import (REWARD_TERMS, EgoTask, MapEnv, check_action, check_options, discrete_index, info_dict,
                      info_dicts, noop_action)
from .driver_view import DriverViewObservation, driver_views
from .observation import Kinematics, TrafficControlObservation, make_observation
from .road import MapRoad
from .routes import route_from_config, sample_config_route, start_place
from .rules import JUDGED, EgoJudge, can_stop_before, has_stopped
from .sim.observe import kinematics
from .sim.vehicle import VehicleModel, speed_control

AGENT_VIOLATIONS = JUDGED  # an agent's violation kinds, in order
AGENT_TERMS = (*REWARD_TERMS, "not_yielding", "stop_order")  # an agent's reward terms, in order
_AGENT_ONLY = [JUDGED.index(k) for k in AGENT_TERMS[len(REWARD_TERMS):]]  # the terms of the agents' judge
#: the multi-agent env's own keys (the rest is MapEnv's config, checked by it): `config.SETTINGS`' rows of MULTI
AGENT_DEFAULTS: dict[str, Any] = defaults(MULTI)
#: MapEnv defaults the multi-agent env changes (decisions at 2 Hz, one junction per route)
WORLD_DEFAULTS: dict[str, Any] = multi_agent_defaults()
AGENT_CHECKS = checks(MULTI)
NOT_TAKEN = multi_agent_not_taken()  # MapEnv keys nothing in the multi-agent env reads: refused


def parallel_env(config: Mapping[str, Any] | None = None, render_mode: str | None = None) -> "MultiAgentMapEnv":
    """The multi-agent env (see the module docstring) on a generated map, or on `map_file` / `map`."""
    return MultiAgentMapEnv(config, render_mode)


def env(config: Mapping[str, Any] | None = None, render_mode: str | None = None):
    """The same env as an AEC env (PettingZoo's `parallel_to_aec`), by PettingZoo's module convention."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(parallel_env(config, render_mode))


# ---- config -----------------------------------------------------------------------------------
def check_agent_config(cfg: Mapping[str, Any]) -> None:
    """The multi-agent keys, strictly: a bad value is a Feat2MapError naming `config.<key>`."""
    for key, check in AGENT_CHECKS.items():
        check(cfg[key], f"config.{key}")


def split_config(config: Mapping[str, Any] | None) -> tuple[dict, dict]:
    """(multi-agent keys, MapEnv keys) of a config; the action dict merges as MapEnv's do."""
    if config is not None and not isinstance(config, Mapping):
        raise Feat2MapError(f"must be a mapping, got {type(config).__name__}", "config")
    ma: dict[str, Any] = {}
    world: dict[str, Any] = {}
    for k, v in (config or {}).items():
        if k in NOT_TAKEN:
            raise Feat2MapError(f"has no effect in the multi-agent env ({NOT_TAKEN[k]})", f"config.{k}")
        (ma if k in AGENT_DEFAULTS else world)[k] = v
    return ma, world


def check_worlds(worlds: int, new_map_each_reset: bool) -> None:
    """Several worlds share one map: a new map at each reset is refused."""
    if worlds > 1 and new_map_each_reset:
        raise Feat2MapError(f"the {worlds} worlds of one env share one map: make a new env for a new map",
                            "config.new_map_each_reset")


def merge_agent_config(base: dict, delta: Mapping[str, Any]) -> dict:
    out = dict(base)
    for k, v in delta.items():
        cur = out.get(k)
        if k == "action" and isinstance(v, Mapping) and isinstance(cur, Mapping):
            out[k] = {**cur, **v} if v.get("type", cur.get("type")) == cur.get("type") else dict(v)
        else:
            out[k] = v
    check_agent_config(out)
    return out


# ---- actions ----------------------------------------------------------------------------------
class AgentActions:
    """The agents' action type: its space, and the accelerations of all agents at once."""

    def __init__(self, cfg: Mapping[str, Any], policy_frequency: float) -> None:
        self.kind = cfg["type"]
        self.speeds = np.array(cfg.get("target_speeds", AGENT_TARGET_SPEEDS), dtype=float)
        self.acceleration_range = tuple(float(x) for x in cfg.get("acceleration_range", AGENT_ACCELERATION_RANGE))
        self.period = 1.0 / policy_frequency
        if self.kind == "TargetSpeed":
            self.space: spaces.Space = spaces.Discrete(len(self.speeds))
        elif self.kind == "DiscreteMetaAction":
            self.space = spaces.Discrete(3)  # highway-env's longitudinal meta-actions: SLOWER, IDLE, FASTER
        else:
            self.space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

    def clear(self, agents: int) -> None:
        """No decisions yet for any of `agents` agents (numbered as `possible_agents`)."""
        self.acc = np.zeros(agents)  # each agent's held acceleration
        self.index = np.zeros(agents, dtype=np.int64)  # ... or its target speed's index

    def start(self, k: int, speed: float) -> None:
        """Agent k is new on the road: it holds its speed (its target speed index the nearest)."""
        self.acc[k], self.index[k] = 0.0, int(np.argmin(np.abs(self.speeds - speed)))

    def decide(self, ks: list[int], actions: list, speeds: np.ndarray) -> None:
        """New decisions of agents `ks` (checked `actions`, their vehicles' `speeds`): their held
        accelerations, or their target speed indices."""
        lo, hi = self.acceleration_range
        if self.kind == "DiscreteMetaAction":
            self.index[ks] = np.clip(self.index[ks] + _indices(actions) - 1, 0, len(self.speeds) - 1)
        elif self.kind == "TargetSpeed":
            self.acc[ks] = np.minimum(np.maximum((self.speeds[_indices(actions)] - speeds)
                                                 / self.period, lo), hi)
        else:
            a = np.array([np.asarray(x, dtype=float).reshape(-1)[0] for x in actions], dtype=float)
            self.acc[ks] = lo + (np.minimum(np.maximum(a, -1.0), 1.0) + 1.0) / 2.0 * (hi - lo)

    def accelerations(self, ks: list[int], speeds: np.ndarray) -> np.ndarray:
        """Accelerations of agents `ks` this frame (DiscreteMetaAction tracks its target speed every frame)."""
        if self.kind == "DiscreteMetaAction":
            return np.clip(speed_control(self.speeds[self.index[ks]], speeds), *IDM_RANGE_MPS2)
        return self.acc[ks]


def _indices(actions: list) -> np.ndarray:
    """Checked discrete actions as an index array."""
    return np.array([discrete_index(x) for x in actions], dtype=np.int64)


# ---- the world --------------------------------------------------------------------------------
class AgentJudge(EgoJudge):
    """The single env's judge of one agent, plus `not_yielding` and `stop_order` (module docstring):
    before each frame `note` keeps the rules' verdict for the junction lane the agent is about to
    enter, as long as the agent could still stop comfortably before the line (`rules.
    can_stop_before`: past that point a conflict that turns up is not its fault, as at amber);
    `check` counts a violation when it enters against the verdict."""

    KINDS = JUDGED
    AGENT = True

    def note(self) -> str | None:
        """Keep the verdict on the junction lane ahead (the row's `v_lane`, `v_clear`, `v_order`,
        which the judge reads when the agent enters that lane: `sim.judge`); the lane whose
        conflict verdict (`TrafficRules.junction_clear`) is to be kept too (`noted`, asked of every
        agent at once by the env), else None."""
        rules, v, core = self.rules, self.ego, self._core
        sl, in_lane, j_lane, d = rules.line_ahead(v, AGENT_ENTRY_LOOK_M)
        if j_lane is None:
            return None
        i, k = v.row, core.table.index[j_lane]
        if core.v_lane[i] == k and not can_stop_before(d, v.speed, v.LENGTH):
            return None  # past the point where it could still stop: judged by the last verdict it could act on
        order = True
        if rules.reservations.get(j_lane) is v:  # a vehicle the rules let commit goes (TrafficRules.may_enter)
            core.v_lane[i], core.v_clear[i], core.v_order[i] = k, True, True
            return None
        if sl is not None and sl.kind == "stop":
            queue = rules.stop_queue.get(sl.junction_id, [])
            order = v not in queue or rules.stop_queue_allows(v, j_lane)  # not stopped at all: a stop_sign violation
        core.v_lane[i], core.v_clear[i], core.v_order[i] = k, True, order
        return j_lane

    def noted(self, clear: bool) -> None:
        """Keep whether the junction lane `note` returned is clear for the agent."""
        self._core.v_clear[self.ego.row] = clear


class AgentView(EgoTask):
    """One agent as the single env's ego (`map_env.EgoTask`: route completion, reward terms,
    infos, the scripted-driver API) over the shared world: its own vehicle, judge, spaces,
    progress and reward terms, and the world's road, map, rules, config and clock, which
    observation types and `ScriptedDriver(view)` read as they read a MapEnv's."""

    PERCEPTION_DISTANCE = MapEnv.PERCEPTION_DISTANCE
    judge: AgentJudge
    observation_type: Any

    def __init__(self, world: "_World", vehicle: ControlledRow, action_type: AgentActions,
                 action_space: spaces.Space) -> None:
        self.world = world
        self.vehicle = vehicle
        self.controlled_vehicles = [vehicle]
        self.action_type, self.action_space = action_type, action_space
        # the episode's (a new episode has new views)
        self.config, self.road, self.net, self.control = world.config, world.road, world.net, world.control
        self.wait_time = 0.0
        self.agent_collision = False
        self._completed_at = -1  # the world's frame of `route_completed`'s last answer
        self._completed = False

    def start(self, judge: AgentJudge, terms: Sequence[str], observation_type: Any) -> None:
        """The agent is on the road: its judge, reward terms and observation; its progress from here."""
        self.judge = judge
        self.observation_type = observation_type
        self.start_task()
        self._last_rewards = dict.fromkeys(terms, 0.0)

    @property
    def time(self) -> float:  # type: ignore[override]  # the world's clock: read-only here
        return self.world.time

    @property
    def np_random(self) -> np.random.Generator:
        return self.world.np_random

    @property
    def unwrapped(self) -> "AgentView":
        return self

    def keep_rewards(self, terms: list[float]) -> None:
        """This step's reward terms (`AGENT_TERMS` order: `reward_terms`) are the info's "rewards"."""
        self._last_rewards = dict(zip(AGENT_TERMS, terms))

    @staticmethod
    def reward_terms(views: list["AgentView"], core: Any, rows: np.ndarray, done: np.ndarray,
                     completed: np.ndarray) -> np.ndarray:
        """[agents, AGENT_TERMS]: this step's reward terms of the agents of `views` (their `rows`),
        given their route metres `done` and whether their routes are `completed`: the single
        env's (`task.reward_terms`) and the two of the agents' judge."""
        terms = np.zeros((len(views), len(AGENT_TERMS)))
        terms[:, :len(REWARD_TERMS)] = task.reward_terms(core, rows, done, completed, core.off_road[rows])
        terms[:, len(REWARD_TERMS):] = core.new_violations[rows][:, _AGENT_ONLY]
        return terms

    def info(self, action: Any = None) -> dict:
        """The single env's info of the agent (`info_columns.columns` of its row) and its own
        keys (`info.INFO_KEYS`)."""
        values = info_columns.columns(self.road.core, self.vehicle.row, [self], [action])
        return self.own_info(info_dict(values, self.action_space))

    def own_info(self, info: dict) -> dict:
        """`info` (the single env's, `map_env.info_dict`) with the agent's own keys."""
        info["agent_collision"] = bool(self.agent_collision)
        info["wait_time"] = float(self.wait_time)
        return info

    def route_completed(self) -> bool:
        """EgoTask's, computed once per simulation frame (it depends only on where the vehicles
        are; the reward, the termination and the info of a step all ask)."""
        steps = self.world.steps
        if self._completed_at != steps:
            self._completed_at, self._completed = steps, EgoTask.route_completed(self)
        return self._completed


class _World(MapEnv):
    """The map, traffic control, traffic and pedestrians of the multi-agent env, with the agents'
    vehicles as controlled rows of its arrays core (MapEnv's reset and step are not used)."""

    def __init__(self, config: dict, agent_config: dict, render_mode: str | None = None) -> None:
        self.agent_config = agent_config
        self._built = False
        super().__init__(config, render_mode)
        self._built = True

    def define_spaces(self) -> None:  # per agent (MultiAgentMapEnv)
        pass

    def reset(self, *, seed=None, options=None):
        if not self._built:  # AbstractEnv.__init__ resets; the multi-agent env resets explicitly
            return None, {}
        raise NotImplementedError("reset the MultiAgentMapEnv")

    def new_episode(self, seed: int | None) -> list[tuple[list[str], bool]]:
        """A fresh episode (traffic control, road, traffic); the agents' routes, placed by the caller."""
        gymnasium.Env.reset(self, seed=seed)  # seeds np_random
        self.time = self.steps = 0
        self.done = False
        self.net = self.network()
        rng = self.np_random
        self.control = TrafficControl(self.net, rng, self.config)
        slot = {"slot": self.core_slot} if self.core_slot is not None else {}
        self.road = MapRoad(self.net, self.control, rng, record_history=self.config["show_trajectories"], **slot)
        self.model = VehicleModel.of(self.config["vehicle"])
        self.controlled_vehicles = []
        self._places: dict[tuple, tuple] = {}
        routes = self._agent_routes(int(self.agent_config["agents"]))
        m = self.net.hdmap
        lanes = [l for r, _ in routes for l in r]
        junctions = {j for j in (m.lanes[l].junction_id for l in lanes) if j is not None}
        crossed = {c for lid in set(lanes) for c, _, _ in self.net.crossings.get(lid, ())
                   if m.crosswalks[c].junction_id is None}  # mid-block crossings on the routes
        self.control.active_crosswalks = sorted(c.id for c in m.crosswalks.values()
                                                if c.junction_id in junctions or c.id in crossed)
        self._spawn_lanes = self._traffic_spawn_lanes(sorted(set(lanes)), junctions)
        return routes

    def fill_traffic(self) -> None:
        for _ in range(int(self.config["traffic_vehicles"])):
            self._spawn_traffic()
        self.control.update(self.road, 0.0)

    def _agent_routes(self, n: int) -> list[tuple[list[str], bool]]:
        """(lane route, whether a manoeuvre route to extend) of each agent."""
        spec = self.agent_config["agent_routes"]
        net, rng, c = self.net, self.np_random, self.config
        if spec == "coverage":
            from ..routes import coverage_routes

            spec = net.memo(("coverage routes", int(c["route_junctions"])),
                            lambda: coverage_routes(net.hdmap, max(1, int(c["route_junctions"]))))
            if not spec:
                raise Feat2MapError("the map has no route-coverage route (no junction manoeuvre)", "config.agent_routes")
        if spec is not None:
            first = int(rng.integers(len(spec)))
            out = []
            for i in range(n):
                k = (first + i) % len(spec)
                out.append(route_from_config(net, spec[k]))
            return out
        return [sample_config_route(net, rng, c) for _ in range(n)]

    def places(self, route: list[str], extend: bool) -> tuple[list[tuple[list[str], float, float]], np.ndarray]:
        """((route, s on its first lane, speed) of each place of an agent's entry, nearest the
        junction first (`agent_queue` at most; fewer where the road before the entry ends), their
        [places, 2] centres)."""
        key = (tuple(route), extend)
        held = self._places.get(key)
        if held is None:
            c, ac = self.config, self.agent_config
            out = []
            for k in range(int(ac["agent_queue"])):
                start = float(c["ego_start_distance"]) + k * float(ac["agent_spacing"])
                r, s0, speed = start_place(self.net, list(route), extend, start, float(c["goal_distance"]),
                                           float(c["ego_initial_speed"]), self.model.length)
                if k and s0 <= 0.0:
                    break  # the road before the entry is full
                out.append((r, s0, speed))
            xy = np.array([self.net.lane_of[r[0]].position(s0, 0.0) for r, s0, _ in out], dtype=float)
            held = self._places[key] = (out, xy)
        return held

    def place(self, route: list[str], extend: bool):
        """An agent's vehicle at the first free place of its entry (None while all are taken)."""
        core = self.road.core
        core.sync()
        places, xy = self.places(route, extend)
        mine = core.rows(self.road)  # road users of this world only
        if len(mine):
            x, y = core.x[mine], core.y[mine]
            gap = np.hypot(x[None, :] - xy[:, :1], y[None, :] - xy[:, 1:]).min(axis=1)
            free = gap >= float(self.agent_config["agent_spacing"]) - 2.0
        else:
            free = np.ones(len(places), dtype=bool)
        for k in np.nonzero(free)[0].tolist():
            r, s0, speed = places[k]
            v = core.add_traffic(self.road, r[0], s0, speed, list(r), model=self.model, view=ControlledRow)
            if self.control.passage_start(v):
                return v
            self.road.vehicles.remove(v)
            core.sync()
        return None


class _GridWorld(_World, JunctionGridEnv):
    pass


class _FileWorld(_World, MapFileEnv):
    pass


# ---- the parallel env -------------------------------------------------------------------------
class MultiAgentMapEnv(ParallelEnv):
    """A PettingZoo ParallelEnv of many agents on one feat2map map (see the module docstring),
    in `worlds` copies of the world that share one arrays core."""

    metadata = {"name": "feat2map_parallel_v0", "render_modes": ["human", "rgb_array"], "is_parallelizable": True}

    def __init__(self, config: Mapping[str, Any] | None = None, render_mode: str | None = None) -> None:
        ma, world = split_config(config)
        self.agent_config = merge_agent_config(AGENT_DEFAULTS, ma)
        self.render_mode = render_mode
        self._world_class = _FileWorld if ("map_file" in world or "map" in world) else _GridWorld
        self._make_worlds({**WORLD_DEFAULTS, **world})
        self.agents: list[str] = []
        self._define_spaces()
        self._views: dict[str, AgentView] = {}

    def _make_worlds(self, config: Mapping[str, Any]) -> None:
        """The worlds (world 0 renders) and the agents' names; with more than one world, each is a
        slot of one shared arrays core on the first world's map (as the vector env's sub-envs)."""
        n = int(self.agent_config["worlds"])
        old = getattr(self, "worlds", [])
        first = self._world_class(dict(config), self.agent_config, self.render_mode)
        for w in old:  # (made again by `configure`: their viewers closed)
            w.close()
        self.worlds: list[_World] = [first]
        if n > 1:
            check_worlds(n, first.config["new_map_each_reset"])
            net = first.network()
            core = TrafficCore(net, n)
            self.worlds += [self._world_class(dict(first.config), self.agent_config) for _ in range(n - 1)]
            for k, w in enumerate(self.worlds):
                w.share(core, k, net)
        self.world = first
        self._name_agents()

    def _name_agents(self) -> None:
        """possible_agents, world-major: agent_{w * agents + i} is agent i of world w."""
        per = int(self.agent_config["agents"])
        self.possible_agents = [f"agent_{i}" for i in range(len(self.worlds) * per)]
        self._world_of = {a: i // per for i, a in enumerate(self.possible_agents)}
        self._number = {a: i for i, a in enumerate(self.possible_agents)}

    def _define_spaces(self) -> None:
        w = self.world
        held = getattr(self, "actions", None)
        self.actions = AgentActions(self.agent_config["action"], float(w.config["policy_frequency"]))
        self.actions.clear(len(self.possible_agents))
        if held is not None:  # configured mid-episode: the agents on the road keep their decisions
            n = min(len(held.acc), len(self.actions.acc))
            self.actions.acc[:n], self.actions.index[:n] = held.acc[:n], held.index[:n]
        self._obs_space = self._make_observation(w).space()  # (an observation type's space needs no ego)

    def _make_observation(self, env: "AgentView | _World"):
        obs = make_observation(env, self.world.config["observation"])
        return TrafficControlObservation(env, obs) if self.world.config["observe_traffic_control"] else obs

    def observation_space(self, agent: str) -> spaces.Space:
        """The same space object for every agent (PettingZoo's tests ask for one object)."""
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space:
        return self.actions.space

    def configure(self, config: Mapping[str, Any]) -> None:
        """Merge `config` (multi-agent and MapEnv keys) into the current config; strict. With
        more than one world (before or after), the worlds are made again."""
        ma, world = split_config(config)
        merged = merge_agent_config(self.agent_config, ma)
        check_worlds(int(merged["worlds"]), world.get("new_map_each_reset", self.world.config["new_map_each_reset"]))
        self.world.configure(world)
        several = len(self.worlds) > 1
        self.agent_config = merged
        self.world.agent_config = merged
        if several or int(merged["worlds"]) > 1:
            self._make_worlds(self.world.config)
        else:
            self._name_agents()
        self._define_spaces()

    # ---- episode ---------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None):
        check_options(options)
        if options and "config" in options:
            self.configure(options["config"])
        self.agents = []
        self._views = {}
        self._pending: list[tuple[str, tuple[list[str], bool]]] = []
        self._agent_ids: dict[int, str] = {}
        per = int(self.agent_config["agents"])
        for k, w in enumerate(self.worlds):  # each world as the one-world env on its seed
            routes = w.new_episode(None if seed is None else seed + k)
            self._pending += list(zip(self.possible_agents[k * per:(k + 1) * per], routes))
            self._spawn_pending({k})
            w.fill_traffic()
        obs = self._observe(self.agents)
        infos = {a: self._views[a].info(action=self._noop()) for a in self.agents}
        return obs, infos

    def _spawn_pending(self, worlds: set[int]) -> list[str]:
        """Agents of `worlds` waiting to enter take their places where free (in agent order)."""
        new, waiting = [], []
        blocked: set[tuple[int, str]] = set()  # entries where an agent found no place: the ones after it wait too
        for name, (route, extend) in self._pending:
            k = self._world_of[name]
            w = self.worlds[k]
            v = None if k not in worlds or (k, route[0]) in blocked else w.place(route, extend)
            if v is None:
                blocked.add((k, route[0]))
                waiting.append((name, (route, extend)))
                continue
            v.target_speeds = self.actions.speeds
            view = AgentView(w, v, self.actions, self.actions.space)
            view.start(AgentJudge(w.control, v), self._reward_terms(), self._make_observation(view))
            self._views[name] = view
            self.actions.start(self._number[name], v.speed)
            self._agent_ids[id(v)] = name
            w.controlled_vehicles.append(v)
            new.append(name)
        self.agents.extend(new)
        self._pending = waiting
        return new

    @staticmethod
    def _reward_terms() -> tuple[str, ...]:
        return AGENT_TERMS

    def step(self, actions: Mapping[str, Any]):
        live = list(self.agents)
        alive = set(live)
        if not isinstance(actions, Mapping):
            raise Feat2MapError(f"must be a dict agent name -> action, got {type(actions).__name__}", "actions")
        for name, a in actions.items():  # every action checked before any agent's decision is applied
            if name not in alive:
                raise Feat2MapError(f"{name!r} is not a live agent (live: {', '.join(live) or 'none'})", "actions")
            try:
                check_action(self.actions.space, a)
            except Feat2MapError as exc:
                raise Feat2MapError(exc.message, f"actions[{name!r}]") from None
        if actions:
            core = self.world.road.core
            self.actions.decide([self._number[a] for a in actions], list(actions.values()),
                                core.speed[[self._views[a].vehicle.row for a in actions]])
        if live:  # (this step's violations)
            self.world.road.core.new_violations[[self._views[a].vehicle.row for a in live]] = 0
        # the worlds with agents on the road step (all of them when none has: the one-world env's
        # step after its end); a world whose agents are all gone stands still
        active = sorted({self._world_of[a] for a in live}) or list(range(len(self.worlds)))
        worlds = [self.worlds[k] for k in active]
        roads = [w.road for w in worlds]
        w = self.world
        core = w.road.core
        frames = max(1, int(w.config["simulation_frequency"] // w.config["policy_frequency"]))
        dt = 1.0 / w.config["simulation_frequency"]
        views = [self._views[a] for a in live]
        vehicles = [v.vehicle for v in views]
        judges = [v.judge for v in views]
        numbers = [self._number[a] for a in live]
        layout = -1  # (the core's when the agents' rows were read: rows move only when it changes)
        for _ in range(frames):
            core.sync()
            if vehicles:
                if layout != core.layout:
                    rows, layout = np.array([v.row for v in vehicles], dtype=np.int64), core.layout
                core.command[rows] = self.actions.accelerations(numbers, core.speed[rows])
                # the rules' verdict is noted for agents near a junction entry (core.entry: where the
                # next one starts, from the current lane's start; the line may lie before it)
                core.refresh_windows()  # rows that moved to a new lane last frame
                near = core.entry[rows] - core.s[rows] <= AGENT_ENTRY_LOOK_M + w.net.max_line_setback
                with core.asking():
                    asked = [(k, judges[k].note()) for k in np.nonzero(near)[0].tolist()]
                    asked = [(k, j_lane) for k, j_lane in asked if j_lane is not None]
                    if asked:  # (the conflict rule asked of every agent at once)
                        clear = core.rows_clear(rows[[k for k, _ in asked]], [j_lane for _, j_lane in asked])
                        for (k, _), ok in zip(asked, clear.tolist()):
                            judges[k].noted(ok)
                crashed = core.crashed[rows]
            core.act(roads)
            core.step(roads, dt)
            for x in worlds:
                x.steps += 1
            if not vehicles:
                continue
            core.judge(rows[core.judge_due(rows)])  # where its check can change anything
            for k in np.nonzero(has_stopped(core.speed[rows]))[0].tolist():
                views[k].wait_time += dt
            for k in np.nonzero(core.crashed[rows] & ~crashed)[0].tolist():
                self._collided(live[k])
        truncated = set()
        for k, x in zip(active, worlds):
            x.time += 1.0 / x.config["policy_frequency"]
            if x.time >= x.config["duration"]:
                truncated.add(k)
        obs, rewards, terms, truncs, infos = {}, {}, {}, {}, {}
        obs = self._observe(live)
        if live:  # the agents' tasks at once (`task`)
            if layout != core.layout:
                rows = np.array([v.row for v in vehicles], dtype=np.int64)
            done, completed = task.route_state(core, rows)
            terms_of = AgentView.reward_terms(views, core, rows, done, completed)
            columns, weights = self._weights()
            reward = task.weighted(terms_of[:, columns], [weights.tolist()] * len(live))
            ended = core.crashed[rows] | completed
            progress = task.route_progress(core, rows, done)
            for a, view, row, r, e in zip(live, views, terms_of.tolist(), reward.tolist(), ended.tolist()):
                view.keep_rewards(row)
                rewards[a], terms[a] = r, e
                truncs[a] = self._world_of[a] in truncated and not e
            acts = [actions.get(a) for a in live]
            cols = info_columns.columns(core, rows, views, [self._noop() if x is None else x for x in acts],
                                        completed, progress)
            for a, view, info in zip(live, views, info_dicts(cols, self.actions.space)):
                infos[a] = view.own_info(info)
        gone = [a for a in live if terms[a] or truncs[a]]
        if gone:
            for a in gone:
                self._views[a].judge.let_go()
            out = {id(self._views[a].vehicle) for a in gone}
            for x in worlds:
                x.road.vehicles = [v for v in x.road.vehicles if id(v) not in out]
                x.controlled_vehicles = [v for v in x.controlled_vehicles if id(v) not in out]
            self.agents = [a for a in self.agents if a not in gone]
        for x in worlds:
            x.respawn_traffic()
        self._pending = [p for p in self._pending if self._world_of[p[0]] not in truncated]
        new = self._spawn_pending(set(active))
        obs.update(self._observe(new))
        for a in new:
            rewards[a], terms[a], truncs[a] = 0.0, False, False
            infos[a] = self._views[a].info(action=self._noop())
        # a world with nobody on the road: its waiting agents will never get in
        on_road = {self._world_of[a] for a in self.agents}
        self._pending = [p for p in self._pending if self._world_of[p[0]] in on_road]
        return obs, rewards, terms, truncs, infos

    def _observe(self, names: list[str]) -> dict[str, Any]:
        """The agents' observations: Kinematics or DriverView of all of them in one program
        (`sim.observe.kinematics`, `driver_view.driver_views`: the single env's values), else each
        agent's observation type."""
        if not names:
            return {}
        types = [self._views[a].observation_type for a in names]
        got = kinematics(types, self.world.road.core) if type(types[0]) is Kinematics else \
            driver_views([t.env for t in types]) if type(types[0]) is DriverViewObservation else [None] * len(names)
        return {a: t.observe() if o is None else o for a, t, o in zip(names, types, got)}

    def _noop(self):
        """The agents' no-op (`map_env.noop_action`; their meta-actions' IDLE is 1: SLOWER, IDLE, FASTER)."""
        return 1 if self.actions.kind == "DiscreteMetaAction" else noop_action(None, self.actions.space)

    def _collided(self, agent: str) -> None:
        """An agent crashed this frame: whether the other vehicle (the nearest crashed one within
        reach) is an agent."""
        core = self.world.road.core
        i = self._views[agent].vehicle.row
        d = np.hypot(core.x - core.x[i], core.y - core.y[i])
        d[i] = np.inf
        d[~core.crashed | (core.env != core.env[i])] = np.inf  # crashed road users of its world
        j = int(np.argmin(d))
        if d[j] < np.hypot(core.length[i], core.width[i]) + np.hypot(core.length[j], core.width[j]):
            peer = self._agent_ids.get(id(core.objs[j]))
            if peer is not None:
                self._views[agent].agent_collision = True
                self._views[peer].agent_collision = True

    def _weights(self) -> tuple[np.ndarray, np.ndarray]:
        """(columns of `AGENT_TERMS`, their weights): the single env's `reward_*` and the two of
        the agents' judge, in that order, without the zero weights (adding their 0.0 products
        changes no sum)."""
        c, ac = self.world.config, self.agent_config
        weights = [*(c[f"reward_{k}"] for k in REWARD_TERMS), ac["reward_not_yielding"], ac["reward_stop_order"]]
        kept = [k for k, w in enumerate(weights) if w != 0]
        return np.array(kept, dtype=np.int64), np.array([weights[k] for k in kept], dtype=float)

    # ---- helpers -------------------------------------------------------------------------------
    def view(self, agent: str) -> AgentView:
        """The agent's view of the world as a single env (for planners: `ScriptedDriver(view)`)."""
        return self._views[agent]

    def state(self) -> np.ndarray:
        """Positions, headings and speeds of every road user of every world ([n, 4], float32;
        world by world)."""
        core = self.world.road.core
        return np.stack([core.x, core.y, core.heading, core.speed], axis=1).astype(np.float32)

    def render(self):
        w = self.world
        if self.render_mode is None:
            return None
        if self.agents:  # world 0's
            w.controlled_vehicles = [self._views[a].vehicle for a in self.agents if self._world_of[a] == 0]
        return MapEnv.render(w)

    def close(self) -> None:
        for w in self.worlds:
            w.close()
