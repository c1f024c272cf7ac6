"""feat2map: concise, junction-diverse HD maps for testing driving planners (Feat2Map)."""
from __future__ import annotations

__version__ = "0.1.0"

from .config import GenerationConfig  # noqa: E402
from .features import PAPER_SF_FEATURE_SPACE, FeatureSpace, JunctionFeature, Socket, normalize_rotation  # noqa: E402
from .generate import generate, generate_from_features  # noqa: E402
from .model import HDMap  # noqa: E402

__all__ = [
    "GenerationConfig", "FeatureSpace", "JunctionFeature", "Socket", "HDMap", "PAPER_SF_FEATURE_SPACE",
    "generate", "generate_from_features", "normalize_rotation", "__version__",
]

from .commonroad_io import install as _commonroad_io_install  # noqa: E402
from .envs.registration import register_envs as _register_envs  # noqa: E402

_commonroad_io_install()  # commonroad-io's XML readers importable next to our protobuf

_register_envs()
