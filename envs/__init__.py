"""Gymnasium environments on feat2map maps (highway-env based): see map_env for info keys."""
from __future__ import annotations

from .registration import ENV_IDS, register_envs

__all__ = ["ENV_IDS", "register_envs"]
