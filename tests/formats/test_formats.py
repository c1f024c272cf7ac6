"""The format table: read_map, export and validate dispatch on it; every format round-trips."""
from __future__ import annotations

import pytest
from conftest import SKIP_COMMONROAD_IO

from feat2map.cli import main
from feat2map.errors import Feat2MapError, MapFormatError
from feat2map.formats import FORMATS, detect, native, read_map, write_map


@pytest.fixture(scope="module")
def small_map():
    import feat2map

    return feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180], "signal", True)], seed=0)


def test_every_format_has_a_package_with_its_faces():
    """Each entry's faces import and fit their Protocols (formats/base.py), export options included."""
    for fmt in FORMATS.values():
        assert fmt.check_faces() == [], fmt.name
        assert fmt.output in ("file", "dir")
        assert fmt.input in ("map", "suite")


def test_a_face_that_does_not_fit_its_protocol_is_named():
    from feat2map.formats.base import ExportOption, MapFormat

    bad = MapFormat("bad", "bad", (".bad",), read="feat2map.formats.base:header_date",  # takes no path
                    write="feat2map.formats.native:save", validate="feat2map.formats.native:no_such_function",
                    options=(ExportOption("--zone", "zone"),))  # save takes no zone
    found = bad.check_faces()
    assert len(found) == 3, found
    assert found[0].startswith("bad.read:") and "MapReader" in found[0]
    assert found[1].startswith("bad.write:") and "export options" in found[1]
    assert found[2].startswith("bad.validate:") and "does not import" in found[2]


def test_the_package_exports_read_write_and_extract():
    import importlib.metadata

    import feat2map
    from feat2map.extract import extract_junctions

    assert feat2map.read_map is read_map and feat2map.write_map is write_map
    assert feat2map.extract_junctions is extract_junctions
    assert feat2map.__version__ == importlib.metadata.version("feat2map")


@pytest.mark.parametrize("name", [n for n, f in FORMATS.items() if f.read and f.write])
def test_write_then_read_gives_the_same_junctions(tmp_path, small_map, name):
    fmt = FORMATS[name]
    out = tmp_path / ("out" if fmt.output == "dir" else f"m{fmt.suffixes[0]}")
    write_map(small_map, out, name)
    back = read_map(out)
    assert detect(out).name == name
    assert len(back.junctions) == len(small_map.junctions)
    assert len(back.signals) > 0 and len(back.crosswalks) > 0


def test_content_decides_when_the_suffix_does_not(tmp_path, small_map):
    native.save(small_map, tmp_path / "m.json")
    (tmp_path / "m.map").write_bytes((tmp_path / "m.json").read_bytes())
    assert detect(tmp_path / "m.map").name == "native"
    (tmp_path / "x.dat").write_bytes(b"nothing we know")
    with pytest.raises(MapFormatError, match="unsupported map format"):
        read_map(tmp_path / "x.dat")


def test_export_help_lists_every_writable_format(capsys):
    with pytest.raises(SystemExit):
        main(["export", "--help"])
    out = capsys.readouterr().out
    assert all(n in out for n, f in FORMATS.items() if f.write)


def test_validate_without_a_validator_is_a_short_error(tmp_path, small_map, capsys):
    native.save(small_map, tmp_path / "m.json")
    assert main(["validate", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert "m.json" in err and len(err) < 300 and err.count("\n") == 1


@pytest.mark.parametrize("name, needs", [("lanelet2", None), ("commonroad", "commonroad.scenario.lanelet")])
def test_exports_are_deterministic_and_atomic(tmp_path, small_map, name, needs):
    """Same map, same bytes (in another process too, with other hash seeds); a failed export
    leaves the earlier file as it was and no temporary file."""
    import os
    import subprocess
    import sys

    from feat2map.errors import Feat2MapError

    if needs:
        from feat2map.formats.commonroad.writer import commonroad_io

        try:
            commonroad_io()  # puts scripts/setup.sh's off-path commonroad-io on sys.path
        except Feat2MapError:
            pytest.skip(SKIP_COMMONROAD_IO)
    suffix = FORMATS[name].suffixes[0]
    native.save(small_map, tmp_path / "m.json")
    write_map(small_map, tmp_path / "a" / f"m{suffix}", name)
    first = (tmp_path / "a" / f"m{suffix}").read_bytes()
    write_map(small_map, tmp_path / "a" / f"m{suffix}", name)
    assert (tmp_path / "a" / f"m{suffix}").read_bytes() == first
    env = dict(os.environ, PYTHONHASHSEED="7")
    subprocess.run([sys.executable, "-m", "feat2map.cli", "export", name, str(tmp_path / "m.json"), "--out",
                    str(tmp_path / "b" / f"m{suffix}")], check=True, env=env, capture_output=True)
    assert (tmp_path / "b" / f"m{suffix}").read_bytes() == first
    before = sorted(p.name for p in (tmp_path / "a").iterdir())
    with pytest.raises(Feat2MapError, match="UTM zone"):
        write_map(small_map, tmp_path / "a" / f"m{suffix}", name, zone=0)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == before
    assert (tmp_path / "a" / f"m{suffix}").read_bytes() == first


@pytest.mark.parametrize("theirs", ["Autoware's MGRS", "edited ours", "a folder", "a link to ours"])
def test_lanelet2_export_keeps_a_projector_info_it_did_not_write(tmp_path, small_map, capsys, theirs):
    """Issue 35: `export lanelet2 --out DIR/x.osm` refuses (one line naming the file, nothing
    written) when DIR/map_projector_info.yaml is not one an earlier export wrote; its own
    earlier one is replaced."""
    from feat2map.formats.lanelet2 import PROJECTOR_INFO

    src = tmp_path / "m.json"
    native.save(small_map, src)
    mine = tmp_path / "ours"
    assert main(["export", "lanelet2", str(src), "--out", str(mine / "a.osm")]) == 0
    ours = (mine / PROJECTOR_INFO).read_bytes()
    assert main(["export", "lanelet2", str(src), "--out", str(mine / "b.osm"), "--origin", "500000", "4000000"]) == 0
    assert (mine / PROJECTOR_INFO).read_bytes() != ours  # an earlier export's file: replaced
    d = tmp_path / "d"
    d.mkdir()
    info = d / PROJECTOR_INFO
    if theirs == "Autoware's MGRS":
        info.write_text("projector_type: MGRS\nvertical_datum: WGS84\nmgrs_grid: 54SUE\n")
    elif theirs == "edited ours":
        info.write_bytes(ours.replace(b"altitude: 0.0", b"altitude: 12.5"))
    elif theirs == "a folder":
        info.mkdir()
    else:
        info.symlink_to(mine / PROJECTOR_INFO)
    before = info.read_bytes() if info.is_file() else None
    capsys.readouterr()
    assert main(["export", "lanelet2", str(src), "--out", str(d / "x.osm")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"feat2map: error: {info}: exists and is not one a feat2map lanelet2 export wrote")
    assert len(err.splitlines()) == 1
    assert sorted(p.name for p in d.iterdir()) == [PROJECTOR_INFO]
    assert (info.read_bytes() if info.is_file() else None) == before
    with pytest.raises(Feat2MapError, match="refusing to overwrite"):
        write_map(small_map, d / "y.osm", "lanelet2")
