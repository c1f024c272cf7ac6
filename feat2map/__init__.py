"""feat2map: concise, junction-diverse HD maps for testing driving planners (Feat2Map).

The public API: generate maps (`generate`, `generate_from_features`), read and write any map
format (`read_map`, `write_map`), extract junction features from a map (`extract_junctions`);
the model (`HDMap`) and the feature types. Importing the package registers the Gymnasium envs.
"""
from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version as _version


def _package_version() -> str:
    """The installed distribution's version (pyproject.toml); a source tree that was never
    installed reports "0+unknown" rather than a version it cannot know."""
    try:
        return _version("feat2map")
    except PackageNotFoundError:
        return "0+unknown"


__version__ = _package_version()

from .config import GenerationConfig  # noqa: E402
from .extract import extract_junctions  # noqa: E402
from .features import PAPER_SF_FEATURE_SPACE, FeatureSpace, JunctionFeature, Socket, normalize_rotation  # noqa: E402
from .formats import read_map, write_map  # noqa: E402
from .generate import generate, generate_from_features  # noqa: E402
from .model import HDMap  # noqa: E402

__all__ = [
    "GenerationConfig", "FeatureSpace", "JunctionFeature", "Socket", "HDMap", "PAPER_SF_FEATURE_SPACE",
    "extract_junctions", "generate", "generate_from_features", "normalize_rotation", "read_map", "write_map",
    "__version__",
]

from .envs.registration import register_envs as _register_envs  # noqa: E402

_register_envs()
