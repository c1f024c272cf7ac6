"""examples/experiments.py: the RQ1 and RQ4 code paths on tiny inputs, bad input, real maps."""
from __future__ import annotations

import importlib.util
import json
import re
import sys
from pathlib import Path

import pytest
from conftest import SHARED_MAPS, shared_map

import feat2map
from feat2map.formats import native

ROOT = Path(__file__).resolve().parents[2]

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def exp():
    spec = importlib.util.spec_from_file_location("experiments", ROOT / "examples" / "experiments.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["experiments"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def tiny_input(tmp_path_factory) -> Path:
    """A four-junction map standing in for San Francisco: 3- and 4-leg signal and stop
    junctions, all with crosswalks, with rotations that differ so the ranges are intervals."""
    J = feat2map.JunctionFeature.make
    m = feat2map.generate_from_features([J([0, 90, 180, 270], "signal", True), J([0, 90, 180], "stop", True),
                                     J([10, 100, 175, 265], "stop", True), J([-20, 70, 200], "signal", True)], seed=0)
    path = tmp_path_factory.mktemp("input") / "tiny.json"
    native.save(m, path)
    return path


def _is_png(p: Path) -> bool:
    return p.is_file() and p.read_bytes()[:8] == PNG_MAGIC


def test_rq1_extracts_generates_and_draws(exp, tiny_input, tmp_path):
    s = exp.Settings(out=tmp_path / "out", docs=tmp_path / "docs", inputs={"san_francisco": tiny_input},
                     seeds=(1, 2, 3), progress=False)
    r = exp.rq1(s)
    space = r["feature_space"]
    assert sorted(space["road_counts"]) == [3, 4]
    assert sorted(space["controls"]) == ["signal", "stop"]
    sf = r["stats"]["San Francisco"]
    assert (sf["junctions"], sf["signal"], sf["stop"], sf["bare"], sf["crosswalk_junctions"]) == (4, 2, 2, 0, 4)
    # one junction per combination of {3, 4} x {signal, stop} x {crosswalk}: 4 per map
    maps = {k: native.load(p) for k, p in r["maps"].items()}
    assert list(maps) == ["M1", "M2", "M3"]
    for name, m in maps.items():
        feats = sorted((j.feature.n_roads, j.feature.control, j.feature.crosswalk) for j in m.junctions.values())
        assert feats == [(3, "signal", True), (3, "stop", True), (4, "signal", True), (4, "stop", True)], name
        assert r["stats"][name]["junctions"] == 4
    rot = [tuple(j.feature.rotation) for m in maps.values() for j in m.junctions.values()]
    assert len(set(rot)) > 4, "three seeds should sample different rotations"
    for pic in ("rq1_sf.png", "rq1_maps.png", "rq1_m1.png", "rq1_m1_junctions.png"):
        assert _is_png(tmp_path / "out" / "rq1" / pic), pic
        assert _is_png(tmp_path / "docs" / pic), pic
        assert (tmp_path / "docs" / pic).stat().st_size < exp.MAX_DOC_PICTURE_BYTES
    table = (tmp_path / "docs" / "rq1.md").read_text()
    assert "| M1 | 1 | 4 (8) |" in table
    saved = json.loads((tmp_path / "out" / "rq1" / "rq1.json").read_text())
    assert saved["stats"]["M2"]["junctions"] == 4


def test_rq4_builds_draws_and_drives_custom_maps(exp, tmp_path):
    s = exp.Settings(out=tmp_path / "out", docs=tmp_path / "docs", max_scenarios=1, progress=False)
    r = exp.rq4(s)
    mega = r["maps"]["mega junction"]["junction_features"]
    assert any(f["n"] == 5 and f["control"] == "signal" and f["crosswalk"] for f in mega)
    one_way = r["maps"]["one-way roads"]["junction_features"]
    assert any({"in", "out"} <= set(f["road_types"]) for f in one_way)
    assert _is_png(tmp_path / "docs" / "rq4_custom.png")
    runs = r["measured"]["maps"]
    assert [x["map"] for x in runs] == [*exp.CUSTOM_SPECS, exp.HIGHWAY_CITY[0]]
    table = (tmp_path / "docs" / "rq4.md").read_text()
    for feature in ("ramp merge", "ramp diverge", "filter lane", "mid-block crosswalk"):  # each, with its lanes
        assert re.search(rf"^\| {feature} \| [1-9]\d* \|", table, flags=re.M), feature
    for x in runs:
        if x["map"] == "road circle":  # no junction manoeuvre: driven as a lap on a lane route
            assert x["junctions"] == 0 and x["routes"] == 0 and "laps" in x["subset"]
            lap = r["maps"]["road circle"]["lap"]
            assert lap["completed"] and not lap["collision"] and not any(lap["violations"].values())
        else:
            assert x["driven"] == 1 and x["routes"] >= 1 and x["lines"] > 0, x["map"]
            assert x["stage_paths"], x["map"]


def test_missing_real_maps_exit_2_naming_them(exp, tmp_path, capsys):
    code = exp.main(["--rq", "3", "--maps", str(tmp_path / "nowhere"), "--out", str(tmp_path / "out"), "--no-docs"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "san_francisco/base_map.bin" in err and "gomentum" in err and "shalun" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("argv", [["--rq", "7"], ["--rq", "x"], ["--budget", "-1"], ["--input", "nowhere=a.bin"]])
def test_bad_arguments_exit_2(exp, argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        code = exp.main(argv + ["--out", str(tmp_path / "o"), "--no-docs", "--maps", str(tmp_path)])
        raise SystemExit(code)
    assert e.value.code == 2
    assert "error" in capsys.readouterr().err


@pytest.mark.real_maps
def test_rq1_on_real_san_francisco(exp, tmp_path):
    shared_map("apollo/san_francisco/base_map.bin")
    r = exp.rq1(exp.Settings(out=tmp_path / "out", docs=None, maps=SHARED_MAPS, progress=False))
    st = r["stats"]["San Francisco"]
    assert st["junctions"] == 91 and st["lanes"] == 1524  # the paper's counts
    assert st["stop"] == 3 and st["bare"] == 0
    assert sorted(r["feature_space"]["controls"]) == ["signal", "stop"]
    assert all(r["stats"][k]["junctions"] == 8 for k in ("M1", "M2", "M3"))  # paper: 8 junctions each


def test_junction_paths_follow_stages_across_scenarios(exp):
    from feat2map.scenarios.rollout import Outcome

    ev = [(0, 0.0, None, "LANE_FOLLOW", "LF"), (1, 0.2, "J1", "TRAFFIC_LIGHT_UNPROTECTED_RIGHT_TURN", "R_S"),
          (5, 1.0, "J1", "TRAFFIC_LIGHT_PROTECTED", "T_A"), (9, 1.8, "J1", "TRAFFIC_LIGHT_PROTECTED", "T_C"),
          (12, 2.4, None, "LANE_FOLLOW", "LF")]
    o = Outcome(name="s", outcome="completed", violations={}, sim_s=3.0, steps=15, stage_path=(), transitions=(),
                junctions=("J1", "J2"), route_progress=1.0, events=tuple(ev))
    paths = exp.junction_paths(o)
    assert [j for j, _ in paths] == ["J1", "J2"]
    lf = "LANE_FOLLOW.LF"
    assert exp.path_label(paths[0][1], lf) == "LF -> R_S -> T_A -> T_C -> LF"
    assert exp.path_label(paths[1][1], lf) == "LF"  # a junction the planner drove in lane following
