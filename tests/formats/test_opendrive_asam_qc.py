"""OpenDRIVE export judged by ASAM's own checker (asam-qc-opendrive, with the official schemas):
no issue from any check on generated maps, spec maps and a map generated from a real map's
features; every check runs (each revision skips only the rule that does not apply to it);
older revisions stay schema-valid and read back; the checker is `feat2map validate`'s face."""
from __future__ import annotations

from functools import lru_cache

import pytest
from lxml import etree

import feat2map
from feat2map.cli import main
from feat2map.config import OPENDRIVE_VERSIONS
from feat2map.formats.asam_qc import OPENDRIVE, find_bundle, run_bundle
from feat2map.formats.opendrive import read_opendrive, to_opendrive, validate_opendrive, write_opendrive

from conftest import (REPO, SKIP_QC_OPENDRIVE, adjacent_junctions_map, crossed_merges_map, merge_at_junction_entry_map,
                      shared_map, split_and_merge_map, uneven_seams_map)
from conftest import assert_same_features

pytestmark = pytest.mark.skipif(find_bundle(OPENDRIVE[0]) is None,
                                reason=SKIP_QC_OPENDRIVE)

ALL_CHECKS = 23  # checkers of asam-qc-opendrive 1.0.0
# each rule that applies to only some revisions: the revision that skips it
NOT_FOR = {"1.8": "check_asam_xodr_junctions_connection_one_connection_element",  # rule for <= 1.7
           "1.7": "check_asam_xodr_junctions_connection_one_link_to_incoming"}  # rule from 1.8 on
SPECS = ("mega_junction", "one_way_t", "multi_lane", "road_circle")


@lru_cache(maxsize=None)
def _map(name: str):
    if name.startswith("seed"):
        return feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=int(name[4:]))
    from feat2map.spec import build_spec, load_spec

    spec = load_spec(REPO / "examples" / f"{name}.yaml")
    return build_spec(spec, seed=0, config=spec.generation_config({}))


def _check(m, tmp_path, version: str = OPENDRIVE_VERSIONS[0]):
    path = tmp_path / f"map-{version}.xodr"
    write_opendrive(m, path, version)
    results = run_bundle(path, OPENDRIVE)
    assert len(results) == ALL_CHECKS
    issues = [str(p) for r in results for p in r.issues]
    assert issues == []
    not_run = {r.checker_id: r.summary for r in results if r.status != "completed"}
    assert set(not_run) <= {NOT_FOR.get(version)}, not_run
    assert all(r.skipped_for_version for r in results if r.status == "skipped")
    return {r.checker_id for r in results if r.status == "completed"}


@pytest.mark.parametrize("name", ("seed11",) + SPECS)
def test_generated_and_spec_maps_pass_every_check(name, tmp_path):
    _check(_map(name), tmp_path)


def test_every_check_runs_on_some_revision(tmp_path):
    """1.8 and 1.7 skip one rule each, the other's: together every check ran and passed."""
    ran = _check(_map("seed5"), tmp_path, "1.8") | _check(_map("seed5"), tmp_path, "1.7")
    assert len(ran) == ALL_CHECKS


@pytest.mark.parametrize("version", OPENDRIVE_VERSIONS[2:])
def test_older_revisions_are_valid_and_read_back(version, tmp_path):
    m = _map("seed5")
    path = tmp_path / f"m{version}.xodr"
    write_opendrive(m, path, version)
    assert validate_opendrive(path) == []
    assert etree.parse(str(path)).getroot().find("header").get("revMinor") == version.split(".")[1]
    back = read_opendrive(path)
    assert len(back.crosswalks) == len(m.crosswalks) and len(back.signals) == len(m.signals)
    assert_same_features(m, back)


def test_same_map_same_bytes():
    a, b = to_opendrive(_map("seed5")), to_opendrive(feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=5))
    assert a == b


@pytest.mark.parametrize("version", OPENDRIVE_VERSIONS[:2])
def test_splits_and_merges_outside_junctions_pass_every_check(version, tmp_path):
    """A lane splitting in two and two lanes merging, outside any junction: direct junctions."""
    _check(split_and_merge_map(), tmp_path, version)


@pytest.mark.parametrize("version", OPENDRIVE_VERSIONS[:2])
def test_adjacent_junctions_pass_every_check(version, tmp_path):
    """A junction lane continuing straight into the next junction's: no connecting road as incoming road."""
    _check(adjacent_junctions_map(), tmp_path, version)


@pytest.mark.parametrize("name", ("uneven_seams", "merge_at_junction_entry"))
def test_lanes_meeting_at_different_widths_or_headings_pass_every_check(name, tmp_path):
    """A lane 4 m wide at its start continuing one 3.5 m wide at its end; a lane forking into a
    lane that another merges into, turned 10 degrees: no border gap."""
    _check({"uneven_seams": uneven_seams_map, "merge_at_junction_entry": merge_at_junction_entry_map}[name](), tmp_path)


def test_lanes_forking_into_lanes_others_merge_into_pass_every_check(tmp_path):
    """Two junction lanes ending at one point, each leading into both lanes of the next junction
    (GoMentum's back-to-back junctions): the road link of a lane no predecessor is aligned to names
    a predecessor whose written end it must start along, or its borders miss it by decimetres."""
    _check(crossed_merges_map(), tmp_path)


@pytest.mark.real_maps
def test_map_from_real_features_passes_every_check(tmp_path):
    from feat2map.extract import extract_junctions, map_feature

    space = map_feature(extract_junctions(read_opendrive(shared_map("opendrive/carla_town01/Town01.xodr"))))
    m = feat2map.generate(space, seed=3, config=feat2map.GenerationConfig(samples_per_combination=4))
    assert len(m.junctions) >= 4
    _check(m, tmp_path)


def test_cli_validate_runs_the_checker_and_reports_its_issues(tmp_path, capsys):
    """A crosswalk painted in a 1.6 file (no such fillType before 1.8) is a schema issue, with
    the file row; the clean file validates with exit 0."""
    good = tmp_path / "good.xodr"
    write_opendrive(_map("mega_junction"), good, "1.6")
    assert main(["validate", str(good)]) == 0
    assert "good.xodr: 0 problems" in capsys.readouterr().out
    root = etree.parse(str(good)).getroot()
    outlines = root.findall(".//object/outlines/outline")
    assert outlines
    for ol in outlines:
        ol.set("fillType", "paint")
    bad = tmp_path / "bad.xodr"
    bad.write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8"))
    assert main(["validate", str(bad)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert len([ln for ln in out if "xml_valid_schema" in ln and "'paint'" in ln]) == len(outlines)
    assert out[-1] == f"{bad}: {len(outlines)} problems"
    assert all(ln.startswith("bad.xodr:") for ln in out[:-1])


def test_a_checker_past_its_time_limit_says_how_to_raise_it(tmp_path, capsys):
    """ASAM's checker runs past `max_checker_s` on a big file (San Francisco's export): the file
    is refused with the limit's name and flag, and `--limit` raises it for one run."""
    from feat2map.config import raised_limits
    from feat2map.errors import Feat2MapError

    path = tmp_path / "m.xodr"
    write_opendrive(_map("mega_junction"), path)
    with raised_limits(max_checker_s=0.01), pytest.raises(Feat2MapError, match="--limit max_checker_s=N"):
        run_bundle(path, OPENDRIVE)
    assert main(["--limit", "max_checker_s=0.01", "validate", str(path)]) != 0
    assert "max_checker_s" in capsys.readouterr().err
    assert main(["--limit", "max_checker_s=900", "validate", str(path)]) == 0


def test_checker_problems_name_the_element(tmp_path):
    """A paramPoly3 whose declared length is not its arc length: a geometry issue located by
    XPath."""
    root = etree.fromstring(to_opendrive(_map("one_way_t")))
    road = root.find("road")
    geometry = road.find("planView/geometry")
    for el, key in ((road, "length"), (geometry, "length")):
        el.set(key, repr(1.5 * float(el.get(key))))
    path = tmp_path / "stretched.xodr"
    path.write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8"))
    problems = validate_opendrive(path)
    assert problems and all(p.element.startswith("stretched.xodr") for p in problems)
    assert any("parampoly3_length_match" in p.message and p.element.endswith("/OpenDRIVE/road[1]/planView/geometry")
               for p in problems)


def test_validate_reports_what_the_reader_skips(tmp_path):
    """A negative lane width passes the checker's schema but makes the road unusable: validate
    reports feat2map's reader skipping it, naming the road."""
    root = etree.fromstring(to_opendrive(_map("one_way_t")))
    width = root.find(".//lane/width")
    width.set("a", "-3.5")
    path = tmp_path / "negative.xodr"
    path.write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8"))
    problems = validate_opendrive(path)
    assert any(p.element == "negative.xodr" and p.message.startswith("feat2map reader: skipping bad road")
               and "width -3.5 m is negative" in p.message for p in problems)


def test_a_border_the_reader_unfolds_is_a_warning_of_validate_not_a_problem(tmp_path, capsys):
    """A lane wider than twice its inner border's radius is valid OpenDRIVE (ASAM's checker finds
    nothing); feat2map's reader unfolds that border to drive it (`semantics.unfolded_boundaries`),
    and validate reports the repair as a warning: every real map's OpenDRIVE export with such a
    turn showed "1 problem" before."""
    from test_apollo_export import _TIGHT_BEND_XODR

    path = tmp_path / "tight.xodr"
    path.write_text(_TIGHT_BEND_XODR)
    found = validate_opendrive(path)
    assert [p.warning for p in found] == [True] and "folds back on itself" in found[0].message
    capsys.readouterr()
    assert main(["validate", str(path)]) == 0
    assert "0 problems, 1 warning" in capsys.readouterr().out
