"""Gymnasium environments on feat2map maps (highway-env based): see map_env for info keys."""
from __future__ import annotations

from .registration import ENV_IDS, register_envs

__all__ = ["ENV_IDS", "parallel_env", "register_envs"]


def parallel_env(config=None, render_mode=None):
    """The PettingZoo ParallelEnv of many agents on one map (envs/multi_agent.py; needs pettingzoo)."""
    from .multi_agent import parallel_env as make

    return make(config, render_mode)
