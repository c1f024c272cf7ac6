"""Shared fixtures: generated maps, and the third-party maps in ../shared/maps (skipped when absent)."""
from __future__ import annotations

import copy
import hashlib
import math
import os
import random
import warnings
from pathlib import Path, PurePosixPath
from typing import Callable

import pytest
from hypothesis import HealthCheck, settings
from lxml import etree

from feat2map.extract import extract_junctions

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
SHARED_MAPS_MISSING = (f"needs the third-party maps at {SHARED_MAPS} (absent here): get the public Apollo and "
                       "OpenDRIVE files from the repositories that docs/realmaps.md (Getting the maps) and "
                       "../shared/maps/SOURCES.md list, then put that maps/ folder at ../shared/maps beside the "
                       "repository or set FEAT2MAP_SHARED_MAPS=/path/to/maps")
# the other skip reasons: what is missing and the command that installs it (tests/test_tiers.py checks
# that every skip in tests/ gives one of these or names such a remedy itself)
SKIP_RL = "needs the rl extra (torch, stable-baselines3), not installed: bash scripts/setup.sh dev,rl"
SKIP_RAY = "needs the ray extra (ray), not installed: bash scripts/setup.sh dev,ray"
SKIP_COMMONROAD_IO = ("needs commonroad-io (the CommonRoad export), not installed: bash scripts/setup.sh dev "
                      "(installs it with --no-deps into .venv/commonroad-io)")
SKIP_NETCONVERT = "needs SUMO's netconvert (eclipse-sumo, the dev extra), not found: bash scripts/setup.sh dev"
SKIP_QC_OPENDRIVE = "needs ASAM's qc_opendrive (asam-qc-opendrive), not installed: bash scripts/setup.sh dev"
SKIP_QC_OPENSCENARIO = ("needs ASAM's qc_openscenario (asam-qc-openscenarioxml), not installed: "
                        "bash scripts/setup.sh dev")
SKIP_LANELET2 = ("needs the lanelet2 wheel (the dev extra; wheels exist for Linux x86_64 only), not installed: "
                 "bash scripts/setup.sh dev")
# the public map corpus (docs/realmaps.md's `corpus` section: OpenDRIVE files of 8 tools, SOURCES.md beside them)
CORPUS = Path(os.environ.get("FEAT2MAP_CORPUS", REPO.parent / "corpus"))
CORPUS_MISSING = (f"needs the public map corpus at {CORPUS} (absent here): put the OpenDRIVE files that "
                  "docs/realmaps.md surveys in a folder and set FEAT2MAP_CORPUS=/path/to/corpus")
SKIP_REASONS = (SHARED_MAPS_MISSING, SKIP_RL, SKIP_RAY, SKIP_COMMONROAD_IO, SKIP_NETCONVERT, SKIP_QC_OPENDRIVE,
                SKIP_QC_OPENSCENARIO, SKIP_LANELET2, CORPUS_MISSING)
# the files of ../shared/maps (its SOURCES.md): tests over every real map are parametrized over this
# list, so a checkout without the maps collects the same tests and skips each with SHARED_MAPS_MISSING
SHARED_MAP_FILES = (
    "apollo/autonomous_stuff/base_map.bin", "apollo/borregas_ave/base_map.bin", "apollo/cube_town/base_map.bin",
    "apollo/cube_town/sim_map.txt", "apollo/gomentum/base_map.bin", "apollo/gomentum/sim_map.txt",
    "apollo/san_francisco/base_map.bin", "apollo/shalun/base_map.bin", "apollo/shalun/sim_map.txt",
    "opendrive/carla_town01/Town01.xodr", "opendrive/carla_town02/Town02.xodr",
    "opendrive/carla_town03/Town03.xodr", "opendrive/carla_town04/Town04.xodr",
    "opendrive/carla_town05/Town05.xodr", "opendrive/carla_town06/Town06.xodr",
    "opendrive/commonroad_arg_carcarana/ARG_Carcarana-1_1_T-1.xodr",
    "opendrive/commonroad_four_way_crossing/four_way_crossing.xodr",
    "opendrive/esmini_fabriksgatan/fabriksgatan_traffic_lights.xodr",
    "opendrive/svl_borregas_ave/borregasave.xodr", "opendrive/svl_cubetown/cubetown.xodr",
)


def shared_map_params(*patterns: str, ids: Callable[[str], str] | None = None) -> list:
    """pytest params, one per third-party map matching a glob of `patterns` (relative to SHARED_MAPS,
    in pattern order): the files of SHARED_MAP_FILES and any other file present; a file that is
    absent is still a test, skipped with SHARED_MAPS_MISSING."""
    out = []
    for pattern in patterns:
        present = {str(p.relative_to(SHARED_MAPS)) for p in SHARED_MAPS.glob(pattern)} if SHARED_MAPS.is_dir() else set()
        known = {f for f in SHARED_MAP_FILES if PurePosixPath(f).match(pattern)}
        for rel in sorted(present | known):
            marks = () if rel in present else (pytest.mark.skip(reason=SHARED_MAPS_MISSING),)
            out.append(pytest.param(rel, marks=marks, id=ids(rel) if ids else rel))
    return out


# The test tiers. `pytest -m "not slow"` is the fast tier to run after each change; plain `pytest`
# (CI, scripts/test.sh) runs everything; README.md (Two commands) gives how long each takes.
# SLOW_TESTS are the tests of 8 s or more each under --durations on a loaded 2-core
# machine: whole end-to-end drives, external checkers over many maps, property tests with many
# examples, subprocess and worker-pool runs. An entry is a module or a test function (all its
# parameters); tests/test_tiers.py checks that each names a test that exists.
SLOW_TESTS = (
    "tests/formats/test_apollo_export.py::test_real_sim_maps_report_nothing_their_base_map_does_not",
    "tests/formats/test_apollo_export.py::test_validator_runs_on_real_apollo_maps",
    "tests/formats/test_apollo_export.py::test_validator_survives_any_cleared_fields",
    "tests/formats/test_apollo_export.py::test_real_maps_apollo_exports_validate_and_read_back_clean",
    "tests/formats/test_commonroad.py::test_real_apollo_maps_commonroad_exports_validate_clean",
    "tests/test_atomic.py::test_sigkill_at_random_moments_never_leaves_a_half_written_or_mixed_folder",
    "tests/scenarios/test_bridge.py::test_the_reference_planner_drives_a_suite_through_the_bridge",
    "tests/scenarios/test_bridge_commonroad.py",
    "tests/envs/test_passages.py::test_bridge_map_drives_clean_with_traffic",
    "tests/envs/test_passages.py::test_coincident_lanes_drive_clean_with_traffic",
    "tests/envs/test_vector.py::test_sb3_subproc_vec_env_steps_through_episode_ends",
    "tests/scenarios/test_experiments.py::test_rq1_on_real_san_francisco",
    "tests/scenarios/test_experiments.py::test_rq4_builds_draws_and_drives_custom_maps",
    "tests/test_features.py::test_exact_alignment_matches_brute_force",
    "tests/test_invariants.py::test_random_feature_spaces_of_3_to_8_legs",
    "tests/test_invariants.py::test_random_features_with_one_way_and_multi_lane_legs",
    "tests/test_invariants.py::test_random_specs",
    "tests/scenarios/test_metrics.py::test_coverage_is_stable_for_a_fixed_seed",
    "tests/formats/test_opendrive_asam_qc.py::test_every_check_runs_on_some_revision",
    "tests/formats/test_opendrive_asam_qc.py::test_generated_and_spec_maps_pass_every_check",
    "tests/scenarios/test_planner.py::test_planner_completes_each_junction_type_with_its_stage_path",
    "tests/test_realmaps_script.py",
    "tests/test_reproducible.py::test_generate_export_suite_are_byte_identical_across_runs",
    "tests/test_robustness.py::test_generated_maps_drive_with_traffic_and_pedestrians_without_collision_or_timeout",
    "tests/test_robustness.py::test_real_map_controls_match_its_own_overlaps_and_signals",
    "tests/test_robustness.py::test_real_map_suite_is_not_empty_and_a_sample_drives_clean",
    "tests/scenarios/test_rollout.py::test_a_planner_that_stops_ends_the_rollout_with_the_report_so_far",
    "tests/scenarios/test_rollout.py::test_broken_planner_fails_with_readable_report_and_gif",
    "tests/scenarios/test_rollout.py::test_ray_backend_gives_the_local_results",
    "tests/scenarios/test_rollout_orphans.py",
    "tests/envs/test_train_smoke.py::test_tiny_training_and_success_table",
    "tests/envs/test_ramp_driving.py::test_the_suite_merges_and_diverges_at_every_ramp_and_completes_at_traffic_6",
    "tests/envs/test_ramp_driving.py::test_public_motorway_ramps_are_merged_and_diverged_at_traffic_6",
)


def is_slow(nodeid: str) -> bool:
    """Whether the test `nodeid` ("tests/x.py::test_f[param]") is in SLOW_TESTS."""
    base = nodeid.split("[", 1)[0]
    return any(base == s or base.startswith(s + "::") for s in SLOW_TESTS)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if is_slow(item.nodeid):
            item.add_marker(pytest.mark.slow)


SEED_ENV = "FEAT2MAP_TEST_SEED"
_SEED = pytest.StashKey[int]()


@pytest.fixture
def random_seed(request) -> int:
    """A new seed each run for a randomized test, or FEAT2MAP_TEST_SEED's value; a failing test's
    report says how to rerun it with the same seed (the section "how to reproduce")."""
    raw = os.environ.get(SEED_ENV, "").strip()
    seed = int(raw) if raw else random.randrange(2**32)
    request.node.stash[_SEED] = seed
    return seed


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = (yield).get_result()
    seed = item.stash.get(_SEED, None)
    if seed is not None and report.failed:
        report.sections.append(("how to reproduce", f"{SEED_ENV}={seed} python -m pytest '{item.nodeid}'"))


# the formats a map's features must survive: (format, the file or folder name it is written to)
ROUND_TRIPS = [("native", "m.json"), ("apollo", "apollo"), ("opendrive", "m.xodr")]


def round_trip(m, tmp_path: Path, fmt: str, name: str):
    """`m` written as `fmt` to tmp_path/name and read back (the reader's repair warnings are not
    these tests' subject)."""
    import warnings

    from feat2map.formats import read_map, write_map

    write_map(m, tmp_path / name, fmt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_map(tmp_path / name)


def example_map_file(tmp_path_factory, example: str) -> Path:
    """examples/<example>.yaml built at seed 0 and saved as native JSON in a fresh folder."""
    from feat2map.formats import native
    from feat2map.spec import build_spec, load_spec

    path = tmp_path_factory.mktemp(example) / f"{example}.json"
    native.save(build_spec(load_spec(REPO / "examples" / f"{example}.yaml"), seed=0), path)
    return path


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def numpy_avx512() -> bool:
    """Whether NumPy runs its AVX-512 kernels here: on such a CPU its float64 sin, cos, arctan2...
    (SVML) differ from the other kernels in the last bit now and then, so a map's bytes can differ
    in a coordinate's 16th digit (a generated map is the same map to 1e-14 m either way).
    `NPY_DISABLE_CPU_FEATURES="AVX512F AVX512_SKX ..."` turns them off."""
    from numpy._core._multiarray_umath import __cpu_features__

    return bool(__cpu_features__.get("AVX512_SKX", False))


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


def read_shared_map(relative: str, reader: Callable | None = None):
    """A third-party map read by `reader` (read_map), or skip; the findings its readers warn about
    (the map's own flaws, docs/semantics.md) are expected: each must name the file, none is shown."""
    from feat2map.formats import read_map

    path = shared_map(relative)
    with warnings.catch_warnings(record=True) as found:
        warnings.simplefilter("always")
        m = (reader or read_map)(path)
    assert all(str(path) in str(w.message) for w in found), [str(w.message) for w in found]
    return m


def shared_map(relative: str) -> Path:
    """Path of a third-party map under ../shared/maps, or skip the test with the reason."""
    path = SHARED_MAPS / relative
    if not path.exists():
        pytest.skip(SHARED_MAPS_MISSING)
    return path


def corpus_map(relative: str) -> Path:
    """Path of a public map under the corpus folder (FEAT2MAP_CORPUS), or skip the test with the reason."""
    path = CORPUS / relative
    if not path.exists():
        pytest.skip(CORPUS_MISSING)
    return path


@pytest.fixture(scope="session")
def sf_default_map():
    """The paper's M1-style map: the embedded San Francisco feature space, seed 1."""
    import feat2map

    return feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1)


# maps whose exports other ecosystems' tools check (Lanelet2, CommonRoad): M1, the example specs
# (one-way roads, a 5-leg junction, multi-lane roads, mid-block crosswalks, motorway ramps and links), bare junctions,
# and a map generated from the features of a real map (CARLA Town01, skipped when ../shared/maps is absent)
ECOSYSTEM_MAPS = ("m1", "one_way_t", "mega_junction", "multi_lane", "midblock", "ramps", "motorway_links", "bare",
                  "town01")
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


def export_problems(m, fmt: str, tmp_path: Path) -> list:
    """What format `fmt`'s own checks (`feat2map validate`: the OpenDRIVE one ASAM's qc_opendrive)
    find in map `m` written to `tmp_path`; skips where the format's checker or library is absent."""
    from feat2map.formats import FORMATS, write_map
    from feat2map.formats.asam_qc import OPENDRIVE, find_bundle

    if fmt == "opendrive" and find_bundle(OPENDRIVE[0]) is None:
        pytest.skip(SKIP_QC_OPENDRIVE)
    f = FORMATS[fmt]
    out = tmp_path / ("out" if f.output == "dir" else f"m{f.suffixes[0]}")
    try:
        write_map(m, out, fmt)
        return f.face("validate")(out)
    except ImportError as exc:  # the format's optional library
        pytest.skip(f"needs {exc.name} (bash scripts/setup.sh dev)")


# ---- OpenDRIVE test helpers (tests/formats/test_opendrive.py, test_opendrive_asam_qc.py, test_semantics.py) ----
def largest_gap_tied(angles, tol_deg: float) -> bool:
    a = sorted(x % 360.0 for x in angles)
    gaps = sorted(((a[(i + 1) % len(a)] - a[i]) % 360.0 for i in range(len(a))), reverse=True)
    return gaps[0] - gaps[1] < tol_deg


def assert_same_features(a, b, tol_deg=0.5):
    """Junctions paired by centre: n, control, crosswalk, lanes exact; socket angles within
    `tol_deg`. Where two largest gaps tie (within tol), rotation normalization may start at
    either, so there the absolute socket angles are compared instead."""
    ja, jb = extract_junctions(a), extract_junctions(b)
    assert len(ja) == len(jb)
    for x in ja:
        y = min(jb, key=lambda y: math.dist(x.center, y.center))
        assert math.dist(x.center, y.center) < 0.5
        fx, fy = x.feature, y.feature
        assert (fx.n_roads, fx.control, fx.crosswalk) == (fy.n_roads, fy.control, fy.crosswalk)
        abs_x = [arm.angle_deg for arm in x.arms]
        abs_y = [arm.angle_deg for arm in y.arms]
        for ang in abs_x:  # every socket has a partner within tol (circular distance)
            assert min(abs((ang - o + 180.0) % 360.0 - 180.0) for o in abs_y) < tol_deg
        if not largest_gap_tied(abs_x, tol_deg):
            assert fx.rotation == pytest.approx(fy.rotation, abs=tol_deg)
            assert [(s.lanes_in, s.lanes_out) for s in fx.sockets] == [(s.lanes_in, s.lanes_out) for s in fy.sockets]


def as_another_tools(root):
    """Our OpenDRIVE export, edited to stand for another producer's file: its header names
    another vendor, so the reader applies its rules for other producers (touching junction
    elements are one junction, turns come from geometry) instead of trusting our own marks."""
    root.find("header").set("vendor", "another tool")
    return root


def split_with_a_centimetre_road(src: Path, dst: Path, gap: float = 0.013) -> None:
    """CARLA-style: cut one straight connecting road of the exported junction in three, the
    first part in the junction, a `gap`-long ordinary road, the last part in a second junction
    element (the elements touch, so the reader merges them)."""

    root = as_another_tools(etree.parse(str(src)).getroot())
    jx = root.find("junction")
    con = next(r for r in root.findall("road") if r.get("junction") == jx.get("id")
               and all(abs(float(r.find("planView/geometry/paramPoly3").get(k))) < 1e-9 for k in ("cV", "dV")))
    length = float(con.find("planView/geometry").get("length"))
    ids = ("901", "902", "903")
    parts = [(0.0, length / 2 - gap / 2), (length / 2 - gap / 2, gap), (length / 2 + gap / 2, length / 2 - gap / 2)]
    parent, at = con.getparent(), con.getparent().index(con)
    parent.remove(con)
    for k, (s0, piece) in enumerate(parts):
        r = straight_piece(con, ids[k], s0, piece)
        r.set("junction", (jx.get("id"), "-1", "999")[k])
        lane_link = r.find("lanes/laneSection/right/lane/link")
        if k > 0:
            r.find("link/predecessor").attrib.update({"elementId": ids[k - 1], "contactPoint": "end"})
            lane_link.find("predecessor").set("id", "-1")
        if k < 2:
            r.find("link/successor").attrib.update({"elementId": ids[k + 1], "contactPoint": "start"})
            lane_link.find("successor").set("id", "-1")
        parent.insert(at + k, r)
    next(c for c in jx.findall("connection") if c.get("connectingRoad") == con.get("id")).set("connectingRoad", "901")
    jy = etree.Element("junction", id="999", name="split")
    c = etree.SubElement(jy, "connection", id="0", incomingRoad="902", connectingRoad="903", contactPoint="start")
    etree.SubElement(c, "laneLink", attrib={"from": "-1", "to": "-1"})
    jx.addnext(jy)
    dst.write_bytes(etree.tostring(root))


def mirrored_to_left_hand_traffic(src: Path, dst: Path) -> None:
    """The mirror image (y -> -y) of an OpenDRIVE file feat2map wrote, as left-hand traffic:
    every road `rule="LHT"`, lanes on the other side of their reference lines (ids negated,
    `<left>` and `<right>` swapped), so each lane drives the mirror of its twin's path. A
    right-hand map's mirror is a left-hand map that drives the same way, mirrored."""
    root = as_another_tools(etree.parse(str(src)).getroot())
    negate = {"geometry": ("y", "hdg"), "paramPoly3": ("aV", "bV", "cV", "dV"), "laneOffset": ("a", "b", "c", "d"),
              "laneLink": ("from", "to"), "validity": ("fromLane", "toLane"), "signal": ("t",),
              "object": ("t", "hdg"), "cornerLocal": ("v",), "lane": ("id",)}
    for el in root.iter():
        if not isinstance(el.tag, str):
            continue
        for attr in negate.get(el.tag, ()):
            if el.get(attr) is not None:
                el.set(attr, repr(-float(el.get(attr))) if "." in el.get(attr) or "e" in el.get(attr)
                       else str(-int(el.get(attr))))
        if el.tag in ("predecessor", "successor") and el.getparent().getparent().tag == "lane":
            el.set("id", str(-int(el.get("id"))))
    for road in root.findall("road"):
        road.set("rule", "LHT")
        for sec in road.iter("laneSection"):
            for side in sec:
                if side.tag in ("left", "right"):
                    side.tag = "right" if side.tag == "left" else "left"
                    side[:] = sorted(side, key=lambda ln: -int(ln.get("id")))
            sec[:] = sorted(sec, key=lambda el: ("left", "center", "right").index(el.tag))
    etree.ElementTree(root).write(str(dst), xml_declaration=True, encoding="UTF-8")



def _one_lane_road_lane(lid: str, pts, preds=(), succs=(), widths=3.5):
    """A lane `lid` (its own road) along `pts`, `widths` wide (one value or one per point),
    boundaries offset along the centreline's normals: as a map read from Apollo holds it."""
    import numpy as np

    from feat2map.model import Lane

    p = np.asarray(pts, dtype=float)
    d = np.gradient(p, axis=0)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    half = np.broadcast_to(np.asarray(widths, dtype=float), len(p))[:, None] / 2

    def pl(q) -> tuple:
        return tuple((float(x), float(y)) for x, y in q)
    return Lane(lid, lid, pl(p), pl(p + half * n), pl(p - half * n), float(np.mean(half) * 2), 10.0, tuple(preds),
                tuple(succs))


def _one_lane_roads_map(lanes):
    from feat2map.model import HDMap, Road

    return HDMap({ln.id: ln for ln in lanes}, {ln.id: Road(ln.id, "chain", (ln.id,)) for ln in lanes}, {})


def split_and_merge_map():
    """One-lane roads (no reference curves, as maps read from Apollo have) outside any junction:
    lane a splits into b (straight on) and c (bending away), and lanes g and h merge into i."""
    import numpy as np

    lane = _one_lane_road_lane
    u = np.linspace(0.0, 1.0, 11)[:, None]
    bend = np.hstack([50 + 50 * u, -10 * u ** 2])  # leaves a's end along its heading
    return _one_lane_roads_map([
        lane("a", [(0, 0), (50, 0)], succs=("b", "c")), lane("b", [(50, 0), (100, 0)], preds=("a",)),
        lane("c", bend, preds=("a",)), lane("g", [(0, -40), (50, -40)], succs=("i",)),
        lane("h", bend[::-1] * (-1, 1) + (100, -40), succs=("i",)), lane("i", [(50, -40), (100, -40)], preds=("g", "h"))])


def uneven_seams_map():
    """One-lane roads whose source cross-sections differ where they meet (a coarse Apollo
    junction lane is 4 m wide at its start, its feeder 3.5 m at its end): b continues a but
    starts 4 m wide; h, merging into i beside g, ends 4 m wide."""
    lane = _one_lane_road_lane
    return _one_lane_roads_map([
        lane("a", [(0, 0), (50, 0)], succs=("b",)),
        lane("b", [(50, 0), (70, 0), (90, -10)], preds=("a",), widths=(4.0, 3.8, 3.5)),
        lane("g", [(0, -40), (50, -40)], succs=("i",)),
        lane("h", [(0, -60), (30, -45), (50, -40)], succs=("i",), widths=(3.5, 3.7, 4.0)),
        lane("i", [(50, -40), (100, -40)], preds=("g", "h"))])


def keyhole_uturn_map():
    """One lane, 3.5 m wide, turning round on a 5 m circle (300 degrees of it, 2 m lead-in and
    lead-out) so that its ends lie 1.5 m apart: its inner (left) border crosses itself where
    the ends meet, as GoMentum's U-turns do."""
    import numpy as np

    ang = np.radians(np.linspace(-60.0, 240.0, 31))
    arc = np.stack([5 * np.cos(ang), 5 + 5 * np.sin(ang)], axis=1)
    h0, h1 = math.radians(30.0), math.radians(-30.0)
    lead_in = arc[0] - 2 * np.array([math.cos(h0), math.sin(h0)])
    lead_out = arc[-1] + 2 * np.array([math.cos(h1), math.sin(h1)])
    return _one_lane_roads_map([_one_lane_road_lane("u", np.vstack([lead_in, arc, lead_out]))])


def crossed_merges_map():
    """Back-to-back junctions as GoMentum has them: junction 1's lanes x and y end at one point,
    each leading into both of junction 2's lanes a and b, all four at different headings (each
    of a and b merges x and y; each of x and y forks into a and b)."""
    from dataclasses import replace

    from feat2map.model import Junction, Road

    lane = _one_lane_road_lane
    inside = {"x": "1", "y": "1", "a": "2", "b": "2"}
    lanes = [replace(ln, junction_id=inside.get(ln.id)) for ln in (
        lane("p", [(0, -12), (30, -6)], succs=("x",)), lane("q", [(0, 12), (30, 6)], succs=("y",)),
        lane("x", [(30, -6), (40, -2.5), (50, 0)], preds=("p",), succs=("a", "b")),
        lane("y", [(30, 6), (40, 2.5), (50, 0)], preds=("q",), succs=("a", "b")),
        lane("a", [(50, 0), (60, 3.5), (70, 8)], preds=("x", "y"), succs=("u",)),
        lane("b", [(50, 0), (60, -3.5), (70, -8)], preds=("x", "y"), succs=("v",)),
        lane("u", [(70, 8), (100, 20)], preds=("a",)), lane("v", [(70, -8), (100, -20)], preds=("b",)))]
    m = _one_lane_roads_map(lanes)
    roads = {rid: Road(rid, "junction", (rid,), junction_id=inside[rid]) if rid in inside else r
             for rid, r in m.roads.items()}
    return replace(m, roads=roads, junctions={"1": Junction("1", ((30, -8), (50, -8), (50, 8), (30, 8))),
                                             "2": Junction("2", ((50, -10), (70, -10), (70, 10), (50, 10)))})


def turned_link_map():
    """One-lane roads 9 m wide (SVL Borregas Ave's flared junction lanes): lane a runs east and
    its successor b starts turned 25 degrees clockwise about a's left end point, so the left
    boundaries meet and the right ones miss each other by 3.9 m."""
    import numpy as np

    lane = _one_lane_road_lane
    h = math.radians(-25.0)
    d, n = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
    start = np.array([20.0, 4.5]) - 4.5 * n  # b's centre: half its width right of a's left end
    return _one_lane_roads_map([lane("a", [(0, 0), (10, 0), (20, 0)], succs=("b",), widths=9.0),
                                lane("b", [start + k * d for k in (0.0, 15.0, 30.0)], preds=("a",), widths=9.0)])


def adjacent_junctions_map():
    """Two junctions side by side with no road between (as in Apollo's Gomentum map): junction
    lane b (junction 1) continues straight into junction lane c (junction 2), which lane f, fed
    from an ordinary road, crosses."""
    from dataclasses import replace

    from feat2map.model import Junction, Road

    lane = _one_lane_road_lane
    inside = {"b": "1", "c": "2", "f": "2"}
    lanes = [replace(ln, junction_id=inside.get(ln.id)) for ln in (
        lane("a", [(0, 0), (40, 0)], succs=("b",)), lane("b", [(40, 0), (50, 0)], preds=("a",), succs=("c",)),
        lane("c", [(50, 0), (60, 0)], preds=("b",), succs=("d",)), lane("d", [(60, 0), (100, 0)], preds=("c",)),
        lane("e", [(55, -50), (55, -10)], succs=("f",)), lane("f", [(55, -10), (55, 10)], preds=("e",), succs=("g",)),
        lane("g", [(55, 10), (55, 50)], preds=("f",)))]
    m = _one_lane_roads_map(lanes)
    roads = {rid: Road(rid, "junction", (rid,), junction_id=inside[rid]) if rid in inside else r
             for rid, r in m.roads.items()}
    return replace(m, roads=roads, junctions={"1": Junction("1", ((40, -5), (50, -5), (50, 5), (40, 5))),
                                             "2": Junction("2", ((50, -10), (60, -10), (60, 10), (50, 10)))})


def merge_at_junction_entry_map():
    """Lane x enters junction 1 and forks into s0 (turning 10 degrees left) and s1; lane y enters
    at the same point and merges into s0 too: s0, with two predecessors, keeps its own start, so
    x must end along it."""
    from dataclasses import replace

    from feat2map.model import Junction, Road

    lane = _one_lane_road_lane
    inside = {"s0", "s1"}
    lanes = [replace(ln, junction_id="1" if ln.id in inside else None) for ln in (
        lane("x", [(0, 0), (50, 0)], succs=("s0", "s1")), lane("y", [(20, -30), (50, 0)], succs=("s0",)),
        lane("s0", [(50, 0), (60, 1.763), (70, 3.527)], preds=("x", "y"), succs=("u",)),
        lane("s1", [(50, 0), (60, -5.774), (70, -11.547)], preds=("x",), succs=("v",)),
        lane("u", [(70, 3.527), (100, 8.817)], preds=("s0",)), lane("v", [(70, -11.547), (100, -28.868)], preds=("s1",)))]
    m = _one_lane_roads_map(lanes)
    roads = {rid: Road(rid, "junction", (rid,), junction_id="1") if rid in inside else r for rid, r in m.roads.items()}
    return replace(m, roads=roads, junctions={"1": Junction("1", ((50, -15), (70, -15), (70, 15), (50, 15)))})


def fork_into_junction_and_road_map():
    """Lane a forks into junction lane j (junction 1) and ordinary lane b, which lane c merges
    into as well: a's end belongs to the junction, so b and c meet by a plain road link."""
    from dataclasses import replace

    from feat2map.model import Junction, Road

    lane = _one_lane_road_lane
    lanes = [replace(ln, junction_id="1" if ln.id == "j" else None) for ln in (
        lane("a", [(0, 0), (50, 0)], succs=("j", "b")), lane("j", [(50, 0), (60, 5)], preds=("a",)),
        lane("b", [(50, 0), (100, 0)], preds=("a", "c")), lane("c", [(0, -20), (50, 0)], succs=("b",)))]
    m = _one_lane_roads_map(lanes)
    return replace(m, roads={**m.roads, "j": Road("j", "junction", ("j",), junction_id="1")},
                   junctions={"1": Junction("1", ((50, -5), (60, -5), (60, 10), (50, 10)))})
