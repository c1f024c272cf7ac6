"""The junction-entry question in arrays (`envs/sim/entries.py`): every answer the batch takes
from the arrays is the rules' own answer (`TrafficRules.stop_distance`, asked of that road user
at that moment), in busy batched traffic with signals, stop signs and pedestrians."""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import feat2map  # noqa: F401  (registers the ids)
from feat2map.envs import core

BUSY_BATCH = {"simulation_frequency": 10, "policy_frequency": 5, "traffic_vehicles": 14, "route_junctions": 3,
              "pedestrian_rate": 20}


def test_the_arrays_answer_junction_entries_as_the_rules_do(monkeypatch):
    """Each answer of `TrafficCore._entry_answers` (held at the line, or free to go) equals the
    stop distance the rules give the same road user asked alone right then, before any claim of
    the frame; the arrays answer many entries, held ones and free ones (a conflict, a queue, a
    reservation or an approach that may go left out of the arrays fails it)."""
    answers = []
    entry_answers, rule_stops = core.TrafficCore._entry_answers, core.TrafficCore._rule_stops

    def asked(self, sc, rows, j_lane, in_lane, d_line, held_key, held_row):
        answered, refused, takes = entry_answers(self, sc, rows, j_lane, in_lane, d_line, held_key, held_row)
        self._want = {i: self.roads[self.env[i]].control.stop_distance(self.objs[i])
                      for i in (answered & ~takes).nonzero()[0]}  # (a row that takes a lane answers with its claim)
        return answered, refused, takes

    def stops(self, traffic):
        self._want = {}
        dist = rule_stops(self, traffic)
        answers.extend((float(dist[i]), want) for i, want in self._want.items())
        return dist

    monkeypatch.setattr(core.TrafficCore, "_entry_answers", asked)
    monkeypatch.setattr(core.TrafficCore, "_rule_stops", stops)
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=12, vectorization_mode="vector_entry_point",
                        config=BUSY_BATCH)
    envs.reset(seed=1)
    for _ in range(60):
        envs.step(np.ones(12, dtype=np.int64))
    envs.close()
    got, want = np.array(answers).T
    assert len(answers) > 2000
    assert (want < math.inf).sum() > 200 and (want == math.inf).sum() > 200
    assert got == pytest.approx(want, abs=1e-9)


def test_junction_clear_in_arrays_is_the_rules_junction_clear_for_every_road_user():
    """`entries.junction_clear` of every road user's next junction lane on its scan, whatever its
    distance to the line, equals the rules' `junction_clear` asked of it, in busy batched
    traffic, and again with reservations planted on conflicting lanes (held by another road
    user, by the road user itself, by one that left the road): each of occupancy, reservations
    and road users about to enter a lane of higher priority decides some answers alone."""
    from feat2map.envs.rules import ENTRY
    from feat2map.envs.sim import entries, rule_scan

    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=12, vectorization_mode="vector_entry_point",
                        config=BUSY_BATCH)
    envs.reset(seed=2)
    c = envs.unwrapped.core
    net, rng = c.net, np.random.default_rng(0)
    ids = net.lane_ids
    gone = object()  # a holder that is no road user now
    counts = {"held": 0, "free": 0}
    for step in range(60):
        envs.step(np.ones(12, dtype=np.int64))
        c.refresh_windows()
        sc = rule_scan.scan(c)
        entry = (sc.what & ENTRY) != 0
        rows = (entry.any(axis=1) & c.driven & entries.placed(c)[c.env]).nonzero()[0]
        j = sc.lanes[rows, np.argmax(entry[rows], axis=1)]
        planted = []
        if step % 3 == 0:  # reservations on lanes conflicting with some road users' lanes
            for r, lane in zip(rows[::4].tolist(), j[::4].tolist()):
                ctl = c.roads[c.env[r]].control
                conflicts = sorted(net.conflicts.get(ids[lane], ()))
                if conflicts:
                    x = conflicts[rng.integers(len(conflicts))]
                    if x not in ctl.reservations:
                        holder = [c.objs[r], gone, c.objs[rng.choice(c.slot_rows(int(c.env[r])))]][rng.integers(3)]
                        ctl.reservations[x] = holder
                        planted.append((ctl, x))
        key, row = c.held_reservations()
        got = entries.junction_clear(c, rows, j, key, row, c._approach_held)
        want = [c.roads[c.env[r]].control.junction_clear(ids[lane], c.objs[r]) for r, lane in zip(rows.tolist(), j.tolist())]
        assert got.tolist() == want, f"step {step}"
        counts["held"] += int((~got).sum())
        counts["free"] += int(got.sum())
        for ctl, x in planted:
            del ctl.reservations[x]
    envs.close()
    assert counts["held"] > 300 and counts["free"] > 300


def _first_come_first_served(ctl, vehicle, j_lane: str) -> bool:
    """Stop-sign order as the rules word it, for one road user, from the slot's queue as lists:
    it is queued at the junction of `j_lane`, and no earlier road user in the queue (other than
    one waiting for a narrow passage) drives into a lane conflicting with `j_lane` (its lane in
    the junction: the first on its route from the lane before its route position on; unknown
    holds) that the box rule lets it take."""
    net = ctl.net
    jid = net.hdmap.lanes[j_lane].junction_id
    queue = ctl.stop_queue.get(jid, [])
    if vehicle not in queue:
        return False
    for other in queue[:queue.index(vehicle)]:
        if any(other in w for w in ctl.passage_waiters.values()):
            continue
        route = other.lane_route
        lane = next((x for x in route[max(other.route_pos - 1, 0):] if net.hdmap.lanes[x].junction_id == jid), None)
        if lane is None or lane in net.conflicts.get(j_lane, ()) and ctl.box_clear(other, lane):
            return False
    return True


def test_stop_sign_turns_are_first_come_first_served_for_every_queued_road_user():
    """`stop_signs.turns` (stop-sign order's one program) of every road user in a stop sign's
    queue, for its lane in that junction and for another row's lane, is first come first served
    as the rules word it, in busy batched traffic; the rules ask it of one road user
    (`stop_queue_allows`) and get the same; turns that have come and turns that have not are both
    among the answers."""
    from feat2map.envs.sim import stop_signs

    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=12, vectorization_mode="vector_entry_point",
                        config=BUSY_BATCH)
    envs.reset(seed=3)
    c = envs.unwrapped.core
    ids = c.net.lane_ids
    counts = {"allowed": 0, "refused": 0}
    for _ in range(60):
        envs.step(np.ones(12, dtype=np.int64))
        rows = (c.stop_junction >= 0).nonzero()[0]
        if not len(rows):
            continue
        own = stop_signs.lanes_in(c, rows, c.stop_junction[rows])
        for lanes in (own, np.roll(own, 1)):  # its own lane, and another row's (mostly another junction's)
            ok = lanes >= 0
            r, j = rows[ok], lanes[ok]
            allowed = stop_signs.turns(c, r, j)
            ctl = [c.roads[c.env[x]].control for x in r.tolist()]
            want = [_first_come_first_served(k, c.objs[x], ids[lane]) for k, x, lane in zip(ctl, r.tolist(), j.tolist())]
            asked = [k.stop_queue_allows(c.objs[x], ids[lane]) for k, x, lane in zip(ctl, r.tolist(), j.tolist())]
            assert allowed.tolist() == want == asked
            counts["allowed"] += int(allowed.sum())
            counts["refused"] += int((~allowed).sum())
    envs.close()
    assert counts["allowed"] > 300 and counts["refused"] > 50, counts
