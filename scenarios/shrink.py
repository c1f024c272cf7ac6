"""Shrinking failures: the smallest scenario that still fails the same way (the same signature),
as property-based testing shrinks a counterexample. A round drives every smaller neighbour of
each failure at once (fewer traffic vehicles, no pedestrians, the route cut to the failing
junction's manoeuvre, a shorter approach) and keeps, per failure, the smallest neighbour with
the same signature; rounds go on until none does, at most SHRINK_MAX_ROUNDS.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable, Mapping, Sequence, cast

from feat2map.config import SEARCH_EGO_START_M, SHRINK_MAX_ROUNDS

from feat2map.routes import Route, is_lane_route

from .rollout import Outcome
from .scenario import Scenario
from .signature import Signature, signature_of

Evaluate = Callable[[Sequence[Scenario]], Sequence[Outcome]]  # scenarios -> outcomes, in order


def size(sc: Scenario) -> tuple[int, float, int, float]:
    """How big a scenario is: vehicles, pedestrian rate, route manoeuvres, approach length."""
    return (sc.traffic_vehicles, sc.pedestrian_rate, 1 if is_lane_route(sc.route) else len(sc.route),
            float(sc.env.get("ego_start_distance", SEARCH_EGO_START_M[1])))


def neighbours(sc: Scenario, junction: str) -> list[Scenario]:
    """The scenarios one step smaller than `sc`, smallest first; `junction` is where it failed
    (a cut route keeps its manoeuvre there)."""
    out: list[Scenario] = []
    n = sc.traffic_vehicles
    for k in dict.fromkeys((0, n // 2, n - 1)):
        if 0 <= k < n:
            out.append(replace(sc, traffic_vehicles=k))
    if sc.pedestrian_rate > 0:
        out.append(replace(sc, pedestrian_rate=0.0))
    route = () if is_lane_route(sc.route) else cast(Route, sc.route)  # a lane route (a direct-link ramp): one link
    if len(route) > 1:
        at = [i for i, mv in enumerate(route) if mv[0] == junction]
        if at:
            i = at[0]
            cuts = [route[i:i + 1], route[:i + 1], route[i:]]
            out += [replace(sc, route=tuple(c)) for c in cuts if 0 < len(c) < len(route)]
    start = float(sc.env.get("ego_start_distance", SEARCH_EGO_START_M[1]))
    if start > SEARCH_EGO_START_M[0]:
        out.append(replace(sc, env={**dict(sc.env), "ego_start_distance": SEARCH_EGO_START_M[0]}))
    return sorted(dict.fromkeys(out), key=size)


def shrink(failures: Mapping[Signature, tuple[Scenario, Outcome]], evaluate: Evaluate,
           rounds: int = SHRINK_MAX_ROUNDS) -> dict[Signature, tuple[Scenario, Outcome]]:
    """Each failure's smallest scenario found with the same signature, and its outcome; the
    neighbours of every failure still shrinking are driven together (one batch a round)."""
    current = dict(failures)
    active = list(current)
    for _ in range(rounds):
        batch = [(sig, cand) for sig in active
                 for cand in neighbours(current[sig][0], str(current[sig][1].site.get("junction", "")))]
        if not batch:
            break
        outcomes = evaluate([cand for _, cand in batch])
        taken: dict[Signature, tuple[Scenario, Outcome]] = {}
        for (sig, cand), o in zip(batch, outcomes):
            if sig not in taken and signature_of(o) == sig:  # the batch lists each failure's neighbours smallest first
                taken[sig] = (cand, o)
        current.update(taken)
        active = [sig for sig in active if sig in taken]
        if not active:
            break
    return current
