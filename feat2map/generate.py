"""The generation pipeline: feature space -> sampled features -> grid layout -> HD map."""
from __future__ import annotations

import contextlib
import gc
from dataclasses import replace
from typing import Iterator, Sequence

import numpy as np

from . import __version__
from .config import MAX_CARDINAL_DEVIATION_DEG, STRICT_CARDINAL_DEVIATION_DEG, GenerationConfig, limits
from .construct import MidblockRequest, RoadChain, assign_midblock, build_map
from .errors import ConfigError, CrossingRoadsError, snippet
from .features import FeatureSpace, JunctionFeature
from .layout import Cell, place
from .model import HDMap
from .sampling import sample_features, sample_midblock, sample_ramps


def check_seed(seed: int) -> int:
    """A seed is an integer 0 <= seed < 2**63 (numpy's seed sequences take no negatives)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise ConfigError(f"seed must be an integer from 0 to 2**63-1, got {snippet(seed)}")
    return int(seed)


@contextlib.contextmanager
def _no_cyclic_gc() -> Iterator[None]:
    """Building a map allocates millions of small tuples (polyline points) that form no cycles;
    the cyclic collector would walk them all again and again (a fifth of the build time)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def generate_from_features(features: Sequence[JunctionFeature], seed: int = 0,
                           config: GenerationConfig = GenerationConfig(),
                           cells: Sequence[Cell | None] | None = None, meta: dict | None = None,
                           chains: Sequence[RoadChain] = (), names: Sequence[str] | None = None,
                           keep_orientation: Sequence[bool] | None = None, progress: bool = False,
                           midblock: Sequence[MidblockRequest] = ()) -> HDMap:
    """Lay out and build a map with one junction per feature; each junction realizes the
    normalized form of its feature (the same shape, rotated and re-indexed). `chains` are
    hand-written roads added as they are (a map may consist of chains only); `names` label
    the features in layout errors; `keep_orientation` (per feature) prefers, among equally good
    placements, the quarter turn that shows the junction closest to its given angles.
    `midblock`: mid-block crosswalks, on the socket's road they name (a socket index of the
    feature as given) or on roads between junctions drawn with the seed.
    `progress` shows a bar over the junctions built, on a terminal only."""
    check_seed(seed)
    config.check_limits()
    limits().check("max_junctions", len(features), "the junction count")
    prefer = None
    if keep_orientation is not None:
        prefer = [round(-f.normalization().rotation_deg / 90.0) % 4 if keep else None
                  for f, keep in zip(features, keep_orientation)]
    info = {"generator": f"feat2map {__version__}", "seed": int(seed), "config": config.to_dict()}
    info.update(meta or {})
    normalized = [f.normalized() for f in features]
    requests = []
    for r in midblock:  # the socket index as given -> the normalized feature's
        if r.socket is not None:
            j, s = r.socket
            r = MidblockRequest(r.feature, (j, features[j].normalization().order.index(s)), r.name)
        requests.append(r)

    def build(max_deviation_deg: float) -> HDMap:
        rng = np.random.default_rng([int(seed), 1])
        placements = place(normalized, rng, cells, names, prefer, max_deviation_deg) if features or not chains else []
        crossings = assign_midblock(placements, requests, np.random.default_rng([int(seed), 2])) if requests else {}
        return build_map(placements, config, info, chains, progress=progress, midblock=crossings)

    with _no_cyclic_gc():
        try:
            return build(MAX_CARDINAL_DEVIATION_DEG)
        except CrossingRoadsError:  # lay it out again, sockets nearer their grid directions (more stubs)
            return build(STRICT_CARDINAL_DEVIATION_DEG)


def check_buildable(feature: JunctionFeature, config: GenerationConfig = GenerationConfig()) -> None:
    """Raise the FeatureError or LayoutError generation would raise on `feature`: its legs must
    keep the generation's minimum separation (a config may ask for more than the leg rule
    extraction applies) and the junction must be built on its own (it fits the grid gap).
    Extraction and generation agree through this: a junction extraction accepts either passes
    here or is reported as skipped."""
    replace(feature, min_separation_deg=config.min_socket_separation_deg)
    generate_from_features([feature], 0, config)


def generate(space: FeatureSpace, seed: int = 0, config: GenerationConfig = GenerationConfig(),
             progress: bool = False) -> HDMap:
    """Algorithm 1: one junction per feature combination (x samples_per_combination) and one ramp
    junction per ramp value (`sampling.sample_ramps`), seeded;
    `progress` shows a bar over the junctions built, on a terminal only."""
    rng = np.random.default_rng([check_seed(seed), 0])
    config.check_limits()
    features = sample_features(space, rng, config)
    midblock = [MidblockRequest(f, None, f"sampled mid-block crosswalk {k} ({f.control})")
                for k, f in enumerate(sample_midblock(space, rng, config))]
    features += sample_ramps(space, rng, config)
    return generate_from_features(features, seed, config, meta={"feature_space": space.to_dict()}, progress=progress,
                                  midblock=midblock)
