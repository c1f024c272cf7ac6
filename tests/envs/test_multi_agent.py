"""The multi-agent env (envs/multi_agent.py): PettingZoo's parallel API and seed tests on a
generated, a spec and a real map; agents enter and leave; each agent's judge agrees with the
single env's on the same drive; agents collide with each other and are told so; strict config."""
from __future__ import annotations

import os
from collections import Counter

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
from gymnasium.utils.env_checker import data_equivalence
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test

import feat2map  # noqa: E402
from feat2map.envs import parallel_env  # noqa: E402
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver  # noqa: E402
from feat2map.envs.map_env import EgoTask, MapEnv  # noqa: E402
from feat2map.envs.multi_agent import AGENT_VIOLATIONS, AgentView, ControlledRow  # noqa: E402
from feat2map.envs.multi_agent import env as aec_env  # noqa: E402
from feat2map.errors import Feat2MapError  # noqa: E402
from feat2map.spec import build_spec, load_spec  # noqa: E402

from conftest import REPO, shared_map  # noqa: E402

J = feat2map.JunctionFeature.make
FOUR = [0, 90, 180, 270]
SMALL = {"agents": 6, "traffic_vehicles": 3, "pedestrian_rate": 6.0, "duration": 20.0}


def map_config(kind: str) -> dict:
    if kind == "generated":
        return {"features": [J(FOUR, "signal", True).to_dict(), J([0, 90, 180], "stop", False).to_dict()]}
    if kind == "spec":
        return {"map": build_spec(load_spec(REPO / "examples" / "one_way_t.yaml"))}
    return {"map_file": str(shared_map("opendrive/carla_town01/Town01.xodr"))}


MAPS = ["generated", "spec", pytest.param("real", marks=pytest.mark.real_maps)]


@pytest.mark.parametrize("kind", MAPS)
def test_parallel_api(kind):
    env = parallel_env({**map_config(kind), **SMALL})
    parallel_api_test(env, num_cycles=50)
    obs, infos = env.reset(seed=1)
    assert env.agents and set(obs) == set(env.agents) == set(infos)
    assert all(env.observation_space(a).contains(o) for a, o in obs.items())


@pytest.mark.parametrize("kind", MAPS)
def test_parallel_seed(kind):
    parallel_seed_test(lambda: parallel_env({**map_config(kind), **SMALL}), num_cycles=30)
    # PettingZoo's test stops after the first step (`any` of a dict of agents): 30 steps here
    envs = [parallel_env({**map_config(kind), **SMALL}) for _ in range(2)]
    outs = [e.reset(seed=3) for e in envs]
    assert data_equivalence(outs[0], outs[1])
    for k in range(30):
        if not envs[0].agents:
            break
        for e in envs:
            e.action_space("agent_0").seed(k)
        acts = [{a: e.action_space(a).sample() for a in e.agents} for e in envs]
        outs = [e.step(a) for e, a in zip(envs, acts)]
        assert data_equivalence(outs[0], outs[1]), k


def test_aec_api_and_seed():
    """The AEC form (`multi_agent.env`, PettingZoo's module convention) passes its API and seed tests."""
    cfg = {**map_config("generated"), **SMALL, "duration": 10.0}
    api_test(aec_env(cfg), num_cycles=30)
    seed_test(lambda: aec_env(cfg), num_cycles=30)


@pytest.mark.parametrize("action", [{"type": "TargetSpeed"}, {"type": "DiscreteMetaAction"},
                                    {"type": "ContinuousAction"}])
@pytest.mark.parametrize("observation", ["Kinematics", "DriverView", "TimeToCollision"])
def test_actions_observations_and_infos(action, observation):
    cfg = {**map_config("generated"), **SMALL, "action": action}
    if observation != "Kinematics":
        cfg["observation"] = {"type": observation}
    env = parallel_env(cfg)
    single = gym.make("feat2map/JunctionGrid-v0", config={**map_config("generated"), "traffic_vehicles": 2})
    _, single_info = single.reset(seed=0)
    obs, infos = env.reset(seed=0)
    for _ in range(6):
        obs, rew, term, trunc, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        for a, info in infos.items():
            assert set(single_info) <= set(info)  # the single env's keys (and agent_collision, wait_time)
            assert set(info["violations"]) == set(AGENT_VIOLATIONS)
            assert env.observation_space(a).contains(obs[a])
            assert isinstance(rew[a], float)


@pytest.mark.parametrize("action", ["TargetSpeed", "DiscreteMetaAction"])
def test_an_agents_discrete_action_given_as_an_array_of_one_value_is_that_value(action):
    cfg = {**map_config("generated"), **SMALL, "action": {"type": action}}
    runs = []
    for wrap in (int, lambda k: np.array([k]), np.int64):
        env = parallel_env(cfg)
        env.reset(seed=0)
        run = []
        for t in range(12):
            obs, rew, *_ = env.step({a: wrap((t + n) % 3) for n, a in enumerate(env.agents)})
            run.append((rew, {a: o.tolist() for a, o in obs.items()}))
        runs.append(run)
        env.close()
    assert runs[0] == runs[1] == runs[2]


def test_a_configure_mid_episode_keeps_the_agents_and_their_decisions():
    """A config change between steps (here one that only moves the episode's end) leaves the
    agents on the road holding what they decided: they step on as without it."""
    cfg = {**map_config("generated"), **SMALL}
    runs = []
    for configure in (False, True):
        env = parallel_env(cfg)
        env.reset(seed=0)
        run = [env.step({a: 4 for a in env.agents})[1]]
        if configure:
            env.configure({"duration": 25.0})
        run += [env.step({})[1] for _ in range(5)]  # no new decisions: each holds its last
        runs.append(run)
        env.close()
    assert runs[0] == runs[1] and any(r for r in runs[0][1:])


def test_time_to_collision_predicts_for_each_agents_action_speeds():
    """TimeToCollision, which highway-env computes for the observer's target speeds, is each
    agent's grid over its action's speeds, centred on the one nearest its speed, and sees the
    road users on a collision course."""
    env = parallel_env({**map_config("generated"), **SMALL, "observation": {"type": "TimeToCollision", "horizon": 4}})
    assert env.observation_space("agent_0").shape == (3, 3, 4 * env.world.config["policy_frequency"])
    obs, _ = env.reset(seed=0)
    seen = 0
    for _ in range(15):
        for a in env.agents:
            v = env.view(a).vehicle
            assert v.target_speeds is env.actions.speeds
            assert v.index_to_speed(v.speed_index) == min(env.actions.speeds, key=lambda x: abs(x - v.speed))
            assert env.observation_space(a).contains(obs[a])
            seen += bool(obs[a].any())
        obs, *_ = env.step({a: 5 for a in env.agents})
    assert seen


def test_agents_enter_when_their_place_is_free_and_leave_at_their_goal():
    # 10 agents on the short stubs of one junction: not all fit at the start
    env = parallel_env({**map_config("generated"), "agents": 10, "agent_queue": 1, "traffic_vehicles": 0,
                        "pedestrian_rate": 0.0, "duration": 120.0, "action": {"type": "TargetSpeed"}})
    obs, _ = env.reset(seed=0)
    first = set(env.agents)
    assert 0 < len(first) < 10
    seen, done = set(first), set()
    while env.agents:
        views = {a: env.view(a) for a in env.agents}
        drivers = {a: ScriptedDriver(v) for a, v in views.items()}
        # the scripted driver's acceleration, as the nearest target speed reached by the next decision
        acts = {}
        for a, d in drivers.items():
            v = views[a].vehicle.speed + d.acceleration() * 0.5
            acts[a] = int(np.argmin(np.abs(env.actions.speeds - max(v, 0.0))))
        obs, rew, term, trunc, infos = env.step(acts)
        seen |= set(obs)
        for a in term:
            if term[a]:
                done.add(a)
                assert infos[a]["route_completed"] and not infos[a]["collision"], infos[a]
                assert a not in env.agents
    assert seen - first  # later agents entered
    assert len(done) >= 8  # nearly all reached their goals within the time


def _judged(single: bool, ignore, offset: float, seed: int) -> dict:
    feats = [J(FOUR, "signal", False), J(FOUR, "stop", False)]
    m = feat2map.generate_from_features(feats, seed=0)
    route = []
    for jid in ("J0", "J1"):
        ln = sorted((ln for ln in m.lanes_by_junction[jid] if ln.turn == "none"), key=lambda ln: ln.id)[0]
        route.append((jid, m.lanes[ln.predecessors[0]].road_id, m.lanes[ln.successors[0]].road_id))
    route = route[:1] if "signal" in ignore else route[1:]
    cfg = {"features": [f.to_dict() for f in feats], "traffic_vehicles": 0, "pedestrian_rate": 0.0, "duration": 40.0,
           "signal_offsets": {"J0": offset}, "simulation_frequency": 15, "policy_frequency": 5}
    if single:
        env = gym.make("feat2map/JunctionGrid-v0", config={**cfg, "route": route, "action": DRIVER_ACTION_CONFIG})
        env.reset(seed=seed)
        driver = ScriptedDriver(env, ignore)
        while True:
            _, _, term, trunc, info = env.step(driver.act())
            if term or trunc:
                return {k: info["violations"][k] for k in ("red_light", "stop_sign", "pedestrian_yield")}
    env = parallel_env({**cfg, "agents": 1, "agent_routes": [route],
                        "action": {"type": "ContinuousAction", "acceleration_range": [-8.0, 4.0]}})
    env.reset(seed=seed)
    info = None
    while env.agents:
        driver = ScriptedDriver(env.view("agent_0"), ignore)
        _, _, _, _, infos = env.step({"agent_0": driver.act()})
        info = infos["agent_0"]
    return {k: info["violations"][k] for k in ("red_light", "stop_sign", "pedestrian_yield")}


def test_agent_judge_agrees_with_the_single_env():
    results = []
    for ignore, offset in ((("signal",), 0.0), (("signal",), 12.0), (("signal",), 24.0), (("stop",), 0.0), ((), 0.0)):
        ours, theirs = _judged(False, ignore, offset, 0), _judged(True, ignore, offset, 0)
        assert ours == theirs, (ignore, offset, ours, theirs)
        results.append(ours)
    assert any(r["red_light"] for r in results) and any(r["stop_sign"] for r in results)
    assert results[-1] == {"red_light": 0, "stop_sign": 0, "pedestrian_yield": 0}


def test_agents_crossing_against_the_rules_collide_and_are_told_so():
    m = feat2map.generate_from_features([J(FOUR, "bare", False)], seed=0)
    by_entry = {}
    for ln in sorted(m.lanes_by_junction["J0"], key=lambda ln: ln.id):
        if ln.turn == "none":
            by_entry.setdefault(m.lanes[ln.predecessors[0]].road_id, (ln.predecessors, ln.successors))
    roads = sorted(by_entry)[:2]  # two straight movements from neighbouring legs cross
    routes = [[("J0", r, m.lanes[by_entry[r][1][0]].road_id)] for r in roads]
    env = parallel_env({"features": [J(FOUR, "bare", False).to_dict()], "agents": 2, "agent_routes": routes,
                        "traffic_vehicles": 0, "pedestrian_rate": 0.0, "ego_start_distance": 20.0,
                        "action": {"type": "TargetSpeed"}})
    env.reset(seed=0)
    crashed = {}
    for _ in range(40):
        if not env.agents:
            break
        _, _, term, _, infos = env.step({a: 3 for a in env.agents})  # 5 m/s, nobody yields
        crashed.update({a: i for a, i in infos.items() if i["collision"]})
    if crashed:
        assert all(i["agent_collision"] for i in crashed.values())
    # both went without yielding: the later one into a junction the other holds is judged
    assert crashed or any(i["violations"]["not_yielding"] for i in infos.values())



def test_each_agents_conflict_verdict_is_the_rules_answer_to_it_alone(monkeypatch):
    """The conflict verdicts the env takes for every agent near a junction entry at once
    (`TrafficCore.rows_clear`, the conflict rule's one program) are the rules' `junction_clear`
    asked of each agent alone at that moment; clear and not clear both come up."""
    from feat2map.envs.multi_agent import AgentJudge

    seen = []
    noted = AgentJudge.noted

    def checked(self, clear):
        lane = self.rules.net.lane_ids[self._core.v_lane[self.ego.row]]  # (the lane `note` kept the verdict for)
        assert clear == self.rules.junction_clear(lane, self.ego)
        seen.append(clear)
        noted(self, clear)

    monkeypatch.setattr(AgentJudge, "noted", checked)
    env = parallel_env({**map_config("generated"), "agents": 10, "traffic_vehicles": 6, "duration": 30.0})
    env.reset(seed=1)
    for _ in range(100):
        if not env.agents:
            env.reset(seed=2)
        env.step({a: 3 for a in env.agents})
    assert seen.count(True) > 20 and seen.count(False) > 5, (seen.count(True), seen.count(False))

def test_config_is_strict():
    with pytest.raises(Feat2MapError, match="agent_spacing"):
        parallel_env({"agent_spacing": -1.0})
    with pytest.raises(Feat2MapError, match="trafic_vehicles"):
        parallel_env({"trafic_vehicles": 3})
    with pytest.raises(Feat2MapError, match="config.action.lateral"):
        parallel_env({"action": {"type": "ContinuousAction", "lateral": True}})
    env = parallel_env({**map_config("generated"), "agents": 2, "traffic_vehicles": 0})
    env.reset(seed=0)
    with pytest.raises(Feat2MapError, match="actions"):
        env.step({"agent_9": 0})


def test_batched_kinematics_equals_each_agents_own_observation():
    cfg = {**map_config("generated"), "agents": 8, "traffic_vehicles": 6, "pedestrian_rate": 20.0,
           "observation": {"type": "Kinematics", "vehicles_count": 6, "see_behind": False,
                           "features": ["presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h"],
                           "features_range": {"x": [-50, 50], "y": [-50, 50], "vx": [-10, 10], "vy": [-10, 10]}}}
    env = parallel_env(cfg)
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(2)  # seeded actions: the same episode every run
    checked = pedestrians = 0
    for _ in range(25):
        if not env.agents:
            break
        obs = env._observe(env.agents)  # (step's observations come before traffic respawns)
        pedestrians += bool(env.world.road.objects)
        for a in env.agents:
            own = env.view(a).observation_type.observe()  # the agent's observation alone (a batch of one)
            np.testing.assert_array_equal(obs[a], own)
            checked += 1
        env.step({a: int(rng.integers(env.action_space(a).n)) for a in env.agents})
    assert checked > 50 and pedestrians  # observations with pedestrians in the scene were compared too


def test_info_shortcuts_equal_the_single_env_answers():
    """The agents' shortcuts (next stop line per route position, route_completed once per frame,
    the reward's weighted sum without zero weights) give the single env's values exactly."""
    env = parallel_env({**map_config("generated"), **SMALL, "agents": 10})
    env.reset(seed=4)
    rng = np.random.default_rng(4)
    seen = {"line": 0, "completed": 0, "stop_line": 0}
    for _ in range(120):
        if not env.agents:
            break
        _, rewards, terms, _, infos = env.step({a: int(rng.choice([0, 3, 5, 5])) for a in env.agents})
        control = env.world.control
        for a in env.agents:
            view = env.view(a)
            slow = control.line_ahead(view.vehicle)
            fast = view.next_stop_line()
            assert fast == slow and type(fast[3]) is type(slow[3])
            assert view.route_completed() == MapEnv.route_completed(view)
            seen["line"] += 1
            seen["stop_line"] += slow[0] is not None
        for a, info in infos.items():
            r = info["rewards"]
            c, ac = env.world.config, env.agent_config
            full = sum((ac if k in ("not_yielding", "stop_order") else c)[f"reward_{k}"] * r[k] for k in r)
            assert rewards[a] == float(full)
            seen["completed"] += bool(terms[a] and info["route_completed"])
    assert seen["line"] > 100 and seen["stop_line"] > 20 and seen["completed"] > 0, seen


def test_signal_states_are_worked_out_again_only_when_one_changes_without_swapping_methods(monkeypatch):
    """The signals' states are worked out for every signal at once (`TrafficCore.signal_codes`:
    the phase plans' one program `signal_timing`, which the frames' rule queries and judges and the agents' infos
    read), again only once a signal's state is due to change, never twice at one clock value; at
    every frame each reads as the plan's state at that time, and nothing replaces the traffic
    control's methods while the infos are made."""
    from feat2map.envs import core

    env = parallel_env({**map_config("generated"), **SMALL, "signal_green": 4.0, "signal_amber": 1.0,
                        "signal_all_red": 0.5})
    env.reset(seed=0)
    asked: Counter = Counter()
    swapped: list[str] = []
    codes, info = core.TrafficCore.signal_codes, AgentView.own_info

    def counted(self, *args):
        before = self._signals_timed
        out = codes(self, *args)
        if self._signals_timed is not before:  # worked out again
            asked[tuple(self._signals_timed[0])] += 1
        return out

    def checked(self, *args, **kwargs):
        asked["infos"] += 1
        swapped.extend(set(vars(self.world.control)) & {"signal_state", "signal_states", "line_ahead"})
        return info(self, *args, **kwargs)

    monkeypatch.setattr(core.TrafficCore, "signal_codes", counted)
    monkeypatch.setattr(AgentView, "own_info", checked)
    frames = 0
    for _ in range(60):
        env.step({a: 3 for a in env.agents})
        ctl = env.world.control
        frames += 1
        for sid, plan in ctl.plans.items():
            assert ctl.signal_state(sid) == plan.state(sid, ctl.t)
            assert ctl.signal_change(sid) == pytest.approx(plan.time_to_change(sid, ctl.t), abs=1e-9)
    infos = asked.pop("infos")
    assert 3 <= len(asked) < frames / 2 and max(asked.values()) == 1 and not swapped and infos >= frames


@pytest.mark.parametrize("angles,control", [(FOUR, "stop"), ([0, 90, 180], "bare"), (FOUR, "signal")])
def test_agents_driven_by_the_rules_are_judged_clean(angles, control):
    """Every agent driven by the ScriptedDriver (which asks the same rules) through one junction:
    no collisions, no violation of the agent judge's rules, all reach their goals."""
    env = parallel_env({"features": [J(angles, control, True).to_dict()], "agents": 8, "agent_routes": "coverage",
                        "traffic_vehicles": 2, "pedestrian_rate": 3.0, "duration": 90.0,
                        "action": {"type": "ContinuousAction", "acceleration_range": [-8.0, 4.0]}})
    env.reset(seed=5)
    last = {}
    while env.agents:
        _, _, _, _, infos = env.step({a: ScriptedDriver(env.view(a)).act() for a in env.agents})
        last.update(infos)
    assert len(last) == 8
    for a, info in last.items():
        assert info["route_completed"] and not info["collision"], (a, info)
        assert sum(info["violations"].values()) == 0, (a, info["violations"])


@pytest.mark.parametrize("action, good, bad", [({"type": "TargetSpeed"}, 5, 99),
                                               ({"type": "DiscreteMetaAction"}, 2, 7),
                                               ({"type": "ContinuousAction"}, np.array([1.0], np.float32),
                                                np.array([np.nan], np.float32))])
def test_a_refused_action_applies_no_agents_decision(action, good, bad):
    """Issue 35: one agent's bad action (out of its space, NaN) is refused, naming the agent,
    before any agent's decision is applied: after it, the env steps exactly as a twin that never
    saw the refused step (the agent whose good action came first keeps its earlier decision)."""
    cfg = {**map_config("generated"), "agents": 3, "traffic_vehicles": 2, "pedestrian_rate": 0.0,
           "duration": 30.0, "action": action}
    env, twin = parallel_env(cfg), parallel_env(cfg)
    assert data_equivalence(env.reset(seed=4), twin.reset(seed=4))
    space = env.action_space("agent_0")
    space.seed(0)
    for _ in range(3):
        acts = {a: space.sample() for a in env.agents}
        assert data_equivalence(env.step(acts), twin.step(acts))
    first, second = env.agents[:2]
    with pytest.raises(ValueError, match=rf"^actions\['{second}'\]: must be"):
        env.step({first: good, second: bad})
    for k in range(4):  # the first agent holds its decision in the first step after
        acts = {a: space.sample() for a in env.agents if k or a != first}
        assert data_equivalence(env.step(acts), twin.step(acts)), k


def test_an_agents_view_is_the_ego_task_over_the_shared_world():
    """`env.view(agent)` is the single env's ego task (`EgoTask`) over the agent's vehicle and the
    world's pieces, not a stand-in MapEnv: nothing else of the world's env is reachable through it."""
    env = parallel_env({**map_config("generated"), "agents": 2, "traffic_vehicles": 1})
    env.reset(seed=0)
    env.step({a: 3 for a in env.agents})
    w = env.world
    for a in env.agents:
        view = env.view(a)
        assert isinstance(view, EgoTask) and not isinstance(view, MapEnv)
        assert type(view.vehicle) is ControlledRow and view.vehicle in w.road.vehicles
        assert (view.road, view.net, view.control, view.config) == (w.road, w.net, w.control, w.config)
        assert view.time == w.time and view.rules is w.control and view.unwrapped is view
        assert not any(hasattr(view, k) for k in ("step", "reset", "_spawn_traffic", "steps", "viewer"))


@pytest.mark.parametrize("actions", [[0, 1], "agent_0", None, 3])
def test_actions_that_are_not_a_dict_are_a_clear_error(actions):
    env = parallel_env({**map_config("generated"), "agents": 2, "traffic_vehicles": 0})
    env.reset(seed=0)
    with pytest.raises(ValueError, match=f"^actions: must be a dict agent name -> action, got {type(actions).__name__}"):
        env.step(actions)


@pytest.mark.parametrize("options, where", [("config", "options"), ([1], "options"), ({"config": "abc"},
                                                                                      "options.config")])
def test_reset_options_that_are_not_a_dict_are_a_clear_error(options, where):
    env = parallel_env({**map_config("generated"), "agents": 2, "traffic_vehicles": 0})
    with pytest.raises(ValueError, match=f"^{where}: must be a dict"):
        env.reset(seed=0, options=options)
    assert env.reset(seed=0)[0]  # still usable


def test_worlds_are_independent_copies_of_the_one_world_env():
    """With `worlds` = 3 the agents of world w drive exactly as the one-world env reset with seed
    + w under the same actions (world w's agents renamed), although all worlds share one arrays
    core; PettingZoo's API and seed tests pass; a world whose agents are gone stands still."""
    per = 4
    cfg = {**map_config("generated"), **SMALL, "agents": per, "duration": 15.0}
    env = parallel_env({**cfg, "worlds": 3})
    assert env.possible_agents == [f"agent_{i}" for i in range(3 * per)]
    ones = [parallel_env(cfg) for _ in range(3)]
    outs = [env.reset(seed=5)] + [e.reset(seed=5 + w) for w, e in enumerate(ones)]
    assert len({id(w.road.core) for w in env.worlds}) == 1

    def world_part(out, w):  # the multi-world env's output for world w, named as the one-world env names it
        return tuple({f"agent_{int(a[6:]) - w * per}": v for a, v in part.items() if int(a[6:]) // per == w}
                     for part in out)

    rng = np.random.default_rng(0)
    steps = 0
    while env.agents:
        for w, e in enumerate(ones):
            assert data_equivalence(world_part(outs[0], w), outs[1 + w]), (steps, w)
            assert [a for a in env.agents if int(a[6:]) // per == w] == \
                [f"agent_{int(a[6:]) + w * per}" for a in e.agents]
        acts = {a: int(rng.integers(env.action_space(a).n)) for a in env.agents}
        outs = [env.step(acts)]
        for w, e in enumerate(ones):
            if e.agents:
                outs.append(e.step({f"agent_{int(a[6:]) - w * per}": x for a, x in acts.items()
                                    if int(a[6:]) // per == w}))
            else:  # its episode is over: the world stands still
                outs.append(tuple({} for _ in range(5)))
                assert env.worlds[w].time == e.world.time
        steps += 1
    assert steps >= 10 and not any(e.agents for e in ones)
    parallel_api_test(parallel_env({**cfg, "worlds": 2}), num_cycles=30)
    parallel_seed_test(lambda: parallel_env({**cfg, "worlds": 2}), num_cycles=20)


def test_worlds_with_nobody_on_the_road_step_on():
    """Once every agent of every world has gone (no traffic, no pedestrians), a step moves worlds
    that hold no road user at all: nothing to report, their clocks on."""
    env = parallel_env({**map_config("generated"), "agents": 2, "worlds": 2, "traffic_vehicles": 0,
                        "pedestrian_rate": 0.0, "duration": 5.0})
    env.reset(seed=0)
    while env.agents:
        env.step({a: 1 for a in env.agents})
    before = [w.time for w in env.worlds]
    assert env.step({}) == ({}, {}, {}, {}, {})
    assert all(w.time > t for w, t in zip(env.worlds, before))


def test_worlds_config():
    """A new map at each reset cannot be shared by several worlds; `configure` may change the
    number of worlds (and of agents), making the worlds again."""
    with pytest.raises(Feat2MapError, match="new_map_each_reset"):
        parallel_env({**map_config("generated"), "worlds": 2, "new_map_each_reset": True})
    env = parallel_env({**map_config("generated"), **SMALL, "agents": 2})
    with pytest.raises(Feat2MapError, match="new_map_each_reset"):
        env.configure({"worlds": 2, "new_map_each_reset": True})
    assert len(env.worlds) == 1 and not env.world.config["new_map_each_reset"]  # refused whole
    env.reset(seed=0, options={"config": {"worlds": 3, "agents": 3}})
    assert len(env.worlds) == 3 and len(env.possible_agents) == 9
    assert {env.view(a).world for a in env.agents} <= set(env.worlds)
    env.configure({"worlds": 1})
    assert len(env.worlds) == 1 and env.possible_agents == ["agent_0", "agent_1", "agent_2"]
    with pytest.raises(Feat2MapError, match="config.worlds"):
        parallel_env({"worlds": 0})
