"""Crosswalk pedestrians (`sim/pedestrians.py`) and the counter-based draws they step out by
(`sim/random.py`): each slot draws on its own, so a sub-env of a batch has the pedestrians of the
single env on its seed; nobody steps out in front of a road user, nor beyond a crosswalk's room;
the yield rule (`sim/crossings.py`, one program) is the rule as worded (rule_specs.py)."""
from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np

import feat2map
from feat2map.config import PEDESTRIAN_CLEARANCE_M, PEDESTRIAN_SPAWN_HORIZON_S
from feat2map.envs.sim import random
from rule_specs import yield_as_worded

J = feat2map.JunctionFeature.make
CONFIG = {"features": [J([0, 90, 180, 270], "signal", True).to_dict(), J([0, 90, 180], "bare", True).to_dict()],
          "traffic_vehicles": 8, "pedestrian_rate": 30.0, "pedestrians_per_crosswalk": 2, "route_junctions": 2,
          "duration": 1e9}


def test_draws_are_a_pure_uniform_function_of_key_counter_stream_and_index():
    keys = np.arange(300, dtype=np.uint64)[:, None]
    u = random.uniform(keys, np.arange(300)[None, :], 0, 1)
    assert u.shape == (300, 300) and 0.0 <= u.min() and u.max() < 1.0
    assert np.array_equal(u, random.uniform(keys, np.arange(300)[None, :], 0, 1))  # no state: the same again
    assert u[7, 11] == random.uniform(7, 11, 0, 1)[0]  # one at a time, the same as in a batch
    # uniform: each tenth of [0, 1) holds 9,000 +- 5 sigma of the 90,000 draws
    counts = np.bincount((u.ravel() * 10).astype(int), minlength=10)
    assert np.all(np.abs(counts - 9000) < 5 * np.sqrt(9000 * 0.9))
    # the streams, indices and neighbouring keys are uncorrelated
    others = [random.uniform(keys, np.arange(300)[None, :], 1, 1), random.uniform(keys, np.arange(300)[None, :], 0, 2),
              random.uniform(keys + np.uint64(1), np.arange(300)[None, :], 0, 1)]
    for v in others:
        assert abs(np.corrcoef(u.ravel(), v.ravel())[0, 1]) < 0.02
        assert not np.array_equal(u, v)


def test_the_wait_for_a_step_out_is_what_a_draw_every_frame_gives():
    """A crosswalk's next step-out comes after a geometric wait (`pedestrians._next`): the number
    of frames until a draw of `chance` a frame first succeeds, drawn once: mean 1 / chance, one
    frame with probability `chance`; none at chance 0."""
    from feat2map.envs.sim.pedestrians import _next

    for chance in (1 / 15, 0.3):
        waits = _next(np.uint64(9), 40, np.arange(40_000), chance) - 40
        assert waits.min() >= 1 and np.all(waits == np.floor(waits))
        assert abs(waits.mean() * chance - 1) < 0.03
        assert abs(np.mean(waits == 1) - chance) < 0.01
        assert abs(np.mean(waits > 10) - (1 - chance) ** 10) < 0.01  # memoryless: P(no success in 10 frames)
    assert np.all(np.isinf(_next(np.uint64(9), 40, np.arange(3), 0.0)))


def _people(env) -> list[tuple[str, float, float]]:
    u = env.unwrapped
    return sorted((p.crosswalk_id, *map(float, p.position)) for ps in u.control.pedestrians.values() for p in ps)


def test_a_sub_envs_pedestrians_are_the_single_envs_on_its_seed():
    """Three sub-envs of a batch and three single envs (a SyncVectorEnv) on the same seeds and
    actions have the same pedestrians at every step, through episode ends and after one sub-env
    alone is reset."""
    n, seeds = 3, [4, 5, 6]
    kwargs = {"num_envs": n, "config": CONFIG}
    batched = gym.make_vec("feat2map/JunctionGrid-v0", vectorization_mode="vector_entry_point", **kwargs)
    singles = gym.make_vec("feat2map/JunctionGrid-v0", vectorization_mode="sync", **kwargs)
    for venv in (batched, singles):
        venv.reset(seed=seeds)
    seen = ends = 0
    for t in range(80):
        if t == 30:  # sub-env 1 starts a new episode while the others walk on
            for venv in (batched, singles):
                venv.reset(seed=[0, 11, 0], options={"reset_mask": np.array([False, True, False])})
        batched.step(np.ones(n, dtype=np.int64))
        _, _, term, trunc, _ = singles.step(np.ones(n, dtype=np.int64))
        ends += int(np.sum(term | trunc))
        for k in range(n):
            people = _people(singles.envs[k])
            assert _people(batched.unwrapped.envs[k]) == people, (t, k)
            seen += len(people)
    assert seen > 50 and ends > 0
    batched.close()
    singles.close()


def test_pedestrians_step_out_clear_of_road_users_and_within_a_crosswalks_room(monkeypatch):
    """Every pedestrian steps out onto an active crosswalk with room (`pedestrians_per_crosswalk`)
    where no road user is within the clearance plus its travel over the spawn horizon, and walks
    the crosswalk to its far end, where it is let go."""
    from feat2map.envs.sim import pedestrians

    step_out = pedestrians._step_out
    out: list = []

    def watched(core, slot, cw, *draws):
        p = step_out(core, slot, cw, *draws)
        if p is not None:
            rows = core.slot_rows(slot)
            reach = PEDESTRIAN_CLEARANCE_M + PEDESTRIAN_SPAWN_HORIZON_S * np.maximum(core.speed[rows], 0.0)
            out.append(np.hypot(core.x[rows] - p.position[0], core.y[rows] - p.position[1]) - reach)
        return p

    monkeypatch.setattr(pedestrians, "_step_out", watched)
    env = gym.make("feat2map/JunctionGrid-v0", config=CONFIG)
    env.reset(seed=2)
    u = env.unwrapped
    core = u.road.core
    let_go = 0
    for _ in range(150):
        before = {id(p): p for ps in u.control.pedestrians.values() for p in ps}
        env.step(1)
        now = {id(p) for ps in u.control.pedestrians.values() for p in ps}
        for cw, ps in u.control.pedestrians.items():
            assert cw in u.control.active_crosswalks and len(ps) <= CONFIG["pedestrians_per_crosswalk"]
        for k in set(before) - now:
            assert before[k].done  # only those across are let go
            let_go += 1
        assert sorted(map(id, core.p_objs)) == sorted(now)  # the walker rows are the people on the road
    assert len(out) > 10 and let_go > 3
    assert min(float(d.min()) for d in out) >= 0.0  # nobody stepped out within a road user's reach
    env.close()


def test_the_yield_rule_is_as_worded_and_the_judge_sees_the_walkers_where_they_are():
    """`pedestrian_blocking` (`sim.crossings.blocking`) of every lane across a crosswalk, from its
    start and from a random place on it, is the yield rule as worded, in a batch with many
    walkers; `walkers_across` (what the judge reads) gives each walker on a crosswalk across a
    lane, at its place seen from the lane. Both held and free answers are many."""
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=4, vectorization_mode="vector_entry_point",
                        config={**CONFIG, "pedestrians_per_crosswalk": 4})
    envs.reset(seed=3)
    core, rng = envs.unwrapped.core, np.random.default_rng(0)
    lanes = [x for x in core.net.lane_ids if x in core.net.crossings]
    held = free = seen = 0
    for _ in range(80):
        envs.step(np.ones(4, dtype=np.int64))
        for road in core.roads:
            ctl = road.control
            if not any(ctl.pedestrians.values()):
                continue
            for lid in lanes:
                for s_from in (0.0, float(rng.uniform(-5.0, 30.0))):
                    want = yield_as_worded(ctl, lid, s_from)
                    assert ctl.pedestrian_blocking(lid, s_from) == want, (lid, s_from)
                    held, free = held + (want is not None), free + (want is None)
                lane, across = core.net.lane_of[lid], core.net.crossings[lid]
                which, s, lat = core.walkers_across(road.slot, lid)
                expect = sorted((k, *lane.local_coordinates(p.position)) for k, (cw, _, _) in enumerate(across)
                                for p in ctl.pedestrians.get(cw, ()))
                assert sorted(zip(which.tolist(), s.tolist(), lat.tolist())) == expect
                seen += len(expect)
    envs.close()
    assert held > 300 and free > 300 and seen > 1000, (held, free, seen)
