"""The registered environments: a generated junction grid, and any map file or HDMap.

`feat2map/JunctionGrid-v0` takes MapEnv's keys and its own (`feature_space`, `features`,
`map_seed`, `generation`, `new_map_each_reset`), `feat2map/MapFile-v0` MapEnv's and `map_file` or
`map`: every key's default, check and doc is a row of `config.SETTINGS` (the README's table).
"""
from __future__ import annotations

import json
from pathlib import Path

from ..config import GenerationConfig
from ..errors import Feat2MapError
from ..features import FeatureSpace, JunctionFeature
from .config import FILE, GRID, defaults
from .map_env import MapEnv, cached_network
from .network import MapNetwork


class JunctionGridEnv(MapEnv):
    """A map generated from a feature space (Feat2Map Algorithm 1), seeded."""

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update(defaults(GRID))
        return config

    def _network(self) -> MapNetwork:
        from ..generate import generate, generate_from_features

        seed = int(self.config["map_seed"])
        if self.config["new_map_each_reset"]:
            seed = int(self.np_random.integers(2**31 - 1))
        gen = GenerationConfig.from_dict(dict(self.config["generation"] or {}))
        feats = self.config.get("features")
        if feats:
            feats = [f if isinstance(f, JunctionFeature) else JunctionFeature.from_dict(f) for f in feats]
            key = ("features", json.dumps([f.to_dict() for f in feats], sort_keys=True), seed, json.dumps(gen.to_dict()))
            return cached_network(key, lambda: generate_from_features(feats, seed, gen))
        space = self.config["feature_space"]
        space = space if isinstance(space, FeatureSpace) else FeatureSpace.from_dict(space)
        key = ("space", space.to_json(), seed, json.dumps(gen.to_dict(), sort_keys=True))
        return cached_network(key, lambda: generate(space, seed, gen))


class MapFileEnv(MapEnv):
    """Any map: a file read by `feat2map.formats.read_map` (`map_file`) or an HDMap (`map`)."""

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update(defaults(FILE))
        return config

    def _network(self) -> MapNetwork:
        from ..formats import read_map

        if self.config.get("map") is not None:
            m = self.config["map"]
            return cached_network(("object", id(m)), lambda: m)
        path = self.config.get("map_file")
        if not path:
            raise Feat2MapError("MapFile-v0 needs config 'map_file' (a map file) or 'map' (an HDMap)", "config")
        p = Path(path)
        if not p.is_file():
            raise Feat2MapError("map file not found", str(p))
        return cached_network(("file", str(p.resolve()), p.stat().st_mtime_ns), lambda: read_map(p))
