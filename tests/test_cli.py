"""The command line as a user runs it: outputs, errors, exit codes, nothing half-written."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from feat2map.atomic import MANIFEST
from feat2map.formats import native
from feat2map.cli import main
from feat2map.features import PAPER_SF_FEATURE_SPACE, FeatureSpace


def test_generate_default_writes_map_features_and_picture(tmp_path, capsys):
    out = tmp_path / "m1"
    assert main(["generate", "--seed", "1", "--out", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted([MANIFEST, "apollo", "features.json", "junctions.png", "map.json",
                                                            "map.png"])
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


def test_generate_from_maps_skips_junctions_it_cannot_build(tmp_path, capsys):
    """A map with a junction whose legs are 8 degrees apart and one with a junction too big for
    a 100 m grid (both built on a wide grid with a small leg separation), next to an ordinary
    map: the two junctions are skipped with a warning naming map and junction, the map is
    generated from the rest; maps of unbuildable junctions only are an error."""
    import dataclasses

    import feat2map
    from feat2map.config import GenerationConfig

    J = feat2map.JunctionFeature.make
    wide = GenerationConfig(grid_gap=260.0)  # the close legs come from the feature's own separation
    maps = {"close": ([J([0, 8, 120, 240], "bare", False, min_separation_deg=5.0)], wide),
            "big": ([J([0, 30, 120, 240], "signal", False, lanes=4)], wide),
            "good": ([J([0, 90, 180, 270], "stop", True), J([0, 90, 180], "signal", False)], GenerationConfig())}
    paths = {}
    for name, (feats, cfg) in maps.items():
        paths[name] = str(tmp_path / f"{name}.json")
        m = feat2map.generate_from_features(feats, seed=1, config=cfg)  # saved as a map read from a file:
        m = dataclasses.replace(m, junctions={k: dataclasses.replace(j, feature=None)  # no recorded feature
                                              for k, j in m.junctions.items()})
        native.save(m, paths[name])
    assert main(["generate", "--from-maps", *paths.values(), "--out", str(tmp_path / "g"),
                 "--quiet", "--no-picture", "--no-apollo"]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("feat2map:")]
    assert len(err) == 2
    assert err[0].startswith(f"feat2map: warning: {paths['close']}: junction J0: sockets 8.00 degrees apart, closer "
                             "than the minimum separation 20.0 degrees")  # the one leg rule, in extraction
    assert err[1].startswith(f"feat2map: warning: {paths['big']}: junction J0: cannot be generated (legs ")
    assert "grid_gap" in err[1] and all(line.endswith("skipped") for line in err)
    space = json.loads((tmp_path / "g" / "features.json").read_text())
    assert space["road_counts"] == [3, 4] and space["controls"] == ["signal", "stop"]
    assert main(["generate", "--from-maps", paths["close"], paths["big"], "--out", str(tmp_path / "h"),
                 "--quiet", "--no-picture"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"feat2map: error: {paths['close']}, {paths['big']}: none of the 1 junction found can be generated"
    assert not (tmp_path / "h").exists()


@pytest.mark.parametrize("content, message", [
    ('{"road_counts": [3]}', "missing field"),
    ("{not json", "not valid JSON"),
    ('{"road_counts": [2], "controls": ["bare"], "crosswalks": [false], "rotation_ranges": {"2": [[0,1],[90,91]]}}',
     "road counts must be 3 to 8"),
])
def test_bad_feature_file_fails_cleanly_and_writes_nothing(tmp_path, capsys, content, message):
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    out = tmp_path / "out"
    assert main(["generate", "--features", str(bad), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and message in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("content", [
    b"", b"\x00\x01garbage", b'{"format": "feat2map-map", "version": 1, "lanes": [{"id": "a"}]}',
    b'{"format": "feat2map-map", "version": 1, "lanes": [], '
    b'"roads": [{"id": "r", "kind": "stub", "right_lanes": ["ghost"]}]}'])
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
    assert r.returncode == 2 and "--seed: must be an integer" in r.stderr
    r = subprocess.run([sys.executable, "-m", "feat2map.cli", "generate", "--out", "/tmp/never", "--lane-width", "-2"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "--lane-width must be" in r.stderr and "Traceback" not in r.stderr


# --- help, version, progress, messages (issue 16) ------------------------------------------------

def _subparsers(parser):
    """(name, parser) of every command and sub-command, depth first."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield name, sub
                yield from ((f"{name} {n}", s) for n, s in _subparsers(sub))


def test_every_option_of_every_command_has_help_and_shows_its_default():
    from feat2map.cli import build_parser

    parser = build_parser()
    commands = dict(_subparsers(parser))
    assert {"generate", "extract", "export", "validate", "suite", "rollout", "coverage"} <= set(commands)
    top = parser.format_help()
    for name in commands:
        if " " not in name:
            assert f"    {name} " in top, f"top-level help does not list {name}"
    for name, sub in commands.items():
        assert sub.description, f"`feat2map {name}` has no description"
        text = " ".join(sub.format_help().split())
        for action in sub._actions:
            if not action.option_strings or action.dest == "help":
                continue
            assert action.help and action.help.strip(), f"`feat2map {name} {action.option_strings[0]}` has no help"
            if not any(action.default is x for x in (None, False)):
                assert "default" in " ".join(action.help.split()) or f"(default: {action.default})" in text, \
                    f"`feat2map {name} {action.option_strings[0]}` does not show its default {action.default!r}"


def test_version(capsys):
    import feat2map

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"feat2map {feat2map.__version__}"


def test_quiet_silences_every_progress_bar(tmp_path, capsys, monkeypatch):
    from feat2map import cli

    monkeypatch.setattr(cli, "on_terminal", lambda: True)  # bars are drawn on a terminal only
    main(["generate", "--seed", "3", "--out", str(tmp_path / "a"), "--quiet", "--no-picture", "--no-apollo"])
    maps = [str(tmp_path / "a" / "map.json")] * 2
    capsys.readouterr()
    assert main(["generate", "--from-maps", *maps, "--out", str(tmp_path / "b"), "--no-picture"]) == 0
    assert "reading maps" in capsys.readouterr().err  # the bar the next run must not show
    for args in (["generate", "--from-maps", *maps, "--out", str(tmp_path / "c")], ["extract", *maps],
                 ["validate", str(tmp_path / "b" / "apollo")]):
        assert main([*args, "--quiet"]) == 0
        assert capsys.readouterr().err == "", args


def test_counts_are_singular_for_one(tmp_path, capsys):
    from pathlib import Path

    spec = Path(__file__).resolve().parents[1] / "examples" / "one_way_t.yaml"
    assert main(["generate", "--spec", str(spec), "--out", str(tmp_path / "t"), "--quiet", "--no-picture"]) == 0
    assert main(["suite", str(tmp_path / "t" / "map.json"), "--out", str(tmp_path / "s.yaml")]) == 0
    out = capsys.readouterr().out
    assert "1 junction," in out and "at 1 map junction (1 with 3 or more arms, as `extract` counts)\n" in out
    assert "junctions" not in out


def test_suite_counts_map_junctions_and_extracted_junctions_apart(tmp_path, capsys):
    """`suite` drives manoeuvres through every junction area of the map, `extract` counts only
    those with 3 or more arms: the suite line gives both, labelled (it said "of 24 junctions"
    where extract reported 10)."""
    import dataclasses

    import feat2map
    from feat2map.formats import native

    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180], "bare", False)], seed=0)
    bend = dataclasses.replace(next(iter(m.junctions.values())), id="bend")  # a 2-arm area: no feature junction
    rid = next(r.id for r in m.roads.values() if r.kind == "stub")
    lanes = {k: dataclasses.replace(v, junction_id="bend") if v.road_id == rid else v for k, v in m.lanes.items()}
    native.save(dataclasses.replace(m, lanes=lanes, junctions={**m.junctions, "bend": bend}), tmp_path / "m.json")
    assert main(["extract", str(tmp_path / "m.json")]) == 0
    assert "\n1 junction (" in capsys.readouterr().out
    assert main(["suite", str(tmp_path / "m.json"), "--out", str(tmp_path / "s.yaml")]) == 0
    assert "at 2 map junctions (1 with 3 or more arms, as `extract` counts)" in capsys.readouterr().out


def test_extract_table_shows_full_paths_and_ids(tmp_path, capsys):
    deep = tmp_path / ("a-rather-long-folder-name-" * 3) / "m"
    main(["generate", "--seed", "3", "--out", str(deep), "--quiet", "--no-picture", "--no-apollo"])
    capsys.readouterr()
    assert main(["extract", str(deep / "map.json")]) == 0
    out = capsys.readouterr().out
    assert f"{deep / 'map.json'}: 8 junctions" in out
    assert all(f"  J{k} " in out for k in range(8))


def test_error_lines_stay_short_and_name_the_file(tmp_path, capsys, sf_default_map):
    """Errors about big inputs quote them at most in part: one line, at most MAX_LINE_CHARS."""
    from feat2map.messages import MAX_LINE_CHARS

    big_map = tmp_path / "map.json"
    big_map.write_text(native.dumps(sf_default_map))
    suite = tmp_path / "suite.json"
    suite.write_text(json.dumps({"version": 1, "name": "s", "scenarios": "x" * 50_000}))  # quoted in the error
    feats = tmp_path / "features.json"
    feats.write_text(json.dumps({"road_counts": [3], "controls": ["x" * 50_000], "crosswalks": [True],
                                 "rotation_ranges": {}}))
    cases = [(["validate", str(big_map)], big_map), (["rollout", str(suite), "--out", str(tmp_path / "r")], suite),
             (["generate", "--features", str(feats), "--out", str(tmp_path / "g")], feats),
             (["export", "apollo", str(suite), "--out", str(tmp_path / "e")], suite)]
    for args, path in cases:
        code = main(args)
        err = capsys.readouterr().err
        assert code == 2, (args, err[:300])
        lines = err.splitlines()
        assert len(lines) == 1 and len(lines[0]) <= MAX_LINE_CHARS + len("feat2map: error: "), (args, len(err))
        assert path.name in lines[0], lines[0]
    r = subprocess.run([sys.executable, "-m", "feat2map.cli", "generate", "--seed", "9" * 100_000, "--out", "x"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1 and len(r.stderr) < 400


def test_one_line_cuts_the_middle():
    from feat2map.messages import counted, one_line

    s = one_line("f.json: element: " + "x" * 10_000 + "\n expected a number", limit=120)
    assert len(s) <= 120 and s.startswith("f.json: element: ") and s.endswith("expected a number")
    assert "characters cut" in s and "\n" not in s
    assert one_line("short\n  text") == "short text"
    assert (counted(1, "junction"), counted(2, "stop sign"), counted(0, "junction")) == \
        ("1 junction", "2 stop signs", "0 junctions")
