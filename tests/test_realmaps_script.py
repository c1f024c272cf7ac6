"""scripts/realmaps.py on a folder of maps the project makes itself: a signal 4-way and a stop T
exported to OpenDRIVE and Apollo, a broken file beside them. The table counts what the map
holds, every map that reads exports to the four formats and each export validates, a broken map
is a recorded finding (stage and error), the survey goes on, and --doc writes the reference page."""
from __future__ import annotations

import importlib.util
import json
import sys

import pytest

from conftest import REPO

SPEC = {"version": 1, "junctions": [
    {"name": "lit cross", "cell": [0, 0], "control": "signal",
     "sockets": [{"angle": 0, "lanes": 2}, {"angle": 90}, {"angle": 180, "lanes": 2}, {"angle": 270}]},
    {"name": "stop T", "cell": [1, 0], "control": "stop", "sockets": [0, 90, {"angle": 180, "lanes": 2}]}]}


def _script():
    spec = importlib.util.spec_from_file_location("realmaps", REPO / "scripts" / "realmaps.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def surveyed(tmp_path_factory):
    from feat2map.formats.apollo.writer import write_apollo
    from feat2map.formats.opendrive.writer import write_opendrive
    from feat2map.spec import build_spec, parse_spec

    d = tmp_path_factory.mktemp("maps")
    m = build_spec(parse_spec(SPEC))
    write_opendrive(m, d / "odr" / "two.xodr")
    write_apollo(m, d / "apollo")
    for p in (d / "apollo").iterdir():  # one Apollo file is enough (sim maps repeat the base map)
        if p.name != "base_map.bin":
            p.unlink()
    (d / "apollo" / "README.txt").write_text("These files are made by the test.\n")  # no map: never surveyed
    (d / "odr" / "broken.xodr").write_text("<OpenDRIVE><header/><road id='1'")  # cut off mid-element
    md, js = d / "table.md", d / "table.json"  # an earlier run's output inside the surveyed folder: no map
    md.write_text("an earlier table\n")
    js.write_text('{"maps": []}')
    rc = _script().main([str(d), "--max-scenarios", "1", "--md", str(md), "--json", str(js)])
    return d, rc, md.read_text(), json.loads(js.read_text())


def test_every_map_file_is_surveyed_and_nothing_else(surveyed):
    d, _, _, data = surveyed
    assert sorted(s["path"] for s in data["maps"]) == [f"{d.name}/apollo/base_map.bin", f"{d.name}/odr/broken.xodr",
                                                      f"{d.name}/odr/two.xodr"]


def test_the_table_counts_junctions_controls_phases_scenarios_and_drives(surveyed):
    from feat2map.scenarios.routes import build_suite

    d, _, md, data = surveyed
    for rel in ("apollo/base_map.bin", "odr/two.xodr"):
        s = next(x for x in data["maps"] if x["path"] == f"{d.name}/{rel}")
        n = len(build_suite(d / rel, traffic_vehicles=6).scenarios)
        assert (s["junctions"], s["skipped"], s["controls"]) == (2, [], {"signal": 1, "stop": 1})
        assert s["signals"] >= 4 and len(s["phases"]) == 1 and 2 <= next(iter(s["phases"].values())) <= 4
        assert (s["scenarios"], s["driven"], s["outcomes"], s["errors"]) == (n, 1, {"completed": 1}, [])
        row = next(r for r in md.splitlines() if f"`{d.name}/{rel}`" in r)
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[3:6] == ["2 (0)", "1 / 1 / 0", str(s["signals"])]
        assert cells[8:] == [str(n), "1", "1", "-", "0 / 0 / 0 / 0"]
        assert s["exports"] == {fmt: {"problems": 0, "warnings": 0, "first": ""}
                                for fmt in ("apollo", "opendrive", "lanelet2", "commonroad")}


def test_a_broken_map_is_a_finding_with_its_stage_and_the_survey_goes_on(surveyed):
    d, rc, md, data = surveyed
    broken = next(x for x in data["maps"] if x["path"].endswith("broken.xodr"))
    assert rc == 1 and [e["stage"] for e in broken["errors"]] == ["read"]
    assert broken["errors"][0]["kind"] == "refusal" and "broken.xodr" in broken["errors"][0]["error"]
    assert f"- `{d.name}/odr/broken.xodr` read: refusal: " in md
    assert "**3 maps: 4 junctions (0 skipped)" in md


def test_compare_marks_the_maps_whose_numbers_changed(surveyed, tmp_path):
    import copy

    d, _, _, data = surveyed
    after = copy.deepcopy(data)
    odr = next(s for s in after["maps"] if s["path"].endswith("two.xodr"))
    odr["outcomes"] = {"completed": 0, "collision": 1}
    files = [tmp_path / "before.json", tmp_path / "after.json"]
    for p, doc in zip(files, (data, after)):
        p.write_text(json.dumps(doc))
    out = tmp_path / "cmp.md"
    assert _script().main(["--compare", *map(str, files), "--md", str(out)]) == 0
    rows = {r.split("|")[1].strip(): r for r in out.read_text().splitlines() if r.startswith("| `")}
    assert "1/1 -> **0/1**" in rows[f"`{d.name}/odr/two.xodr`"] and "- -> **collision 1**" in rows[f"`{d.name}/odr/two.xodr`"]
    assert "->" not in rows[f"`{d.name}/apollo/base_map.bin`"]
    assert "Before: 2 of 2 driven completed" in out.read_text() and "After: 1 of 2 driven completed" in out.read_text()


def test_the_reference_page_has_one_row_per_map_and_names_each_refusal(surveyed, tmp_path):
    d, _, _, data = surveyed
    js = tmp_path / "run.json"
    js.write_text(json.dumps(data))
    doc = tmp_path / "realmaps.md"
    assert _script().main(["--from-json", str(js), "--doc", str(doc)]) == 0
    text = doc.read_text()
    rows = [r for r in text.splitlines() if r.startswith(f"| `{d.name}/")]
    assert len(rows) == 3 and "## Reproducing" in text and "semantics.md" in text
    two = next(r for r in rows if "two.xodr" in r)
    assert [c.strip() for c in two.strip("|").split("|")][2:] == ["2 (0)", "1 / 1 / 0", next(
        str(s["scenarios"]) for s in data["maps"] if s["path"].endswith("two.xodr")), "1 / 1", "-", "0 / 0 / 0 / 0"]
    assert f"- `{d.name}/odr/broken.xodr` read: refusal: " in text
    assert "2 of 3 maps export to all four formats with no problem" in text


def test_a_raised_limit_reaches_every_stage(surveyed, tmp_path, monkeypatch):
    """`--limit NAME=VALUE` holds for the whole survey, as feat2map's own flag does for a command
    (San Francisco's OpenDRIVE export needs ASAM's checker longer than the default): every map's
    stages run under it; a bad value is refused before any map is read."""
    from feat2map.config import limits

    script = _script()
    seen = []

    def survey_map(path, label, **kw):
        seen.append(limits().max_checker_s)
        return script.MapSurvey(label, size=0)
    monkeypatch.setattr(script, "survey_map", survey_map)
    assert script.main([str(surveyed[0] / "odr"), "--limit", "max_checker_s=1234", "--md", str(tmp_path / "t.md"),
                        "--json", str(tmp_path / "t.json")]) == 0
    assert seen == [1234.0, 1234.0] and limits().max_checker_s == 600.0  # both files, and only for the survey
    with pytest.raises(SystemExit) as bad:
        script.main([str(surveyed[0] / "odr"), "--limit", "max_checker_s=-1"])
    assert bad.value.code == 2


def test_the_ramp_suites_table_counts_each_maps_ramps_and_their_scenarios(tmp_path):
    """Maps with ramps get a row in the survey table's and the reference page's ramp section:
    ramps found, the suite's merge and diverge scenarios, how many drove and completed."""
    script = _script()
    ramps = script.MapSurvey("c/Ex_Entry_Exit.xodr", ramps={"on": 1, "off": 1}, ramp_scenarios=[
        {"scenario": "e-r000-diverge", "kinds": ["diverge"], "outcome": "completed"},
        {"scenario": "e-r001-merge", "kinds": ["merge"], "outcome": "timeout"}])
    plain = script.MapSurvey("c/plain.xodr")
    rows = script.ramp_table([ramps, plain])
    assert rows[2] == "| `c/Ex_Entry_Exit.xodr` | 1 / 1 | 2 (1 / 1) | 2 / 1 | timeout 1 |" and len(rows) == 4
    assert script.ramp_table([plain]) == []
    js = tmp_path / "run.json"
    js.write_text(json.dumps({"folders": ["/x/c"], "maps": [ramps.__dict__, plain.__dict__]}))
    assert script.main(["--from-json", str(js), "--doc", str(tmp_path / "doc.md")]) == 0
    assert "## Ramp suites" in (text := (tmp_path / "doc.md").read_text()) and rows[2] in text
