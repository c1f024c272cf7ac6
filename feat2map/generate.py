"""The generation pipeline: feature space -> sampled features -> grid layout -> HD map."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from . import __version__
from .config import GenerationConfig
from .construct import build_map
from .features import FeatureSpace, JunctionFeature
from .layout import Cell, place
from .model import HDMap
from .sampling import sample_features


def generate_from_features(features: Sequence[JunctionFeature], seed: int = 0,
                           config: GenerationConfig = GenerationConfig(),
                           cells: Sequence[Cell | None] | None = None, meta: dict | None = None) -> HDMap:
    """Lay out and build a map with one junction per feature; each junction realizes the
    normalized form of its feature (the same shape, rotated and re-indexed)."""
    rng = np.random.default_rng([int(seed), 1])
    placements = place([f.normalized() for f in features], rng, cells)
    info = {"generator": f"feat2map {__version__}", "seed": int(seed), "config": config.to_dict()}
    info.update(meta or {})
    return build_map(placements, config, info)


def generate(space: FeatureSpace, seed: int = 0, config: GenerationConfig = GenerationConfig()) -> HDMap:
    """Algorithm 1: one junction per feature combination (x samples_per_combination), seeded."""
    rng = np.random.default_rng([int(seed), 0])
    features = sample_features(space, rng, config)
    return generate_from_features(features, seed, config, meta={"feature_space": space.to_dict()})
