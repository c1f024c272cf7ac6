"""Whole-folder atomic outputs: a folder output is the old one or the new one, whole, even when
the command is SIGKILLed at any moment; an earlier output is replaced as a whole, any other
non-empty folder refused; staging leftovers of killed runs are removed by the next run.

FEAT2MAP_KILL_RUNS=N kills N runs per case instead of a few."""
from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys

import pytest
from killpoints import fingerprint, run

from feat2map import atomic
from feat2map.cli import main
from feat2map.errors import Feat2MapError
from feat2map.features import FeatureSpace

KILL_RUNS = int(os.environ.get("FEAT2MAP_KILL_RUNS", "3"))
SPACE = FeatureSpace((3,), ("signal",), (True,), {3: ((-5, 5), (85, 95), (175, 185))})


@pytest.fixture(scope="module")
def space_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("space") / "space.json"
    path.write_text(SPACE.to_json())
    return path


def _generate(space_file, seed, out, *extra):
    return ["generate", "--features", str(space_file), "--seed", str(seed), "--out", str(out), "--quiet",
            "--opendrive", *extra]


def test_an_earlier_output_is_replaced_whole(tmp_path, space_file):
    out = tmp_path / "m"
    assert main(_generate(space_file, 1, out, "--no-picture")) == 0
    assert (out / "apollo").is_dir() and (out / "map.xodr").is_file()
    assert main(["generate", "--features", str(space_file), "--seed", "2", "--out", str(out), "--quiet",
                 "--no-picture", "--no-apollo"]) == 0
    # nothing of seed 1 stays
    assert sorted(p.name for p in out.iterdir()) == sorted([atomic.MANIFEST, "features.json", "map.json"])
    assert json.loads((out / "map.json").read_text())["meta"]["seed"] == 2


def test_other_folders_are_refused_before_any_work(tmp_path, space_file, capsys):
    out = tmp_path / "home"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    assert main(_generate(space_file, 1, out)) == 2
    err = capsys.readouterr().err
    assert "refusing to replace it" in err and len(err.strip().splitlines()) == 1
    assert [p.name for p in out.iterdir()] == ["thesis.tex"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".home.")]


@pytest.mark.parametrize("argv", [["generate", "--out", ""], ["generate", "--out", "."],
                                  ["export", "opendrive", "MAP", "--out", ""]])
def test_an_empty_out_is_an_error(tmp_path, argv, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "m.json").write_text("{}")
    assert main([str(tmp_path / "m.json") if a == "MAP" else a for a in argv]) == 2
    assert "--out" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_file_outputs_that_are_folders_and_late_failures_write_nothing(tmp_path, space_file, capsys):
    m = tmp_path / "g"
    assert main(_generate(space_file, 1, m, "--no-picture", "--no-apollo")) == 0
    folder = tmp_path / "folder"
    folder.mkdir()
    for argv in (["extract", str(m / "map.json"), "--out", str(folder)],
                 ["export", "opendrive", str(m / "map.json"), "--out", str(folder)],
                 ["suite", str(m / "map.json"), "--out", str(folder)],
                 ["extract", str(m / "map.json"), "--out", str(tmp_path / "f.json"), "--picture",
                  str(tmp_path / "p.xyz")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not list(folder.iterdir()) and not (tmp_path / "f.json").exists()


def test_leftovers_of_dead_runs_are_removed_and_live_ones_kept(tmp_path):
    out = tmp_path / "report"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    stale = [tmp_path / f".report.stage-{pid}-abc", tmp_path / f".report.old-{pid}-x1", tmp_path / f".report.tmp-{pid}-q"]
    stale[0].mkdir()
    (stale[0] / "half.json").write_text("{")
    stale[1].mkdir()
    stale[2].write_text("x")
    live = tmp_path / f".report.stage-{os.getpid()}-zz"
    live.mkdir()
    other = tmp_path / f".other.stage-{pid}-abc"
    other.mkdir()
    with atomic.staged_dir(out, ("summary.json",)) as tmp:
        (tmp / "summary.json").write_text("{}")
    assert not any(p.exists() for p in stale) and live.exists() and other.exists()
    assert sorted(p.name for p in out.iterdir()) == [atomic.MANIFEST, "summary.json"]


def test_a_failing_block_leaves_the_old_folder(tmp_path):
    out = tmp_path / "o"
    with atomic.staged_dir(out, ("a",)) as tmp:
        (tmp / "a").write_text("old")
    with pytest.raises(RuntimeError), atomic.staged_dir(out, ("a",)) as tmp:
        (tmp / "a").write_text("new")
        raise RuntimeError("late failure")
    assert (out / "a").read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["o"]
    with pytest.raises(Feat2MapError, match="is a folder"):
        atomic.write_text(out, "x")


@pytest.mark.parametrize("case", ["generate over another seed", "generate --no-apollo over a full output",
                                  "export apollo over another seed"])
def test_sigkill_at_random_moments_never_leaves_a_half_written_or_mixed_folder(tmp_path, space_file, case, random_seed):
    """Each run is killed right before a random one of its filesystem changes (every change
    point is a moment a real SIGKILL can hit); the folder must be the old output or the new
    one, whole, and the next run must leave exactly its own output and no hidden leftovers."""
    seed = random_seed
    rng = random.Random(seed)
    maps = tmp_path / "maps"
    for s in (1, 2):
        assert main(_generate(space_file, s, maps / str(s), "--no-picture", "--no-apollo")) == 0
    cmds = {"generate": lambda s, out: _generate(space_file, s, out, "--no-picture"),
            "generate --no-apollo": lambda s, out: _generate(space_file, s, out, "--no-apollo", "--no-picture"),
            "export apollo": lambda s, out: ["export", "apollo", str(maps / str(s) / "map.json"), "--out", str(out)]}
    under_test = case.split(" over ")[0]
    before = "generate" if "full output" in case else under_test
    old = tmp_path / "old"
    assert run(cmds[before](1, old), cwd=tmp_path)[0] == 0
    new = tmp_path / "new"
    code, changes = run(cmds[under_test](2, new), cwd=tmp_path)
    assert code == 0 and changes > 3
    want_old, want_new = fingerprint(old), fingerprint(new)
    work = tmp_path / "work"
    work.mkdir()
    out = work / "out"
    for k in sorted(rng.sample(range(1, changes + 1), min(KILL_RUNS, changes))):
        shutil.rmtree(out, ignore_errors=True)
        shutil.copytree(old, out)
        code, _ = run(cmds[under_test](2, out), kill_at=k, cwd=work)
        assert code == -9, f"not killed at change {k} (random seed {seed})"
        assert fingerprint(out) in (want_old, want_new), f"killed at change {k} of {changes} (random seed {seed})"
        assert run(cmds[under_test](2, out), cwd=work)[0] == 0
        assert fingerprint(out) == want_new
        assert [p.name for p in work.iterdir()] == ["out"], f"leftovers after a kill at change {k} (seed {seed})"


@pytest.mark.parametrize("decoy", ["map.json folder", "map.json file", "manifest folder", "manifest link"])
def test_a_folder_is_not_ours_by_the_names_it_holds(tmp_path, space_file, decoy):
    """Only the manifest feat2map writes makes a folder replaceable: a folder (or file) named
    like our outputs, or a fake manifest, does not; the user's files stay."""
    out = tmp_path / "d"
    out.mkdir()
    (out / "notes.txt").write_text("precious")
    if decoy == "map.json folder":
        (out / "map.json").mkdir()
    elif decoy == "map.json file":
        (out / "map.json").write_text("{}")
    elif decoy == "manifest folder":
        (out / atomic.MANIFEST).mkdir()
    else:
        (tmp_path / "m.json").write_text('{"files": ["notes.txt", "map.json"]}')
        (out / atomic.MANIFEST).symlink_to(tmp_path / "m.json")
        (out / "map.json").write_text("{}")
    assert main(_generate(space_file, 1, out)) == 2
    assert (out / "notes.txt").read_text() == "precious"


def test_an_earlier_output_with_a_file_added_is_refused(tmp_path, space_file, capsys):
    out = tmp_path / "m"
    assert main(_generate(space_file, 1, out, "--no-picture", "--no-apollo")) == 0
    assert atomic.ours(out, ("map.json",)) and not atomic.ours(out, ("base_map.bin",))
    (out / "apollo").mkdir()
    (out / "apollo" / "mine.txt").write_text("precious")
    assert main(_generate(space_file, 2, out, "--no-picture", "--no-apollo")) == 2
    assert "refusing to replace it" in capsys.readouterr().err
    assert (out / "apollo" / "mine.txt").read_text() == "precious"
    (out / "apollo" / "mine.txt").unlink()
    (out / "apollo").rmdir()
    assert main(_generate(space_file, 2, out, "--no-picture", "--no-apollo")) == 0


@pytest.mark.parametrize("where", ["top", "inside apollo"])
def test_an_earlier_output_with_an_empty_folder_added_is_refused(tmp_path, space_file, capsys, where):
    """Issue 35: replacing would delete a user's empty folder; it is refused, naming the folder,
    and the earlier output replaced once the folder is gone (README's design notes)."""
    out = tmp_path / "m"
    assert main(_generate(space_file, 1, out, "--no-picture")) == 0
    mine = out / ("mine" if where == "top" else "apollo/mine")
    mine.mkdir()
    assert main(_generate(space_file, 2, out, "--no-picture")) == 2
    err = one_line(capsys)
    assert f"{out}: folder is an earlier output with '{mine.relative_to(out)}/' added since" in err
    assert mine.is_dir() and json.loads((out / "map.json").read_text())["meta"]["seed"] == 1
    mine.rmdir()
    assert main(_generate(space_file, 2, out, "--no-picture")) == 0
    listed = json.loads((out / atomic.MANIFEST).read_text())
    assert listed["folders"] == ["apollo"] and "map.json" in listed["files"]


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


MALFORMED = {"nested list": b'{"files": [["map.json"]]}', "not JSON": b"map.json", "a list": b'["map.json"]',
             "files a string": b'{"files": "map.json"}', "folders a number": b'{"files": ["map.json"], "folders": 3}',
             "not UTF-8": b"\xff\xfe{", "deep": b"[" * 100_000 + b"]" * 100_000, "null": b"null",
             "huge": b'{"files": ["map.json"' + b', "x"' * 300 + b"]}"}


@pytest.mark.parametrize("name", MALFORMED)
def test_a_malformed_manifest_is_refused_in_one_line(tmp_path, space_file, capsys, monkeypatch, name):
    """Issue 35: a damaged .feat2map-output.json never gives a traceback: the folder is not ours,
    refused with one line naming the manifest; nothing in it changes."""
    out = tmp_path / "m"
    assert main(_generate(space_file, 1, out, "--no-picture", "--no-apollo")) == 0
    manifest = out / atomic.MANIFEST
    manifest.write_bytes(MALFORMED[name])
    monkeypatch.setattr(atomic, "OUTPUT_MANIFEST_MAX_BYTES", 1000)  # "huge": over it
    before = sorted((p.name, p.read_bytes()) for p in out.iterdir())
    assert main(_generate(space_file, 2, out, "--no-picture", "--no-apollo")) == 2
    err = one_line(capsys)
    assert f"{manifest}: malformed" in err and "not an output feat2map wrote" in err
    assert sorted((p.name, p.read_bytes()) for p in out.iterdir()) == before
    assert not atomic.ours(out, ("map.json",))
    assert [p.name for p in tmp_path.iterdir()] == ["m"]


def test_an_out_that_is_a_link_is_written_through_and_leaves_no_stray_link(tmp_path, space_file):
    """Issue 35: `--out LINK` (to a folder) writes the output into the link's target, keeps the
    link, and leaves no hidden staging link behind, on the first run and on a replace."""
    target = tmp_path / "data"
    target.mkdir()
    link = tmp_path / "out"
    link.symlink_to(target)
    for seed in (1, 2):
        assert main(_generate(space_file, seed, link, "--no-picture", "--no-apollo")) == 0
        assert link.is_symlink() and os.readlink(link) == str(target)
        assert json.loads((target / "map.json").read_text())["meta"]["seed"] == seed
        assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "out"]


def test_an_error_while_staging_names_the_output_not_the_staging_folder(tmp_path, capsys):
    """Issue 35: an Apollo export refused inside `generate --spec` names DIR/apollo, never the
    hidden `.DIR.stage-...` folder; the same for any Feat2MapError or OSError of a staged block."""
    ring = tmp_path / "ring.yaml"  # a two-way closed ring: two loops, so Apollo's routing graph is refused
    pts = [(40, 0, 90), (0, 40, 180), (-40, 0, 270), (0, -40, 0), (40, 0, 90)]
    roads = "".join(f"      - {{end: [{x}, {y}], heading: {h}}}\n" for x, y, h in pts[1:])
    ring.write_text("version: 1\nchains:\n  - name: ring\n    lanes_forward: 1\n    lanes_backward: 1\n"
                    f"    start: {{point: [40, 0], heading: 90}}\n    roads:\n{roads}")
    out = tmp_path / "o"
    assert main(["generate", "--spec", str(ring), "--out", str(out), "--no-picture", "--quiet"]) == 2
    err = one_line(capsys)
    assert err.startswith(f"feat2map: error: {out / 'apollo'}: refusing to export") and ".stage-" not in err
    assert [p.name for p in tmp_path.iterdir()] == ["ring.yaml"]
    for make in (lambda t: Feat2MapError("bad", f"{t}/x.json"), lambda t: Feat2MapError(f"{t}/x.json is bad"),
                 lambda t: FileNotFoundError(2, "No such file", f"{t}/x.json")):
        with pytest.raises((Feat2MapError, OSError)) as info, atomic.staged_dir(tmp_path / "d") as tmp:
            raise make(tmp)
        assert str(tmp_path / "d" / "x.json") in str(info.value) and ".stage-" not in str(info.value)


def test_a_failed_file_write_names_the_file_not_its_temporary(tmp_path, monkeypatch):
    def full_disk(src, dst):
        raise OSError(28, "No space left on device", src)

    monkeypatch.setattr(atomic.os, "replace", full_disk)
    with pytest.raises(OSError) as info:
        atomic.write_bytes(tmp_path / "map.json", b"{}")
    assert info.value.filename == str(tmp_path / "map.json") and ".tmp-" not in str(info.value)
    assert list(tmp_path.iterdir()) == []
