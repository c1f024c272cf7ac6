"""The junction-entry question in arrays (`envs/sim/entries.py`): every answer the batch takes
from the arrays is the rules' own answer (`TrafficRules.stop_distance`, asked of that road user
at that moment), in busy batched traffic with signals, stop signs and pedestrians; the conflict
rule and stop-sign order, each one program, answer as the rules word them (rule_specs.py)."""
from __future__ import annotations

import math
from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle

import feat2map  # noqa: F401  (registers the ids)
from feat2map.envs import core
from feat2map.envs.vehicles import RouteFollower
from rule_specs import check_conflict_questions, first_come_first_served, junction_lanes_ahead

BUSY_BATCH = {"simulation_frequency": 10, "policy_frequency": 5, "traffic_vehicles": 14, "route_junctions": 3,
              "pedestrian_rate": 20}


def test_the_arrays_answer_junction_entries_and_crosswalks_as_the_rules_do(monkeypatch):
    """Each answer of `TrafficCore._entry_answers` (held at the line, or free to go) and of
    `_people_answers` (held before a crosswalk with people, or free to go) equals the stop
    distance the rules give the same road user asked alone right then, before any claim of the
    frame; the arrays answer many entries and crosswalks, held ones and free ones (a conflict, a
    queue, a reservation, an approach that may go or a walker left out of the arrays fails it)."""
    answers: dict[str, list] = {"entry": [], "people": []}
    entry_answers, people_answers, rule_stops = (core.TrafficCore._entry_answers, core.TrafficCore._people_answers,
                                                 core.TrafficCore._rule_stops)

    def want(self, kind, rows):  # (a row that takes a lane answers with its claim)
        self._want[kind] = {i: self.roads[self.env[i]].control.stop_distance(self.objs[i])
                            for i in (rows & ~self._takes).nonzero()[0]}

    def asked(self, sc, rows, j_lane, in_lane, d_line):
        answered, refused, takes, crowd = entry_answers(self, sc, rows, j_lane, in_lane, d_line)
        self._takes = takes
        want(self, "entry", answered)
        return answered, refused, takes, crowd

    def people(self, sc, rows, first):
        seen, stop = people_answers(self, sc, rows, first)
        want(self, "people", seen)
        return seen, stop

    def stops(self, traffic):
        self._want, self._takes = {}, np.zeros(len(self.objs), dtype=bool)
        dist = rule_stops(self, traffic)
        for kind, wanted in self._want.items():
            answers[kind].extend((float(dist[i]), w) for i, w in wanted.items())
        return dist

    monkeypatch.setattr(core.TrafficCore, "_entry_answers", asked)
    monkeypatch.setattr(core.TrafficCore, "_people_answers", people)
    monkeypatch.setattr(core.TrafficCore, "_rule_stops", stops)
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=12, vectorization_mode="vector_entry_point",
                        config=BUSY_BATCH)
    envs.reset(seed=1)
    for _ in range(60):
        envs.step(np.ones(12, dtype=np.int64))
    envs.close()
    for kind, least in (("entry", 200), ("people", 50)):
        got, wanted = np.array(answers[kind]).T
        assert (wanted < math.inf).sum() > least and (wanted == math.inf).sum() > least, kind
        assert got == pytest.approx(wanted, abs=1e-9), kind


def test_the_conflict_rule_is_as_worded_in_busy_batched_traffic():
    """`TrafficCore.lanes_clear` (the conflict rule's one program, `entries.junction_clear`) of
    every road user of every slot, and of nobody, for the junction lanes ahead on its route and
    others, with priority and as cross traffic, is the rule as worded, in busy batched traffic,
    and again with reservations planted on conflicting lanes (held by another road user, by the
    road user itself, by one that left the road); every slot asked at once answers the same.
    Each of occupancy, reservations and road users about to enter decides some answers."""
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=12, vectorization_mode="vector_entry_point",
                        config=BUSY_BATCH)
    envs.reset(seed=2)
    c = envs.unwrapped.core
    net, rng, why = c.net, np.random.default_rng(0), Counter()
    gone = object()  # a holder that is no road user now
    for step in range(40):
        envs.step(np.ones(12, dtype=np.int64))
        planted = []
        if step % 3 == 0:  # reservations on lanes conflicting with some road users' lanes
            for r in c.driven.nonzero()[0][::5].tolist():
                ctl = c.roads[c.env[r]].control
                ahead = junction_lanes_ahead(net, c.objs[r])
                conflicts = sorted(net.conflicts.get(ahead[0], ())) if ahead else []
                if conflicts:
                    x = conflicts[rng.integers(len(conflicts))]
                    if x not in ctl.reservations:
                        holder = [c.objs[r], gone, c.objs[rng.choice(c.slot_rows(int(c.env[r])))]][rng.integers(3)]
                        ctl.reservations[x] = holder
                        planted.append((ctl, x))
        check_conflict_questions(c, rng, why)
        for ctl, x in planted:
            del ctl.reservations[x]
    envs.close()
    assert min(why["reserved"], why["occupied"], why["coming"]) > 100 and why["clear"] > 1000, why


class _RouteCarrier(RouteFollower, Vehicle):
    """A road user of user code's own class (a highway-env body driving straight on) that follows
    a lane route: an external row, which the rules read from its object."""

    def __init__(self, road, lane_id: str, s: float, speed: float, route: list[str]) -> None:
        lane = road.network.lane_of[lane_id]
        super().__init__(road, lane.position(s, 0.0), lane.heading_at(s), speed)
        self.init_route(route)


def test_the_conflict_rule_is_as_worded_for_a_steering_ego_and_road_users_user_code_adds():
    """The same for the single env with an ego steered at random and now and then put by user
    code near the end of another junction's approach (a controlled row located off its route
    lane counts where it is), among traffic and road users of user code's own class that carry a
    lane route, driving straight into a junction (external road users: read from their objects)."""
    env = gym.make("feat2map/JunctionGrid-v0", config={
        **BUSY_BATCH, "traffic_vehicles": 10, "action": {"type": "ContinuousAction"}})
    env.reset(seed=4)
    u = env.unwrapped
    net, rng, why = u.net, np.random.default_rng(1), Counter()
    straight = [x for x in net.lane_ids if net.hdmap.lanes[x].junction_id is not None and net.hdmap.lanes[x].turn == "none"]
    for step in range(120):
        if step % 4 == 0:
            into = straight[rng.integers(len(straight))]
            before = net.hdmap.lanes[into].predecessors[0]
            u.road.vehicles.append(_RouteCarrier(u.road, before, net.lane_of[before].length - 12.0, 6.0, [before, into]))
        if step % 4 == 2:  # the ego 3 m before the end of that approach, its route on into the junction
            lane = net.lane_of[before]
            u.vehicle.position = lane.position(lane.length - 3.0, 0.0)
            u.vehicle.heading, u.vehicle.speed = lane.heading_at(lane.length - 3.0), 6.0
            u.vehicle.on_state_update()
            if step % 8 == 2:  # its route position already on the junction lane (located off it)
                u.road.core.reroute(u.vehicle._row, [before, into], 1)
            check_conflict_questions(u.road.core, rng, why)  # (where user code put it)
        _, _, term, trunc, _ = env.step(rng.uniform(-1.0, 1.0, 2).astype(np.float32))
        if term or trunc:
            env.reset(seed=int(step))
        check_conflict_questions(u.road.core, rng, why)
    env.close()
    assert why["off its route lane"] > 50 and why["coming, added by user code"] > 5 and why["coming"] > 200, why


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
            want = [first_come_first_served(k, c.objs[x], ids[lane]) for k, x, lane in zip(ctl, r.tolist(), j.tolist())]
            asked = [k.stop_queue_allows(c.objs[x], ids[lane]) for k, x, lane in zip(ctl, r.tolist(), j.tolist())]
            assert allowed.tolist() == want == asked
            counts["allowed"] += int(allowed.sum())
            counts["refused"] += int((~allowed).sum())
    envs.close()
    assert counts["allowed"] > 300 and counts["refused"] > 50, counts


@pytest.fixture(scope="module")
def signal_bridge(tmp_path_factory):
    """Two 4-way signal junctions with crosswalks joined by road 3, narrowed to a one-lane bridge
    (test_passages.py's bridge): a map with a narrow passage and swept stretches whose traffic
    also meets signals, conflicts and crosswalks with people."""
    from test_passages import BRIDGE_WIDTH_M, TAPER_M, _narrow

    from feat2map.formats.opendrive.writer import write_opendrive

    d = tmp_path_factory.mktemp("signal_bridge")
    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", True)
    write_opendrive(feat2map.generate_from_features([four, four], seed=0), d / "twin.xodr")
    _narrow(d / "twin.xodr", d / "signal_bridge.xodr", "3", BRIDGE_WIDTH_M, TAPER_M)
    return d / "signal_bridge.xodr"


@pytest.mark.parametrize("where", ["grid", "bridge"])
def test_every_row_that_does_not_claim_is_answered_as_the_rules_answer_it(where, signal_bridge, monkeypatch):
    """Each traffic row whose stop distance a frame does not take from a claim (held at a signal's
    line, answered by the arrays at a junction entry or a crosswalk with people, or by its own
    question to the rules) gets the stop distance the rules give that road user asked alone
    before the frame's claims: narrow passages and swept stretches included. On the bridge map a
    row with the passage ahead claims (its place at the passage is part of its claim), and a
    row with a swept stretch in reach asks the rules (they move its stop point out of the
    sweeps): left to the arrays, either would get another answer."""
    claimed: set[int] = set()
    counts: Counter = Counter()
    rule_stops, claim = core.TrafficCore._rule_stops, core.TrafficCore._claim

    def claims(self, rows, sc, dist, enters=None):
        claimed.update(rows)
        return claim(self, rows, sc, dist, enters)

    def stops(self, traffic):
        claimed.clear()
        rows = (traffic & ~self.crashed).nonzero()[0].tolist()
        wanted = {i: self.roads[self.env[i]].control.stop_distance(self.objs[i]) for i in rows}
        dist = rule_stops(self, traffic)
        for i, w in wanted.items():
            if i in claimed:
                counts["claimed"] += 1
                continue
            assert dist[i] == pytest.approx(w, abs=1e-9), (i, self.objs[i].lane_index)
            counts["held" if w < math.inf else "free"] += 1
        return dist

    monkeypatch.setattr(core.TrafficCore, "_claim", claims)
    monkeypatch.setattr(core.TrafficCore, "_rule_stops", stops)
    if where == "grid":
        envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=8, vectorization_mode="vector_entry_point",
                            config=BUSY_BATCH)
    else:
        envs = gym.make_vec("feat2map/MapFile-v0", num_envs=8, vectorization_mode="vector_entry_point",
                            config={**BUSY_BATCH, "map_file": str(signal_bridge), "traffic_vehicles": 10})
        net = envs.unwrapped.core.net
        assert net.passages and net.swept
    envs.reset(seed=1)
    for _ in range(40):
        envs.step(np.ones(8, dtype=np.int64))
    envs.close()
    assert counts["held"] > 200 and counts["free"] > 200 and counts["claimed"] > 20, counts


def test_a_claim_the_arrays_answered_equals_the_claims_walk(monkeypatch):
    """A row the arrays let go into its entry's lane, first to claim in its slot, reserves that lane
    with its chain without walking its route again (`TrafficCore._claim`): step for step, every
    output and every slot's reservations equal those of claiming by the walk; both happen many
    times, and rows after another claimant of their slot walk (a row taking its lane without
    the walk after an earlier claim of its slot fails it)."""
    claim = core.TrafficCore._claim
    kinds: Counter = Counter()

    def counted(self, rows, sc, dist, enters=None):
        slots = [int(self.env[i]) for i in rows]
        for k, (i, s) in enumerate(zip(rows, slots)):
            kinds["taken" if enters and i in enters and s not in slots[:k] else "later" if enters and i in enters
                  else "walked"] += 1
        return claim(self, rows, sc, dist, enters)

    def run(walk: bool) -> list:
        monkeypatch.setattr(core.TrafficCore, "_claim", (lambda self, rows, sc, dist, enters=None:
                                                         claim(self, rows, sc, dist)) if walk else counted)
        envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=8, vectorization_mode="vector_entry_point",
                            config=BUSY_BATCH)
        out, rng = [envs.reset(seed=4)[0]], np.random.default_rng(0)
        for _ in range(100):
            out += [*envs.step(rng.integers(envs.single_action_space.n, size=8))[:4], envs.unwrapped.core.res.copy()]
        envs.close()
        return out

    walked = run(walk=True)
    taken = run(walk=False)
    assert len(taken) == len(walked)
    for a, b in zip(taken, walked):
        np.testing.assert_array_equal(a, b)
    assert kinds["taken"] > 50 and kinds["later"] > 0, kinds
