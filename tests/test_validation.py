"""The model's boundary: every reader's map passes validate_model, whose errors name file and
element; values that parse but are invalid (NaN, inf, 1e308, negative or string widths,
1-point Béziers, lanes that are their own successor) are errors, never tracebacks; writers
refuse non-finite values."""
from __future__ import annotations

import dataclasses
import json
import math

import pytest

import feat2map
from feat2map.cli import main
from feat2map.config import GenerationConfig, raised_limits
from feat2map.errors import ERROR_MAX_CHARS, ConfigError, Feat2MapError, LimitError, MapFormatError
from feat2map.formats import native, read_map, write_map
from feat2map.formats.opendrive import read_opendrive
from feat2map.validation import refuse_nonfinite, validate_model


@pytest.fixture(scope="module")
def small_doc():
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180], "signal", True)], seed=0)
    return m, native.to_dict(m)


def lane(doc):
    return doc["lanes"][0]


NAN, INF = float("nan"), float("inf")
MUTATIONS = [
    ("centerline NaN", lambda d: lane(d)["centerline"][0].__setitem__(0, NAN), "centerline point 0"),
    ("centerline inf", lambda d: lane(d)["centerline"][1].__setitem__(1, INF), "centerline point 1"),
    ("centerline 1e308", lambda d: lane(d)["centerline"][0].__setitem__(0, 1e308), "max_coordinate_m"),
    ("centerline one point", lambda d: lane(d).__setitem__("centerline", lane(d)["centerline"][:1]), "at least 2"),
    ("negative width", lambda d: lane(d).__setitem__("width", -3.5), "width"),
    ("string width", lambda d: lane(d).__setitem__("width", "wide"), "width"),
    ("1-point Bezier", lambda d: lane(d).__setitem__("bezier", [[0, 0]]), "bezier"),
    ("string reference", lambda d: d["roads"][0].__setitem__("reference", "x"), "reference"),
    ("own successor", lambda d: lane(d).__setitem__("successors", [lane(d)["id"]]), "its own successor"),
    ("NaN stop line", lambda d: d["signals"][0]["stop_line"][0].__setitem__(0, NAN), "stop_line"),
    ("inf heading", lambda d: d["signals"][0].__setitem__("heading", INF), "heading"),
    ("2-point crosswalk", lambda d: d["crosswalks"][0].__setitem__("polygon", d["crosswalks"][0]["polygon"][:2]),
     "polygon"),
    ("unknown turn", lambda d: lane(d).__setitem__("turn", "sideways"), "turn"),
    ("int links", lambda d: lane(d).__setitem__("predecessors", 5), "predecessors"),
    ("9-leg feature", lambda d: d["junctions"][0].__setitem__("feature", {"rotation": [i * 40.0 for i in range(9)]}),
     "at most 8"),
]


@pytest.mark.parametrize("name, mutate, needle", MUTATIONS, ids=[m[0] for m in MUTATIONS])
def test_invalid_values_in_a_map_file_are_one_line_errors(tmp_path, capsys, small_doc, name, mutate, needle):
    doc = json.loads(json.dumps(small_doc[1]))
    mutate(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))  # NaN/Infinity literals as Python writes them
    with pytest.raises(MapFormatError, match=needle) as err:
        native.load(path)
    assert str(path) in str(err.value) and len(str(err.value)) <= ERROR_MAX_CHARS
    for argv in (["extract", str(path)], ["export", "apollo", str(path), "--out", str(tmp_path / "a")]):
        assert main(argv) == 2
        out = capsys.readouterr()
        assert "Traceback" not in out.err and len(out.err.strip().splitlines()) == 1
    assert not (tmp_path / "a").exists()


def test_a_valid_map_passes_and_the_model_check_is_the_one_every_reader_uses(tmp_path, small_doc):
    m = small_doc[0]
    assert validate_model(m) is m
    write_map(m, tmp_path / "m.xodr", "opendrive")
    write_map(m, tmp_path / "apollo", "apollo")
    for path in (tmp_path / "m.xodr", tmp_path / "apollo"):
        assert len(read_map(path).lanes) > 0


def test_writers_refuse_non_finite_values(tmp_path, small_doc):
    m = small_doc[0]
    lid = next(iter(m.lanes))
    bad = dataclasses.replace(m, lanes={**m.lanes, lid: dataclasses.replace(m.lanes[lid], width=math.nan)})
    for fmt, out in (("native", tmp_path / "m.json"), ("opendrive", tmp_path / "m.xodr"), ("apollo", tmp_path / "ap")):
        with pytest.raises(MapFormatError, match=f"lane {lid}: width"):
            write_map(bad, out, fmt)
        assert not out.exists()
    with pytest.raises(MapFormatError, match=f"lane {lid}: width"):
        native.dumps(bad)
    with pytest.raises(Feat2MapError, match=r"element 'L1'.*NaN"):
        refuse_nonfinite('lane {\n  id: "L1"\n  length: nan\n}\n', "out")


@pytest.mark.parametrize("attr, value, needle", [
    ("length", "1e9", "max_road_length_m"), ("length", "1e308", "max_road_length_m"), ("length", "nan", "not finite"),
    ("length", "-5", "negative"), ("hdg", "inf", "not finite"),
])
def test_opendrive_values_that_parse_but_are_invalid(tmp_path, small_doc, attr, value, needle):
    """A bad road is skipped with a warning (here every road is bad); a road above a size
    limit is an error naming it and the limit to raise."""
    import re

    write_map(small_doc[0], tmp_path / "m.xodr", "opendrive")
    text = (tmp_path / "m.xodr").read_text()
    bad = tmp_path / "bad.xodr"
    bad.write_text(re.sub(rf'(<geometry [^>]*\b{attr}=")[^"]*"', rf'\g<1>{value}"', text))
    if needle.startswith("max_"):
        with pytest.raises(LimitError, match=rf"road \d+ <geometry>.*{needle}"):
            read_opendrive(bad)
        return
    with pytest.warns(UserWarning, match=needle), pytest.raises(MapFormatError, match="no readable <road>"):
        read_opendrive(bad)


@pytest.mark.parametrize("width, message", [("1e300", "max_lane_width_m"), ("-3.5", "width -3.5 m is negative")])
def test_huge_or_negative_opendrive_widths_skip_the_road(tmp_path, small_doc, width, message):
    write_map(small_doc[0], tmp_path / "m.xodr", "opendrive")
    text = (tmp_path / "m.xodr").read_text()
    bad = tmp_path / "wide.xodr"
    bad.write_text(text.replace('<width sOffset="0.0" a="3.5"', f'<width sOffset="0.0" a="{width}"', 1))
    with pytest.warns(UserWarning) as rec:  # all of them (with match=, pytest 8 re-emits the others)
        m = read_opendrive(bad)
    assert 0 < len(m.lanes) < len(small_doc[0].lanes)
    # every finding names the file; past the skipped road's own, they are the links to it, skipped
    found = [str(w.message) for w in rec]
    assert all(f"{bad}: " in f for f in found), found
    skipped = [f for f in found if message in f]
    assert skipped and all(f in skipped or "unknown road id" in f for f in found), found


@pytest.mark.parametrize("value", ["-3.5", "nan"])
def test_apollo_width_samples_must_be_non_negative(tmp_path, small_doc, value):
    """Apollo lane widths are the mean of the width samples, which would hide a bad one."""
    write_map(small_doc[0], tmp_path / "a", "apollo")
    (tmp_path / "a" / "base_map.bin").unlink()
    text = (tmp_path / "a" / "base_map.txt").read_text()
    (tmp_path / "a" / "base_map.txt").write_text(text.replace("width: ", f"width: {value}  # ", 1))
    with pytest.raises(MapFormatError, match=r"base_map.txt: lane '.+': width sample .+ is negative or not a number"):
        read_map(tmp_path / "a")


def test_cli_warnings_are_one_line_each(tmp_path, small_doc, capsys):
    """A road the reader skips is a `feat2map: warning:` line, in every command, not Python's
    two-line format with our source line."""
    write_map(small_doc[0], tmp_path / "m.xodr", "opendrive")
    bad = tmp_path / "bad.xodr"
    bad.write_text((tmp_path / "m.xodr").read_text().replace('<width sOffset="0.0" a="3.5"',
                                                             '<width sOffset="0.0" a="-3.5"', 1))
    # what is left after the skipped road must validate whole, else the export refuses (issue 25)
    assert main(["export", "apollo", str(bad), "--out", str(tmp_path / "a")]) in (0, 2)
    err = capsys.readouterr().err.splitlines()
    warned = [line for line in err if not line.startswith("feat2map: error: ")]
    assert warned and all(line.startswith("feat2map: warning: ") and str(bad) in line for line in warned)
    assert "width -3.5 m is negative" in err[0] and len(err) - len(warned) <= 1


@pytest.mark.parametrize("field, value", [("grid_gap", math.nan), ("grid_gap", math.inf), ("lane_width", math.nan),
                                          ("lane_width", -1.0), ("lane_width", "3"), ("samples_per_combination", 1.5),
                                          ("uturns", 1), ("sample_spacing", 1e-9), ("crosswalk_width", True)])
def test_generation_config_refuses_what_value_checks_let_through(field, value):
    with pytest.raises(ConfigError, match=field):
        GenerationConfig(**{field: value})


def test_size_limits_fail_before_the_work_and_can_be_raised():
    space = feat2map.PAPER_SF_FEATURE_SPACE
    with pytest.raises(LimitError, match="is 125000, above the limit max_junctions=20000 "):
        feat2map.generate(space, config=GenerationConfig(samples_per_combination=125_000))
    with pytest.raises(LimitError, match="max_road_length_m"):
        feat2map.generate(space, config=GenerationConfig(grid_gap=1e308))
    with raised_limits(max_junctions=4), pytest.raises(LimitError, match="max_junctions=4"):
        feat2map.generate(space)
    with pytest.raises(ConfigError, match="seed"):
        feat2map.generate(space, seed=-1)
