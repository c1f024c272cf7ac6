"""Traffic control and traffic: signal phase plans, stop-sign queues, junction reservations from
precomputed conflict tables, crosswalk pedestrians, route-following IDM vehicles, and a `Road`
whose neighbour search and collision checks stay local (lane buckets and a grid hash).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import RoadObject

from ..phases import group_phases, travel_headings  # noqa: F401 (the env's phase grouping, kept importable here)
from .network import MapNetwork

SIGNAL_STATES = ("green", "amber", "red")
STOPPED_SPEED_MPS = 0.3
STOP_ZONE_M = 6.0  # a stop counts when made within this distance of the stop line
COMMIT_DISTANCE_M = 10.0
LOOKAHEAD_M = 60.0
PEDESTRIAN_CORRIDOR_M = 6.0  # beyond the lane half-width, a pedestrian walking towards the lane makes vehicles yield
PEDESTRIAN_IN_PATH_M = 0.6  # beyond the lane half-width, a pedestrian is in the vehicle's path
COLLISION_CELL_M = 10.0
PRIORITY_HORIZON_S = 3.0  # left turns wait for priority traffic this close in time
PEDESTRIAN_CLEARANCE_M = 6.0  # a pedestrian does not step out in front of a vehicle this close
# IDM parameters of our vehicles (own constants: highway-env's envs mutate IDMVehicle's class attributes)
IDM_ACC, IDM_BRAKE, IDM_DELTA, IDM_GAP_M, IDM_TIME_GAP_S = 3.0, 4.0, 4.0, 2.5, 1.2


@dataclass(frozen=True)
class PhasePlan:
    """Fixed-time plan of one signalized junction: each phase (a group of approaches) green in
    turn, then amber, then all-red. Paired phases give opposite approaches green together, with
    left turns unprotected (they yield through the conflict table); single phases protect all."""

    phases: tuple[tuple[str, ...], ...]  # signal ids per phase
    green: float
    amber: float
    all_red: float
    offset: float

    @property
    def cycle(self) -> float:
        return len(self.phases) * (self.green + self.amber + self.all_red)

    def phase_of(self, signal_id: str) -> int:
        return next(i for i, p in enumerate(self.phases) if signal_id in p)

    def state(self, signal_id: str, t: float) -> str:
        slot = self.green + self.amber + self.all_red
        local = (t + self.offset) % self.cycle - self.phase_of(signal_id) * slot
        if 0 <= local < self.green:
            return "green"
        if self.green <= local < self.green + self.amber:
            return "amber"
        return "red"

    def time_to_change(self, signal_id: str, t: float) -> float:
        slot = self.green + self.amber + self.all_red
        local = ((t + self.offset) % self.cycle - self.phase_of(signal_id) * slot) % self.cycle
        for edge in (self.green, self.green + self.amber, self.cycle):
            if local < edge:
                return edge - local
        return 0.0


class Pedestrian(RoadObject):
    """A person walking straight across a crosswalk at constant speed."""

    LENGTH = 0.8
    WIDTH = 0.8

    def __init__(self, road, start: np.ndarray, end: np.ndarray, speed: float, crosswalk_id: str) -> None:
        d = end - start
        super().__init__(road, start.copy(), float(math.atan2(d[1], d[0])), speed)
        self.end = end
        self.crosswalk_id = crosswalk_id
        self.remaining = float(np.hypot(*d))
        self.collidable = True
        self.solid = False
        self.check_collisions = False

    def step(self, dt: float) -> None:
        move = min(self.speed * dt, self.remaining)
        self.position = self.position + move * self.direction
        self.remaining -= move

    @property
    def done(self) -> bool:
        return self.remaining <= 1e-6


class RouteFollower:
    """Mixin: follow an explicit list of map lane ids; re-plan by Dijkstra after a lane change."""

    lane_route: list[str]
    route_pos: int

    def init_route(self, lane_route: list[str]) -> None:
        self.lane_route = list(lane_route)
        self.route_pos = 0
        self.lane_s = 0.0
        self.lane_lat = 0.0
        self.reserved: str | None = None
        net: MapNetwork = self.road.network
        self.target_lane_index = net.index_of[self.lane_route[0]]
        self.route = None

    @property
    def net(self) -> MapNetwork:
        return self.road.network

    def current_lane_id(self) -> str:
        return self.lane_route[self.route_pos]

    def follow_road(self) -> None:
        net = self.net
        lane = net.get_lane(self.target_lane_index)
        s, _ = lane.local_coordinates(self.position)
        if s <= lane.length - 1.0:
            return
        tid = net.id_of[self.target_lane_index]
        if tid != self.lane_route[self.route_pos]:  # changed lane: re-plan from here
            path = self.parallel_route(tid) or net.lane_route(tid, self.lane_route[-1])
            if not path:
                return
            self.lane_route = self.lane_route[:self.route_pos] + path
        if self.route_pos + 1 < len(self.lane_route):
            self.route_pos += 1
            self.target_lane_index = net.index_of[self.lane_route[self.route_pos]]

    def parallel_route(self, start: str) -> list[str]:
        """The rest of the route moved beside itself after a lane change onto `start`: each next
        lane the successor of the previous one on the same road edge ([] where they part, e.g.
        at a junction). Keeps loops round a ring road whose lanes never merge."""
        net = self.net
        m = net.hdmap
        path = [start]
        for lid in self.lane_route[self.route_pos + 1:]:
            edge = net.index_of[lid][:2]
            nxt = next((x for x in m.lanes[path[-1]].successors if x in net.index_of and net.index_of[x][:2] == edge), None)
            if nxt is None:
                return []
            path.append(nxt)
        return path

    def steering_control(self, target_lane_index) -> float:
        """highway-env's lane-following controller (lateral P -> heading P -> steering), in scalar
        math: numpy's clip on scalars dominated the step time."""
        lane = self.road.network.get_lane(target_lane_index)
        s, r = lane.local_coordinates(self.position)
        future_heading = lane.heading_at(s + self.speed * self.TAU_PURSUIT)
        v = self.speed if abs(self.speed) > 1e-2 else 1e-2
        heading_cmd = math.asin(min(max(-self.KP_LATERAL * r / v, -1.0), 1.0))
        heading_ref = future_heading + min(max(heading_cmd, -math.pi / 4), math.pi / 4)
        rate = self.KP_HEADING * ((heading_ref - self.heading + math.pi) % (2 * math.pi) - math.pi)
        slip = math.asin(min(max(self.LENGTH / 2 / v * rate, -1.0), 1.0))
        steer = math.atan(2 * math.tan(slip))
        return min(max(steer, -self.MAX_STEERING_ANGLE), self.MAX_STEERING_ANGLE)

    def on_state_update(self) -> None:
        if self.road:
            hint = getattr(self, "target_lane_index", None) or getattr(self, "lane_index", None)
            self.lane_index, self.lane_s, self.lane_lat = self.road.network.locate(self.position, self.heading, hint)
            self.lane = self.road.network.get_lane(self.lane_index)
            if self.road.record_history:
                self.history.appendleft(self.create_from(self))

    def route_distance_done(self) -> float:
        """Metres driven along the route: lanes behind plus the position on the current one."""
        net = self.net
        done = sum(net.lane_of[l].length for l in self.lane_route[:self.route_pos])
        lane = net.lane_of[self.lane_route[self.route_pos]]
        s, _ = lane.local_coordinates(self.position)
        return done + min(max(s, 0.0), lane.length)

    def route_length(self) -> float:
        return sum(self.net.lane_of[l].length for l in self.lane_route)

    def upcoming(self, horizon: float = LOOKAHEAD_M):
        """(route index, lane id, distance from the vehicle to the lane start, own s on it) ahead."""
        net = self.net
        lane = net.lane_of[self.lane_route[self.route_pos]]
        s, _ = lane.local_coordinates(self.position)
        out = [(self.route_pos, self.lane_route[self.route_pos], -s, s)]
        d = lane.length - s
        for k in range(self.route_pos + 1, len(self.lane_route)):
            if d > horizon:
                break
            lid = self.lane_route[k]
            out.append((k, lid, d, None))
            d += net.lane_of[lid].length
        return out

    def leader_gaps(self) -> list[tuple[float, float]]:
        """(bumper gap, speed) of every road user in the path ahead along the route: on the route's
        lanes, and on junction lanes that diverge from or cross them where they are in the way."""
        net = self.net
        m = net.hdmap
        buckets = self.road.control.buckets
        gaps = []
        for k, lid, d, s_own in self.upcoming():
            lane = net.lane_of[lid]
            others = list(buckets.get(lid, ()))
            ln = m.lanes[lid]
            if ln.junction_id is not None:
                near = set(net.conflicts.get(lid, ()))
                for p in ln.predecessors:
                    near.update(x for x in m.lanes[p].successors if x != lid)
                for x in near:
                    others += [o for o in buckets.get(x, ()) if o not in others]
            for o in others:
                if o is self:
                    continue
                so, ro = lane.local_coordinates(o.position)
                if s_own is not None and so <= s_own:
                    continue
                if abs(ro) > lane.width / 2 + 1.0 or so < -self.LENGTH or so > lane.length + self.LENGTH:
                    continue
                gaps.append(((so - s_own if s_own is not None else d + so) - self.LENGTH, float(getattr(o, "speed", 0.0))))
        return gaps

    def next_junction_lane(self) -> tuple[str | None, str | None, float]:
        """(incoming lane, junction lane, distance to the stop line) of the next junction entry."""
        m = self.net.hdmap
        for k, lid, d, _ in self.upcoming(1e9):
            if k > self.route_pos and m.lanes[lid].junction_id is not None and \
                    m.lanes[self.lane_route[k - 1]].junction_id is None:
                return self.lane_route[k - 1], lid, d
        return None, None, math.inf


class TrafficControl:
    """Signals, stop-sign queues, junction reservations and crosswalk pedestrians of one episode."""

    def __init__(self, net: MapNetwork, rng: np.random.Generator, cfg: dict) -> None:
        self.net = net
        self.t = 0.0
        self.cfg = cfg
        self.rng = rng
        m = net.hdmap
        self.plans: dict[str, PhasePlan] = {}
        by_j: dict[str | None, list] = {}
        for sig in m.signals.values():
            by_j.setdefault(sig.junction_id, []).append(sig)
        self.signals_by_junction = {j: sorted(x.id for x in sigs) for j, sigs in by_j.items()}
        g, a, r = cfg["signal_green"], cfg["signal_amber"], cfg["signal_all_red"]
        for jid in sorted(by_j, key=str):
            phases = group_phases(by_j[jid], cfg["signal_phases"] == "paired", travel_headings(m, by_j[jid]))
            offset = float(rng.uniform(0, len(phases) * (g + a + r)))
            fixed = cfg.get("signal_offsets") or {}  # by junction id, or by any of its signal ids
            key = next((k for k in [jid, *sorted(x.id for x in by_j[jid])] if k is not None and str(k) in fixed), None)
            if key is not None:
                offset = float(fixed[str(key)])
            plan = PhasePlan(phases, g, a, r, offset)
            for phase in phases:
                for sid in phase:
                    self.plans[sid] = plan
        self.stop_queue: dict[str | None, list] = {}
        self.reservations: dict[str, object] = {}
        self.pedestrians: dict[str, list[Pedestrian]] = {}
        self.active_crosswalks: list[str] = []
        self.buckets: dict[str, list] = {}

    # ---- signals ----------------------------------------------------------------------
    def signal_state(self, signal_id: str) -> str:
        plan = self.plans.get(signal_id)
        return plan.state(signal_id, self.t) if plan else "green"

    def signal_states(self, junction_id: str | None = None) -> dict[str, str]:
        """States of one junction's signals (all signals when `junction_id` is None)."""
        if junction_id is None:
            return {sid: self.signal_state(sid) for sid in self.net.hdmap.signals}
        return {sid: self.signal_state(sid) for sid in self.signals_by_junction.get(junction_id, ())}

    # ---- occupancy ----------------------------------------------------------------------
    def occupied(self, lane_id: str, by_other_than=None) -> bool:
        holder = self.reservations.get(lane_id)
        if holder is not None and holder is not by_other_than:
            return True
        return any(v is not by_other_than for v in self.buckets.get(lane_id, ()))

    def junction_clear(self, junction_lane: str, vehicle=None) -> bool:
        """No conflicting junction lane is occupied or reserved, and no vehicle with priority
        (straight/right over left turns) is about to enter one from an approach allowed to go."""
        net = self.net
        mine = net.lane_of[junction_lane].priority
        for c in net.conflicts.get(junction_lane, ()):
            if self.occupied(c, vehicle):
                return False
            if net.lane_of[c].priority <= mine:
                continue
            for p in net.hdmap.lanes[c].predecessors:
                sl = net.stop_lines.get(p)
                if sl is not None and (sl.kind == "stop" or self.signal_state(sl.control_id) == "red"):
                    continue
                if self.about_to_enter(p, c, vehicle, margin=3.0):
                    return False
        return True

    def about_to_enter(self, approach: str, lane_id: str, exclude=None, margin: float = 3.0) -> bool:
        """A route follower on lane `approach` (other than `exclude`) drives into `lane_id` next
        and reaches it within PRIORITY_HORIZON_S at its speed, plus `margin` metres."""
        lane = self.net.lane_of.get(approach)
        for v in self.buckets.get(approach, ()):
            if v is exclude or not isinstance(v, RouteFollower):
                continue
            k = v.route_pos + 1
            if k < len(v.lane_route) and v.lane_route[k] == lane_id:
                d = lane.length - lane.local_coordinates(v.position)[0]
                if d < PRIORITY_HORIZON_S * max(v.speed, 0.0) + margin:
                    return True
        return False

    def stop_queue_allows(self, vehicle, junction_lane: str) -> bool:
        """Arrival order: no earlier vehicle in the junction's queue wants a conflicting lane."""
        jid = self.net.hdmap.lanes[junction_lane].junction_id
        queue = self.stop_queue.get(jid, [])
        if vehicle not in queue:
            return False
        conflicts = self.net.conflicts.get(junction_lane, frozenset())
        for other in queue[:queue.index(vehicle)]:
            _, lane, _ = other.next_junction_lane() if hasattr(other, "next_junction_lane") else (None, None, 0)
            if lane is None or lane in conflicts:
                return False
        return True

    def may_enter(self, vehicle, in_lane: str, j_lane: str, d_line: float, commit: bool = True,
                  ignore: frozenset = frozenset()) -> bool:
        """Whether `vehicle` may drive past the stop line of `in_lane` into `j_lane` now. A
        reservation skips the other checks but not the signal: a vehicle held at the line (e.g. by
        pedestrians) into amber stays there if it can stop, and on red gives its reservation up."""
        sl = self.net.stop_lines.get(in_lane)
        if sl is not None and sl.kind == "signal" and "signal" not in ignore:
            state = self.signal_state(sl.control_id)
            if state == "red":
                if self.reservations.get(j_lane) is vehicle and commit:
                    del self.reservations[j_lane]
                    vehicle.reserved = None
                return False
            if state == "amber" and d_line > vehicle.speed ** 2 / (2 * 3.0) + 1.0:
                return False
        if self.reservations.get(j_lane) is vehicle:
            return True
        if sl is not None and sl.kind == "stop" and "stop" not in ignore:
            if not self.stop_queue_allows(vehicle, j_lane):
                return False
        if "conflict" not in ignore and not self.junction_clear(j_lane, vehicle):
            return False
        if commit and d_line < max(COMMIT_DISTANCE_M, 1.5 * vehicle.speed) and j_lane not in self.reservations:
            self.reservations[j_lane] = vehicle
            vehicle.reserved = j_lane
        return True

    def pedestrian_blocking(self, lane_id: str, s_from: float) -> float | None:
        """s on `lane_id` to stop at for a pedestrian in the lane's path beyond `s_from`, or None."""
        net = self.net
        lane = net.lane_of[lane_id]
        best = None
        for cw, s0, s1 in net.crossings.get(lane_id, ()):
            if s0 < s_from - 0.5:
                continue
            for p in self.pedestrians.get(cw, ()):
                sp, rp = lane.local_coordinates(p.position)
                if not s0 - 2.0 <= sp <= s1 + 2.0:
                    continue
                h = lane.heading_at(sp)
                towards = rp * (p.direction[0] * -math.sin(h) + p.direction[1] * math.cos(h)) < 0
                if abs(rp) < lane.width / 2 + PEDESTRIAN_IN_PATH_M or (
                        towards and abs(rp) < lane.width / 2 + PEDESTRIAN_CORRIDOR_M):
                    stop_at = s0 - 1.0
                    best = stop_at if best is None else min(best, stop_at)
        return best

    def stop_distance(self, vehicle, commit: bool = True, ignore: frozenset = frozenset()) -> float:
        """Distance ahead of `vehicle` where traffic rules make it stop (inf when free to go)."""
        m = self.net.hdmap
        for k, lid, d, s_own in vehicle.upcoming():
            lane_model = m.lanes[lid]
            if s_own is not None:  # the current lane: pedestrians ahead of us on it
                ped = None if "pedestrian" in ignore else self.pedestrian_blocking(lid, s_own)
                if ped is not None:
                    return ped - s_own
                continue
            if lane_model.junction_id is not None and m.lanes[vehicle.lane_route[k - 1]].junction_id is None:
                if not self.may_enter(vehicle, vehicle.lane_route[k - 1], lid, d, commit, ignore):
                    return d - 1.0
            ped = None if "pedestrian" in ignore else self.pedestrian_blocking(lid, 0.0)
            if ped is not None:
                return d + ped
            if lane_model.junction_id is None and k > vehicle.route_pos + 1:
                break
        return math.inf

    # ---- per-step bookkeeping -------------------------------------------------------------
    def update(self, road: "MapRoad", dt: float) -> None:
        self.t += dt
        m = self.net.hdmap
        buckets: dict[str, list] = {}
        for v in road.vehicles:
            lid = self.net.id_of.get(v.lane_index)
            if lid is not None:
                buckets.setdefault(lid, []).append(v)
        self.buckets = buckets
        # release reservations of vehicles that left their junction lane (or the road)
        alive = set(map(id, road.vehicles))
        for lid, v in list(self.reservations.items()):
            on = lid in (self.net.id_of.get(v.lane_index), getattr(v, "lane_route", [None])[getattr(v, "route_pos", 0)])
            passed = hasattr(v, "lane_route") and lid in v.lane_route[:v.route_pos]
            if id(v) not in alive or (passed and not on):
                del self.reservations[lid]
                if getattr(v, "reserved", None) == lid:
                    v.reserved = None
        # stop-sign queues: join after stopping at the line, leave on entering the junction
        def waiting(v) -> bool:
            lid = self.net.id_of.get(v.lane_index)
            return id(v) in alive and lid in m.lanes and m.lanes[lid].junction_id is None

        for jid, queue in list(self.stop_queue.items()):
            self.stop_queue[jid] = [v for v in queue if waiting(v)]
        for v in road.vehicles:
            lid = self.net.id_of.get(v.lane_index)
            sl = self.net.stop_lines.get(lid) if lid else None
            if sl is None or sl.kind != "stop" or v.speed > STOPPED_SPEED_MPS:
                continue
            if 0 <= sl.s - getattr(v, "lane_s", 0.0) <= STOP_ZONE_M:
                q = self.stop_queue.setdefault(sl.junction_id, [])
                if v not in q:
                    q.append(v)
                    v.stopped_at = sl.control_id
        # pedestrians
        rate = self.cfg["pedestrian_rate"] / 60.0
        for cw in self.active_crosswalks:
            peds = [p for p in self.pedestrians.get(cw, ()) if not p.done]
            if rate > 0 and self.rng.uniform() < rate * dt and len(peds) < self.cfg["pedestrians_per_crosswalk"]:
                a, b, width = self.net.crosswalk_axes[cw]
                if self.rng.uniform() < 0.5:
                    a, b = b, a
                d = (b - a) / max(np.hypot(*(b - a)), 1e-9)
                off = np.array([-d[1], d[0]]) * self.rng.uniform(-0.3, 0.3) * width
                if any(np.hypot(*(v.position - a - off)) < PEDESTRIAN_CLEARANCE_M + 3.0 * max(v.speed, 0.0)
                       for v in road.vehicles):
                    self.pedestrians[cw] = peds
                    continue
                speed = float(self.cfg["pedestrian_speed"] * self.rng.uniform(0.85, 1.15))
                p = Pedestrian(road, a + off, b + off, speed, cw)
                peds.append(p)
            self.pedestrians[cw] = peds
        road.objects = [o for o in road.objects if not isinstance(o, Pedestrian)] + \
            [p for cw in self.active_crosswalks for p in self.pedestrians.get(cw, ())]


class MapRoad(Road):
    """A `Road` on a `MapNetwork` with traffic control; local neighbour and collision checks."""

    def __init__(self, network: MapNetwork, control: TrafficControl, np_random, record_history=False) -> None:
        super().__init__(network, [], [], np_random, record_history)
        self.control = control

    def act(self) -> None:
        for v in self.vehicles:
            v.act()

    def step(self, dt: float) -> None:
        for v in self.vehicles:
            v.step(dt)
        for o in self.objects:
            if isinstance(o, Pedestrian):
                o.step(dt)
        self.control.update(self, dt)
        self._collisions(dt)

    def _collisions(self, dt: float) -> None:
        cells: dict[tuple[int, int], list] = {}
        for o in self.vehicles + self.objects:
            key = (int(o.position[0] // COLLISION_CELL_M), int(o.position[1] // COLLISION_CELL_M))
            cells.setdefault(key, []).append(o)
        seen = set()
        for (cx, cy), objs in cells.items():
            near = [o for dx in (-1, 0, 1) for dy in (-1, 0, 1) for o in cells.get((cx + dx, cy + dy), ())]
            for a in objs:
                if not isinstance(a, Vehicle):
                    continue
                for b in near:
                    if b is a or (id(b), id(a)) in seen:
                        continue
                    seen.add((id(a), id(b)))
                    a.handle_collisions(b, dt)

    def neighbour_vehicles(self, vehicle, lane_index=None):
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        net: MapNetwork = self.network
        lid = net.id_of.get(lane_index)
        lane = net.get_lane(lane_index)
        s = lane.local_coordinates(vehicle.position)[0]
        front = rear = None
        sf = sr = None
        cands = [(lid, 0.0)]
        if lid in net.hdmap.lanes:
            cands += [(x, lane.length) for x in net.hdmap.lanes[lid].successors]
            cands += [(x, -net.lane_of[x].length) for x in net.hdmap.lanes[lid].predecessors if x in net.lane_of]
        for cl, off in cands:
            for v in self.control.buckets.get(cl, ()):
                if v is vehicle:
                    continue
                sv = net.lane_of[cl].local_coordinates(v.position)[0] + off
                if sv >= s and (sf is None or sv < sf):
                    sf, front = sv, v
                if sv < s and (sr is None or sv > sr):
                    sr, rear = sv, v
        return front, rear


class TrafficVehicle(RouteFollower, IDMVehicle):
    """An IDM vehicle on its own lane route; stops for signals, stop signs, pedestrians and
    conflicting junction traffic (reservations), following leaders along its route."""

    def __init__(self, road, position, heading=0, speed=0, target_lane_index=None, target_speed=None,
                 route=None, enable_lane_change=False, timer=None):
        super().__init__(road, position, heading, speed, target_lane_index, target_speed, route,
                         enable_lane_change, timer)

    MOBIL_PERIOD_S = 1.0
    MOBIL_GAIN = 0.3  # [m/s2] own acceleration gain that makes a lane change worth it
    MOBIL_SAFE_BRAKE = 3.0  # [m/s2] the new follower must not need to brake harder
    MOBIL_POLITENESS = 0.3

    def act(self, action=None) -> None:
        if self.crashed:
            return
        self.follow_road()
        if self.timer - getattr(self, "_mobil_t", -1e9) >= self.MOBIL_PERIOD_S:
            self._mobil_t = self.timer
            self.mobil_change()
        steering = self.steering_control(self.target_lane_index)
        Vehicle.act(self, {"steering": steering, "acceleration": self.idm_acceleration()})

    def idm_acceleration(self) -> float:
        stop = self.road.control.stop_distance(self)
        return idm(self, self.leader_gaps(), stop)

    def mobil_change(self) -> bool:
        """MOBIL on multi-lane roads: move to a same-direction neighbour lane when it raises the
        acceleration (with politeness) and the new follower stays safe; the route is re-planned
        from that lane by Dijkstra and the change is taken only if it costs no detour."""
        net, m = self.net, self.net.hdmap
        lid = self.lane_route[self.route_pos]
        if lid != net.id_of.get(self.target_lane_index):
            return False
        ln = m.lanes[lid]
        lane = net.lane_of[lid]
        s, _ = lane.local_coordinates(self.position)
        if ln.junction_id is not None or lane.length - s < 30.0 or self.speed < 1.0:
            return False
        remaining = sum(net.lane_of[l].length for l in self.lane_route[self.route_pos:])
        a_cur = idm(self, self.leader_gaps())
        buckets = self.road.control.buckets
        for n in ln.left_neighbors + ln.right_neighbors:
            if n not in m.lanes:
                continue
            goal = m.lanes[self.lane_route[-1]]
            paths = [net.lane_route(n, g) for g in (goal.id,) + goal.left_neighbors + goal.right_neighbors
                     if g in m.lanes]  # any lane of the destination road will do
            paths = [p for p in paths if p and sum(net.lane_of[l].length for l in p) <= remaining + 5.0]
            if not paths:
                continue
            path = min(paths, key=len)
            nl = net.lane_of[n]
            sn, _ = nl.local_coordinates(self.position)
            ahead, behind = [], None
            for o in buckets.get(n, ()):
                so, _ = nl.local_coordinates(o.position)
                if so >= sn:
                    ahead.append((so - sn - self.LENGTH, float(o.speed)))
                elif behind is None or so > behind[0]:
                    behind = (so, o)
            if any(g < 2.0 for g, _ in ahead):
                continue
            a_new = idm(self, ahead)
            follower_cost = 0.0
            if behind is not None:
                so, f = behind
                gap = sn - so - self.LENGTH
                if gap < 2.0 or not isinstance(f, RouteFollower):
                    continue
                a_f = idm(f, [(gap, self.speed)])
                if a_f < -self.MOBIL_SAFE_BRAKE:
                    continue
                follower_cost = max(0.0, idm(f, []) - a_f)
            if a_new - a_cur - self.MOBIL_POLITENESS * follower_cost > self.MOBIL_GAIN:
                self.lane_route = self.lane_route[:self.route_pos] + path
                self.target_lane_index = net.index_of[n]
                self.lane_changes = getattr(self, "lane_changes", 0) + 1
                return True
        return False

    def step(self, dt: float) -> None:
        super().step(dt)
        if self.speed < 0:
            self.speed = 0.0

    @property
    def finished(self) -> bool:
        if self.route_pos < len(self.lane_route) - 1:
            return False
        lane = self.net.lane_of[self.lane_route[-1]]
        return lane.local_coordinates(self.position)[0] >= lane.length - 2.0


class EgoMDPVehicle(RouteFollower, MDPVehicle):
    """The ego under DiscreteMetaAction: MDPVehicle that follows the episode's lane route."""

    def step(self, dt: float) -> None:
        super().step(dt)
        if self.speed < 0 and self.target_speed >= 0:
            self.speed = 0.0


class EgoVehicle(RouteFollower, ControlledVehicle):
    """The ego under ContinuousAction: takes acceleration/steering; when the action type has no
    lateral control, steering follows the route (a lane-keeping assist)."""

    auto_steer = True
    target_speeds = np.array([0.0, 4.5, 9.0])  # for highway-env's TimeToCollision observation

    def index_to_speed(self, index: int) -> float:
        return float(self.target_speeds[index])

    @property
    def speed_index(self) -> int:
        return int(np.argmin(np.abs(self.target_speeds - self.speed)))

    def act(self, action=None) -> None:
        if isinstance(action, dict):
            action = dict(action)
            self.follow_road()
            if self.auto_steer:
                action["steering"] = self.steering_control(self.target_lane_index)
            Vehicle.act(self, action)

    def step(self, dt: float) -> None:
        Vehicle.step(self, dt)
        if self.speed < 0 and self.action.get("acceleration", 0) <= 0:
            self.speed = 0.0


def idm(vehicle, gaps: list[tuple[float, float]], stop_distance: float = math.inf,
        stop_margin: float = 0.5) -> float:
    """IDM acceleration towards the lane speed limit, behind leaders and before a stop point
    (`stop_distance` from the vehicle centre; the front bumper halts `stop_margin` short of it)."""
    net = vehicle.net
    v = max(vehicle.speed, 0.0)
    v0 = max(net.lane_of[vehicle.lane_route[vehicle.route_pos]].speed_limit, 1.0)
    a_max, b = IDM_ACC, IDM_BRAKE
    acc = a_max * (1 - (v / v0) ** IDM_DELTA)
    items = [(g, vl, IDM_GAP_M) for g, vl in gaps]
    if stop_distance < math.inf:
        items.append((stop_distance - vehicle.LENGTH / 2 - stop_margin, 0.0, 0.3))
    for gap, vl, s0 in items:
        s_star = s0 + v * IDM_TIME_GAP_S + v * (v - vl) / (2 * math.sqrt(a_max * b))
        acc = min(acc, a_max * (1 - (v / v0) ** IDM_DELTA - (max(s_star, 0.0) / max(gap, 0.05)) ** 2))
    return min(max(float(acc), -8.0), 6.0)
