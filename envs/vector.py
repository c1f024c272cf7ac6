"""A native batched vector env: N sub-envs of one map whose traffic lives in one `TrafficCore`
(one table of rows with a slot per row), stepped together by one call per simulation frame.

`gym.make_vec("feat2map/JunctionGrid-v0", num_envs=N, vectorization_mode="vector_entry_point",
config={...})` (and for MapFile-v0) returns a `MapVectorEnv`. Each sub-env is an ordinary
`MapEnv` (the same code: its ego, rules, judge, observation, reward and info) whose road is a
slot of the shared core; `map_env.simulate` steps all of them frame by frame, the traffic of all
sub-envs in one array program (`TrafficCore.act` / `step`). With the same seeds and actions a
sub-env gives exactly what a single env gives (tests/test_envs_vector_native.py).

Gymnasium's conventions as in `SyncVectorEnv` (reset seeds per sub-env, `options["reset_mask"]`,
autoreset next-step by default, `autoreset_mode` honoured, info as arrays with "_key" masks).
`render()` draws one sub-env (`render_env`, default 0).
"""
from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.vector.utils import concatenate, iterate

from ..errors import Feat2MapError
from .core import TrafficCore
from .map_env import MapEnv, simulate

# config values a batch cannot hold: (key, value, why)
UNSUPPORTED = (("traffic_core", "objects", "the batch steps the arrays core only"),
               ("new_map_each_reset", True, "the sub-envs of a batch share one map"),
               ("manual_control", True, "no keyboard in a batch"))


class MapVectorEnv(SyncVectorEnv):
    """N `env_class` sub-envs of one config whose traffic shares one core (module docstring)."""

    def __init__(self, env_class: type[MapEnv], num_envs: int, config: dict | None = None,
                 render_mode: str | None = None, autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
                 render_env: int = 0, copy: bool = True) -> None:
        if int(num_envs) < 1:
            raise Feat2MapError(f"must be >= 1, got {num_envs}", "num_envs")
        for key, value, why in UNSUPPORTED:
            if (config or {}).get(key) == value:
                raise Feat2MapError(f"{value!r} is not supported by the batched vector env ({why})", f"config.{key}")
        if not 0 <= render_env < num_envs:
            raise Feat2MapError(f"must be in [0, {num_envs}), got {render_env}", "render_env")
        self.render_env = render_env
        fns = [(lambda k=k: env_class(config=config, render_mode=render_mode if k == render_env else None))
               for k in range(int(num_envs))]
        super().__init__(fns, copy=copy, autoreset_mode=autoreset_mode)
        self.render_mode = render_mode
        first = self.envs[0]
        net = first.net
        self.core = TrafficCore(net, self.num_envs)
        for k, env in enumerate(self.envs):
            env.core_slot = (self.core, k)
            env._network = lambda net=net: net  # the map of the batch, for every reset

    def step(self, actions):
        """Step every sub-env (next-step autoreset: those that ended last step are reset
        instead), all stepping ones together (`map_env.simulate`)."""
        acts = list(iterate(self.action_space, actions))
        infos: dict[str, Any] = {}
        stepping, done_infos = [], {}
        for i, env in enumerate(self.envs):
            if self.autoreset_mode == AutoresetMode.NEXT_STEP and self._autoreset_envs[i]:
                self._env_obs[i], done_infos[i] = env.reset()
                self._rewards[i] = 0.0
                self._terminations[i] = self._truncations[i] = False
            else:
                if self.autoreset_mode == AutoresetMode.DISABLED:
                    assert not self._autoreset_envs[i], f"{self._autoreset_envs=}"
                stepping.append(i)
        envs = [self.envs[i] for i in stepping]
        for i, env in zip(stepping, envs):
            env._begin_step(acts[i])
        simulate(envs, [acts[i] for i in stepping])
        for i, env in zip(stepping, envs):
            self._env_obs[i], self._rewards[i], self._terminations[i], self._truncations[i], done_infos[i] = \
                env._end_step(acts[i])
        for i, env in enumerate(self.envs):
            info = done_infos[i]
            if self.autoreset_mode == AutoresetMode.SAME_STEP and (self._terminations[i] or self._truncations[i]):
                infos = self._add_info(infos, {"final_obs": self._env_obs[i], "final_info": info}, i)
                self._env_obs[i], info = env.reset()
            infos = self._add_info(infos, info, i)
        self._observations = concatenate(self.single_observation_space, self._env_obs, self._observations)
        self._autoreset_envs = np.logical_or(self._terminations, self._truncations)
        obs = self._observations
        return (np.copy(obs) if self.copy and isinstance(obs, np.ndarray) else obs, np.copy(self._rewards),
                np.copy(self._terminations), np.copy(self._truncations), infos)

    def render(self):
        """The frame of sub-env `render_env` (None without a render mode)."""
        return self.envs[self.render_env].render() if self.render_mode is not None else None


def junction_grid_vector(num_envs: int, **kwargs) -> MapVectorEnv:
    """`vector_entry_point` of feat2map/JunctionGrid-v0."""
    from .junction_env import JunctionGridEnv

    return MapVectorEnv(JunctionGridEnv, num_envs, **kwargs)


def map_file_vector(num_envs: int, **kwargs) -> MapVectorEnv:
    """`vector_entry_point` of feat2map/MapFile-v0."""
    from .junction_env import MapFileEnv

    return MapVectorEnv(MapFileEnv, num_envs, **kwargs)
