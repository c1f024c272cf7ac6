"""Same seed, same bytes: every file `generate`, `export` (every format in the FORMATS table) and
`suite` write is byte-identical across two runs, whatever the wall clock says; header dates
come from SOURCE_DATE_EPOCH (the reproducible-builds convention) or are left out. An env steps
the same in every process, whatever its string hashes (the order a set of lane ids iterates in)."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from feat2map.cli import main
from feat2map.errors import Feat2MapError
from feat2map.formats import FORMATS
from feat2map.formats.base import header_date

REPO = Path(__file__).resolve().parents[1]
WRITABLE = sorted(name for name, f in FORMATS.items() if f.write is not None)


def tree(root: Path) -> dict[str, bytes]:
    """Every file under `root` (or `root` itself), by relative path."""
    if root.is_file():
        return {root.name: root.read_bytes()}
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def assert_same_files(a: Path, b: Path) -> None:
    ta, tb = tree(a), tree(b)
    assert ta, f"{a} is empty"
    assert sorted(ta) == sorted(tb)
    differ = [name for name in ta if ta[name] != tb[name]]
    assert not differ, f"files differ between two runs with the same inputs: {differ}"


def run(args: list[str]) -> None:
    assert main(args) == 0, args


def outputs(root: Path) -> list[Path]:
    """One full run: generate (all pictures, Apollo, OpenDRIVE), export in every format, suite."""
    m = root / "m"
    run(["generate", "--seed", "5", "--opendrive", "--out", str(m), "--quiet"])
    made = [m]
    for name in WRITABLE:
        if FORMATS[name].input == "suite":
            continue
        out = root / "export" / (name if FORMATS[name].output == "dir" else f"map{FORMATS[name].suffixes[0]}")
        run(["export", name, str(m / "map.json"), "--out", str(out)])
        made.append(out)
    run(["suite", str(m / "map.json"), "--traffic", "3", "--pedestrian-rate", "2", "--out", str(root / "suite.yaml")])
    made.append(root / "suite.yaml")
    for name in WRITABLE:  # formats of suites (OpenSCENARIO)
        if FORMATS[name].input == "suite":
            run(["export", name, str(root / "suite.yaml"), "--out", str(root / "export" / name)])
            made.append(root / "export" / name)
    run(["generate", "--spec", str(REPO / "examples" / "one_way_t.yaml"), "--out", str(root / "t"), "--quiet"])
    made.append(root / "t")
    return made


def test_generate_export_suite_are_byte_identical_across_runs(tmp_path, monkeypatch):
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    first = outputs(tmp_path / "a")
    time.sleep(1.1)  # a writer stamping the wall clock (to the second) would now write other bytes
    second = outputs(tmp_path / "b")
    for a, b in zip(first, second):
        assert_same_files(a, b)
    base = (tmp_path / "a" / "m" / "apollo" / "base_map.txt").read_text()
    assert "date:" not in base.split("lane {")[0]
    assert ' date="' not in (tmp_path / "a" / "m" / "map.xodr").read_text()


def test_header_dates_come_from_source_date_epoch(tmp_path, monkeypatch, sf_default_map):
    from feat2map.formats import write_map

    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1000000000")
    write_map(sf_default_map, tmp_path / "apollo", "apollo")
    write_map(sf_default_map, tmp_path / "m.xodr", "opendrive")
    assert 'date: "2001-09-09T01:46:40"' in (tmp_path / "apollo" / "base_map.txt").read_text()
    assert 'date="2001-09-09T01:46:40"' in (tmp_path / "m.xodr").read_text()


def test_source_date_epoch_must_be_seconds(monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    with pytest.raises(Feat2MapError, match="SOURCE_DATE_EPOCH"):
        header_date()
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")
    assert header_date() == "1970-01-01T00:00:00"


# a batch of DriverView egos among traffic at the default grid's junctions: the digest of its
# observations and rewards over 120 random steps (ties between conflicting vehicles included)
_STEPS = """
import hashlib, numpy as np, gymnasium as gym, feat2map
env = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=8, vectorization_mode="vector_entry_point",
                   config={"observation": {"type": "DriverView"}, "traffic_vehicles": 12, "duration": 20.0})
obs, _ = env.reset(seed=0)
h, rng = hashlib.sha256(obs.tobytes()), np.random.default_rng(0)
for _ in range(120):
    obs, reward, *_ = env.step(rng.integers(0, 3, 8))
    h.update(obs.tobytes())
    h.update(reward.tobytes())
print(h.hexdigest())
"""


def test_an_env_steps_the_same_whatever_the_processs_string_hashes():
    digests = set()
    for hash_seed in ("1", "2", "3"):
        env = {**os.environ, "PYTHONHASHSEED": hash_seed, "SDL_VIDEODRIVER": "offscreen"}
        out = subprocess.run([sys.executable, "-c", _STEPS], env=env, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        digests.add(out.stdout.strip())
    assert len(digests) == 1, digests
