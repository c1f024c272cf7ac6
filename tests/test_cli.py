"""The command line as a user runs it: outputs, errors, exit codes, nothing half-written."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from feat2map.formats import native
from feat2map.cli import main
from feat2map.features import PAPER_SF_FEATURE_SPACE, FeatureSpace


def test_generate_default_writes_map_features_and_picture(tmp_path, capsys):
    out = tmp_path / "m1"
    assert main(["generate", "--seed", "1", "--out", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["apollo", "features.json", "junctions.png", "map.json", "map.png"]
    m = native.load(out / "map.json")
    assert len(m.junctions) == 8
    assert FeatureSpace.from_json((out / "features.json").read_text()) == PAPER_SF_FEATURE_SPACE
    assert (out / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "8 junctions" in capsys.readouterr().out


def test_extract_round_trips_generated_features(tmp_path, capsys):
    out = tmp_path / "m"
    main(["generate", "--seed", "3", "--out", str(out), "--quiet", "--no-picture"])
    capsys.readouterr()
    assert main(["extract", str(out / "map.json"), "--json", "--out", str(tmp_path / "f.json")]) == 0
    doc = json.loads(capsys.readouterr().out)
    m = native.load(out / "map.json")
    assert len(doc["junctions"]) == len(m.junctions)
    for j in doc["junctions"]:
        want = m.junctions[j["id"]].feature
        assert (j["n_roads"], j["control"], j["crosswalk"]) == (want.n_roads, want.control, want.crosswalk)
        assert j["rotation"] == pytest.approx(list(want.rotation), abs=1e-3)
    assert FeatureSpace.from_json((tmp_path / "f.json").read_text()).road_counts == (3, 4)


def test_generate_from_maps_uses_their_feature_space(tmp_path):
    main(["generate", "--seed", "3", "--out", str(tmp_path / "a"), "--quiet", "--no-picture"])
    assert main(["generate", "--from-maps", str(tmp_path / "a" / "map.json"), "--seed", "4",
                 "--out", str(tmp_path / "b"), "--quiet", "--no-picture"]) == 0
    assert len(native.load(tmp_path / "b" / "map.json").junctions) == 8


@pytest.mark.parametrize("content, message", [
    ('{"road_counts": [3]}', "missing field"),
    ("{not json", "not valid JSON"),
    ('{"road_counts": [2], "controls": ["bare"], "crosswalks": [false], "rotation_ranges": {"2": [[0,1],[90,91]]}}',
     "road counts must be >= 3"),
])
def test_bad_feature_file_fails_cleanly_and_writes_nothing(tmp_path, capsys, content, message):
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    out = tmp_path / "out"
    assert main(["generate", "--features", str(bad), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and message in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("content", [b"", b"\x00\x01garbage", b'{"format": "feat2map-map", "version": 1, "lanes": [{"id": "a"}]}',
                                     b'{"format": "feat2map-map", "version": 1, "lanes": [], "roads": [{"id": "r", "kind": "stub", "right_lanes": ["ghost"]}]}'])
def test_corrupt_map_files_name_the_file(tmp_path, capsys, content):
    bad = tmp_path / "broken.json"
    bad.write_bytes(content)
    assert main(["extract", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "broken.json" in err and "Traceback" not in err


def test_truncated_map_file(tmp_path, capsys, sf_default_map):
    path = tmp_path / "t.json"
    text = native.dumps(sf_default_map)
    path.write_text(text[: len(text) // 2])
    assert main(["extract", str(path)]) == 2
    assert "truncated or corrupt" in capsys.readouterr().err


def test_bad_arguments_exit_2():
    r = subprocess.run([sys.executable, "-m", "feat2map.cli", "generate", "--seed", "x", "--out", "/tmp/never"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "invalid int value" in r.stderr
    r = subprocess.run([sys.executable, "-m", "feat2map.cli", "generate", "--out", "/tmp/never", "--lane-width", "-2"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "lane_width" in r.stderr and "Traceback" not in r.stderr
