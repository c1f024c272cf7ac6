"""Issue 25's rough edges, each as a user meets it: messages that name the culprit (file, option,
command), terminal-only output, export outputs that validate, output folders recognised safely."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from feat2map.cli import main

REPO = Path(__file__).resolve().parents[1]


def one_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


@pytest.fixture(scope="module")
def small_map(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("m") / "m"
    assert main(["generate", "--seed", "3", "--out", str(out), "--no-apollo", "--no-picture", "--quiet"]) == 0
    return out / "map.json"


def test_a_spec_config_over_a_limit_names_the_file(tmp_path, capsys):
    spec = tmp_path / "big.yaml"
    spec.write_text("config: {samples_per_combination: 1000000}\njunctions:\n"
                    "  - sockets: [{angle: 0}, {angle: 90}, {angle: 180}]\n")
    assert main(["generate", "--spec", str(spec), "--out", str(tmp_path / "o")]) == 2
    err = one_error(capsys)
    assert f"{spec}: config: config field 'samples_per_combination' is 1000000, above the limit" in err


@pytest.mark.parametrize("argv, text", [
    (["--grid-gap", "-5"], "command line: --grid-gap must be at least 20, got -5.0"),
    (["--samples-per-combination", "100000000"], "command line: --samples-per-combination is 100000000, above"),
])
def test_generate_options_are_named_as_options(tmp_path, capsys, argv, text):
    assert main(["generate", "--out", str(tmp_path / "o"), *argv]) == 2
    err = one_error(capsys)
    assert text in err and "config field" not in err


@pytest.mark.parametrize("fmt, out", [("apollo", "a"), ("lanelet2", "m.osm"), ("commonroad", "m.xml")])
def test_an_absurd_origin_names_the_option(tmp_path, capsys, small_map, fmt, out):
    assert main(["export", fmt, str(small_map), "--origin", "1e300", "1e300", "--out", str(tmp_path / out)]) == 2
    assert one_error(capsys).startswith("feat2map: error: --origin: easting and northing must be finite")
    assert not (tmp_path / out).exists()


def test_an_unknown_option_gets_its_command_and_the_nearest_option(tmp_path, capsys):
    with pytest.raises(SystemExit) as ex:
        main(["generate", "--sed", "2", "--out", str(tmp_path / "o")])
    assert ex.value.code == 2
    assert one_error(capsys) == "feat2map generate: error: unrecognized arguments: --sed 2 (did you mean --seed?)"
    with pytest.raises(SystemExit):
        main(["export", "apollo", "m.json", "--out", "x", "--orign", "1", "2"])
    assert one_error(capsys).startswith("feat2map export apollo: error: unrecognized arguments: --orign 1 2 "
                                        "(did you mean --origin?)")
    with pytest.raises(SystemExit):
        main(["generate", "--out", "x", "--bogus"])
    assert "did you mean" not in one_error(capsys)


@pytest.mark.parametrize("command", ["extract", "validate"])
def test_a_plain_text_file_is_not_blamed_on_apollo_nor_quoted(tmp_path, capsys, command):
    """Issue 35: the error names the file and what a .txt map is, never the file's content."""
    notes = tmp_path / "notes.txt"
    notes.write_text("hello world, my password is hunter2\n")
    assert main([command, str(notes)]) == 2
    err = one_error(capsys)
    assert f"{notes}: not a map feat2map reads" in err and "Apollo protobuf text" in err and "broken Apollo" not in err
    assert "hello" not in err and "hunter2" not in err


@pytest.mark.parametrize("text", ['header {\n  version: hunter2\n}\n',
                                  'header { version: "1" }\nlane { central_curve { segment { line_segment { '
                                  'point { x: hunter2 } } } } }\n'])
def test_an_apollo_text_parse_error_gives_its_position_not_the_token(tmp_path, capsys, text):
    bad = tmp_path / "bad.txt"
    bad.write_text(text)
    assert main(["extract", str(bad)]) == 2
    err = one_error(capsys)
    assert "broken Apollo map text (line" in err and "hunter2" not in err


def test_an_xodr_parse_error_gives_its_position_once(tmp_path, capsys):
    bad = tmp_path / "bad.xodr"
    bad.write_text('<OpenDRIVE><header/><road id="1"\n')
    assert main(["extract", str(bad)]) == 2
    err = one_error(capsys)
    assert err.count("line 2") == 1 and "malformed XML" in err, err


def test_help_shows_limits_as_whole_numbers(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "max_file_bytes=2147483648" in out and "e+0" not in out


def test_a_non_utf8_file_name_in_a_picture_title_is_drawn(tmp_path, capsys, small_map):
    folder = tmp_path / b"ma\xffp".decode("utf-8", "surrogateescape")
    assert main(["export", "apollo", str(small_map), "--out", str(folder)]) == 0
    picture = tmp_path / "problems.png"
    assert main(["validate", str(folder), "--picture", str(picture), "--quiet"]) == 0
    assert picture.read_bytes().startswith(b"\x89PNG") and "Traceback" not in capsys.readouterr().err


def test_extract_out_writes_the_feature_and_prints_no_json(tmp_path, capsys, small_map):
    out = tmp_path / "f.json"
    assert main(["extract", str(small_map), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "{" not in printed and f"map feature written to {out}" in printed
    assert json.loads(out.read_text())["road_counts"]
    assert main(["extract", str(small_map)]) == 0
    shown = json.loads(capsys.readouterr().out.split("map feature:\n", 1)[1])
    angles = [a for rs in shown["rotation_ranges"].values() for r in rs for a in r]
    assert angles and all(round(a, 3) == a for a in angles)


def test_suite_out_takes_yaml_or_json_by_suffix(tmp_path, capsys, small_map):
    assert main(["suite", str(small_map), "--out", str(tmp_path / "s.txt")]) == 2
    assert "YAML (.yaml, .yml) or JSON (.json)" in one_error(capsys) and not (tmp_path / "s.txt").exists()
    assert main(["suite", str(small_map), "--out", str(tmp_path / "s.json"), "--traffic", "0"]) == 0
    assert json.loads((tmp_path / "s.json").read_text())["scenarios"]


def test_export_opendrive_reports_the_revision_it_wrote(tmp_path, capsys, small_map):
    assert main(["export", "opendrive", str(small_map), "--odr-version", "1.7", "--out", str(tmp_path / "m.xodr")]) == 0
    assert "(ASAM OpenDRIVE 1.7 " in capsys.readouterr().out
    assert 'revMinor="7"' in (tmp_path / "m.xodr").read_text()


def test_no_progress_frames_or_float_warnings_on_a_non_terminal_stderr(tmp_path):
    """A log file or pipe gets the result lines only: no redrawn progress bars, no numpy notes."""
    code = ("import sys, warnings, numpy as np; from feat2map.cli import main\n"
            "import feat2map.cli as c\n"
            "orig = c.cmd_validate\n"
            "def noisy(args):\n"
            "    np.array([1.0]) / np.array([0.0])\n"  # a RuntimeWarning: divide by zero
            "    return orig(args)\n"
            "c.cmd_validate = noisy\n"
            "sys.exit(main(sys.argv[1:]))\n")
    out = tmp_path / "m"
    r = subprocess.run([sys.executable, "-c", code, "generate", "--seed", "2", "--out", str(out)],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    r = subprocess.run([sys.executable, "-c", code, "validate", str(out / "apollo")], capture_output=True,
                       text=True, cwd=tmp_path)
    assert r.returncode == 0 and r.stderr == "" and "\r" not in r.stdout, r.stderr


def _broken(small_map: Path, tmp_path: Path, how: str) -> Path:
    d = json.loads(small_map.read_text())
    junction = [ln for ln in d["lanes"] if ln.get("junction_id")]
    if how == "junction-lane cycle":
        a, b = junction[0], junction[1]
        a["successors"], b["predecessors"], b["successors"], a["predecessors"] = [b["id"]], [a["id"]], [a["id"]], [b["id"]]
    else:  # a zero-length road lane, in a map that does not say feat2map generated it
        ln = [x for x in d["lanes"] if not x.get("junction_id")][3]
        for key in ("centerline", "left_boundary", "right_boundary"):
            ln[key] = [ln[key][0]] * 2
        d["meta"].pop("generator", None)
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(d))
    return path


@pytest.mark.parametrize("how", ["junction-lane cycle", "zero-length lane"])
def test_export_refuses_what_validate_would_reject(tmp_path, capsys, small_map, how):
    src = _broken(small_map, tmp_path, how)
    assert main(["export", "apollo", str(src), "--out", str(tmp_path / "a")]) == 2
    errors = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("feat2map: error:")]  # after warnings
    assert len(errors) == 1 and "refusing to export a map that would not validate" in errors[0]
    assert "would not validate: lane " in errors[0]  # the first problem leads, naming the lane
    assert not (tmp_path / "a").exists()
    assert main(["export", "apollo", str(small_map), "--out", str(tmp_path / "ok")]) == 0
    assert main(["validate", str(tmp_path / "ok"), "--quiet"]) == 0


def test_pip_check_is_clean():
    """commonroad-io's protobuf pin is kept out of the environment (scripts/setup.sh)."""
    r = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


def readme_python_block() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)\n```", section, re.S).group(1)


@pytest.mark.slow
@pytest.mark.parametrize("shared", [False, True])
def test_readme_python_block_runs_as_written_with_and_without_shared_maps(tmp_path, shared):
    from conftest import SHARED_MAPS, SHARED_MAPS_MISSING

    if shared and not SHARED_MAPS.is_dir():
        pytest.skip(SHARED_MAPS_MISSING)
    work = tmp_path / "repo"
    work.mkdir()
    if shared:
        (tmp_path / "shared").mkdir()
        (tmp_path / "shared" / "maps").symlink_to(SHARED_MAPS)
    r = subprocess.run([sys.executable, "-c", readme_python_block()], cwd=work, capture_output=True, text=True,
                       timeout=600, env={**os.environ, "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"})
    assert r.returncode == 0, r.stderr[-2000:]
    assert "junctions," in r.stdout and "one step:" in r.stdout
    assert ("'signal', 'stop'" in r.stdout) or not shared



def test_pictures_explain_their_colours(tmp_path, monkeypatch):
    """drive.png's env frames and the rollout report's outcomes.png carry legends."""
    import importlib.util
    import types

    import matplotlib.figure

    spec = importlib.util.spec_from_file_location("demo_example", REPO / "examples" / "demo.py")
    demo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(demo)
    labels = [h.get_label() for h in demo.frame_legend((200, 200, 0))]
    assert {"ego vehicle (at the centre)", "other vehicles", "ego route", "pedestrian", "stop sign"} <= set(labels)
    assert sum(label.startswith("signal ") for label in labels) == 3

    from feat2map.scenarios import report

    seen = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: seen.extend(
        t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()))
    outcome = lambda name, kind: types.SimpleNamespace(name=name, outcome=kind, sim_s=3.0)  # noqa: E731
    result = types.SimpleNamespace(name="s", outcomes=[outcome("a", "completed"), outcome("b", "collision")],
                                   counts=lambda: {k: int(k in ("completed", "collision")) for k in report.OUTCOMES})
    report._plot_outcomes(result, tmp_path / "outcomes.png")
    assert seen == ["completed", "collision"] or set(seen) == {"completed", "collision"}


def test_an_xodr_with_links_to_a_missing_road_is_refused_or_validates(tmp_path, capsys, small_map):
    """Reading drops what it cannot resolve, with a warning; links to a missing road whose lanes
    end exactly where others start are restored from the geometry (`link_touching_ends`), so
    that map is written and validates, and so is a map whose dropped connections leave it
    sound."""
    xodr = tmp_path / "m.xodr"
    assert main(["export", "opendrive", str(small_map), "--out", str(xodr)]) == 0
    text = xodr.read_text()
    k = iter(range(10**6))
    (tmp_path / "roads.xodr").write_text(re.sub(r'(elementType="road" elementId=")[^"]*(")',
                                                lambda m: m[1] + "9999" + m[2] if next(k) < 24 else m[0], text))
    (tmp_path / "connections.xodr").write_text(re.sub(r'(incomingRoad=")[^"]*(")', r"\g<1>8888\2", text, count=24))
    capsys.readouterr()
    assert main(["export", "apollo", str(tmp_path / "roads.xodr"), "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "unknown road id '9999', link skipped" in err
    assert re.search(r"\d+ missing link\(s\) added where a lane without successor ends exactly where another starts", err)
    assert main(["validate", str(tmp_path / "a"), "--quiet"]) == 0
    assert main(["export", "apollo", str(tmp_path / "connections.xodr"), "--out", str(tmp_path / "b")]) == 0
    assert "unknown road id, skipped" in capsys.readouterr().err
    assert main(["validate", str(tmp_path / "b"), "--quiet"]) == 0
