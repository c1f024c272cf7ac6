"""Shared fixtures: generated maps, and the third-party maps in ../shared/maps (skipped when absent)."""
from __future__ import annotations

import copy
import math
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

# Property tests draw new examples every run (CI keeps no example database). Tests that set no count
# of their own (the invariant tests) run 100 examples each under the default "ci" profile and
# 1,500 under "thorough", which FEAT2MAP_LONG_TESTS=1 (the long version of the suite) loads.
LONG_TESTS = os.environ.get("FEAT2MAP_LONG_TESTS") == "1"
settings.register_profile("ci", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", deadline=None, max_examples=1500, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("thorough" if LONG_TESTS else "ci")

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

REPO = Path(__file__).resolve().parents[1]
SHARED_MAPS = Path(os.environ.get("FEAT2MAP_SHARED_MAPS", REPO.parent / "shared" / "maps"))
# the one skip reason of every test that reads the third-party maps
SHARED_MAPS_MISSING = (f"needs the third-party maps at {SHARED_MAPS} (absent here): put that maps/ folder at "
                       "../shared/maps beside the repository or set FEAT2MAP_SHARED_MAPS (README, Command line)")


def straight_piece(road, rid: str, s0: float, length: float):
    """A copy of the OpenDRIVE `road` element (first geometry straight) as its straight piece of
    `length` from `s0`, with id `rid`: fixtures cut exported roads into CARLA-style pieces."""
    from lxml import etree

    g = road.find("planView/geometry")
    x, y, h = (float(g.get(k)) for k in ("x", "y", "hdg"))
    r = copy.deepcopy(road)
    r.attrib.update({"id": rid, "length": repr(length)})
    geo = r.find("planView/geometry")
    geo.remove(geo[0])
    etree.SubElement(geo, "line")
    geo.attrib.update({"x": repr(x + s0 * math.cos(h)), "y": repr(y + s0 * math.sin(h)), "length": repr(length)})
    return r


def shared_map(relative: str) -> Path:
    """Path of a third-party map under ../shared/maps, or skip the test with the reason."""
    path = SHARED_MAPS / relative
    if not path.exists():
        pytest.skip(SHARED_MAPS_MISSING)
    return path


@pytest.fixture(scope="session")
def sf_default_map():
    """The paper's M1-style map: the embedded San Francisco feature space, seed 1."""
    import feat2map

    return feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1)


# maps whose exports other ecosystems' tools check (Lanelet2, CommonRoad): M1, the example specs
# (one-way roads, a 5-leg junction, multi-lane roads), bare junctions, and a map generated from
# the features of a real map (CARLA Town01, skipped when ../shared/maps is absent)
ECOSYSTEM_MAPS = ("m1", "one_way_t", "mega_junction", "multi_lane", "bare", "town01")
BARE_SPEC = {"version": 1, "junctions": [
    {"name": "bare cross", "cell": [0, 0], "control": "bare", "crosswalk": True,
     "sockets": [{"angle": 0, "lanes": 2}, {"angle": 90}, {"angle": 180, "lanes": 2}, {"angle": 270}]},
    {"name": "bare T", "cell": [1, 0], "control": "bare", "sockets": [0, 90, {"angle": 180, "lanes": 2}]}]}


@pytest.fixture(scope="session", params=ECOSYSTEM_MAPS)
def ecosystem_map(request, sf_default_map):
    """(name, HDMap) for each of ECOSYSTEM_MAPS."""
    import feat2map
    from feat2map.extract import extract_junctions, map_feature
    from feat2map.formats import read_map
    from feat2map.spec import build_spec, load_spec, parse_spec

    name = request.param
    if name == "m1":
        return name, sf_default_map
    if name == "bare":
        return name, build_spec(parse_spec(BARE_SPEC))
    if name == "town01":
        junctions = extract_junctions(read_map(shared_map("opendrive/carla_town01/Town01.xodr")))
        return name, feat2map.generate(map_feature(junctions), seed=0)
    return name, build_spec(load_spec(REPO / "examples" / f"{name}.yaml"))
