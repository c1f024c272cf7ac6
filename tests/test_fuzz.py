"""Fuzzing every reader: truncations and bit flips of a generated map in every format and of
every shared map (skipped when ../shared/maps is absent) go through every reader, the Apollo
validator and `feat2map extract`; each gives a valid, finite map (or problem list) or a
Feat2MapError / exit 2 naming the file, never another exception and never NaN or inf.

FEAT2MAP_FUZZ=N: N truncations and N bit-flip variants per file (default 1; the generated
map's files get 3 times as many). The mutations are new each run; a failure names its seed
(FEAT2MAP_TEST_SEED=N reruns them).
"""
from __future__ import annotations

import math
import os
import random
import warnings

import numpy as np
import pytest
from conftest import shared_map

import feat2map
from feat2map.cli import main
from feat2map.errors import Feat2MapError
from feat2map.formats import FORMATS, write_map
from feat2map.formats.apollo import validate_apollo

FUZZ = int(os.environ.get("FEAT2MAP_FUZZ", "1"))
SHARED_FILES = ["apollo/cube_town/base_map.bin", "apollo/cube_town/sim_map.txt", "apollo/borregas_ave/base_map.bin",
                "apollo/autonomous_stuff/base_map.bin", "apollo/shalun/base_map.bin", "apollo/gomentum/base_map.bin",
                "apollo/san_francisco/base_map.bin", "opendrive/esmini_fabriksgatan/fabriksgatan_traffic_lights.xodr",
                "opendrive/commonroad_four_way_crossing/four_way_crossing.xodr", "opendrive/svl_cubetown/cubetown.xodr",
                "opendrive/svl_borregas_ave/borregasave.xodr", "opendrive/carla_town01/Town01.xodr",
                "opendrive/carla_town03/Town03.xodr", "opendrive/commonroad_arg_carcarana/ARG_Carcarana-1_1_T-1.xodr"]
READERS = {name: fmt.face("read") for name, fmt in FORMATS.items() if fmt.read is not None}


def mutants(data: bytes, rng: random.Random, n: int) -> list[tuple[str, bytes]]:
    out = [(f"cut at {k}", data[:k]) for k in sorted(rng.sample(range(1, len(data)), min(n, len(data) - 1)))]
    for i in range(n):
        b = bytearray(data)
        for _ in range(rng.randint(1, 6)):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        out.append((f"flips {i}", bytes(b)))
    return out


def assert_finite_map(m) -> None:
    pts = [np.asarray(p, dtype=float) for ln in m.lanes.values()
           for p in (ln.centerline, ln.left_boundary, ln.right_boundary)]
    assert all(np.isfinite(p).all() for p in pts)
    assert all(math.isfinite(ln.width) and math.isfinite(ln.speed_limit) for ln in m.lanes.values())


def read_everything(path, check_cli: bool) -> None:
    """Every reader, the Apollo validator and `extract`: a valid result or a Feat2MapError; what
    they warn about (a mutant's or the map's own flaws, varying with the seed) names the file."""
    with warnings.catch_warnings(record=True) as found:
        warnings.simplefilter("always")
        _read_everything(path, check_cli)
    ours = [str(w.message) for w in found if issubclass(w.category, UserWarning)]
    assert all(str(path) in m and "\n" not in m for m in ours), [m for m in ours if str(path) not in m or "\n" in m]
    for w in found:  # anything else (a library's own warning) is shown as it would have been
        if not issubclass(w.category, UserWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def _read_everything(path, check_cli: bool) -> None:
    for name, read in READERS.items():
        try:
            m = read(path)
        except Feat2MapError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc), (name, str(exc))
        else:
            assert_finite_map(m)
    try:
        problems = validate_apollo(path)
    except Feat2MapError as exc:
        assert "\n" not in str(exc)
    else:
        assert all("\n" not in str(p) for p in problems)
    if check_cli:
        assert main(["extract", str(path), "--quiet"]) in (0, 2)


@pytest.fixture(scope="module")
def generated_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", True),
                                         feat2map.JunctionFeature.make([0, 120, 240], "stop", False)], seed=3)
    write_map(m, d / "map.json", "native")
    write_map(m, d / "map.xodr", "opendrive")
    write_map(m, d / "apollo", "apollo")
    return [d / "map.json", d / "map.xodr", d / "apollo" / "base_map.txt", d / "apollo" / "base_map.bin"]


@pytest.mark.parametrize("k", range(4))
def test_fuzzed_generated_maps(generated_files, tmp_path, k, capsys, random_seed):
    src = generated_files[k]
    rng = random.Random(f"{src.name}-{random_seed}")
    for label, data in mutants(src.read_bytes(), rng, 3 * FUZZ):
        path = tmp_path / f"m{src.suffix}"
        path.write_bytes(data)
        try:
            read_everything(path, check_cli=True)
        except AssertionError as exc:
            raise AssertionError(f"{src.name} {label} (seed {random_seed}): {exc}") from None
        capsys.readouterr()


@pytest.mark.parametrize("rel", SHARED_FILES)
def test_fuzzed_shared_maps(rel, tmp_path, random_seed):
    src = shared_map(rel)
    rng = random.Random(f"{rel}-{random_seed}")
    for label, data in mutants(src.read_bytes(), rng, FUZZ):
        path = tmp_path / src.name
        path.write_bytes(data)
        try:
            read_everything(path, check_cli=False)
        except AssertionError as exc:
            raise AssertionError(f"{rel} {label} (seed {random_seed}): {exc}") from None
