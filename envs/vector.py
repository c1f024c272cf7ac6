"""A native batched vector env: N sub-envs of one map whose traffic lives in one `TrafficCore`
(one table of rows with a slot per row), stepped together by one call per simulation frame.

`gym.make_vec("feat2map/JunctionGrid-v0", num_envs=N, vectorization_mode="vector_entry_point",
config={...})` (and for MapFile-v0) returns a `MapVectorEnv`. Each sub-env is an ordinary
`MapEnv` (the same code: its ego, rules, judge, observation, reward and info) whose road is a
slot of the shared core; `map_env.simulate` steps all of them frame by frame, the traffic of all
sub-envs in one array program (`TrafficCore.act` / `step`). With the same seeds and actions a
sub-env gives exactly what a single env gives (tests/envs/test_vector_native.py).

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
from . import core
from .core import TrafficCore
from .kinematics_batch import observe_egos
from .map_env import MapEnv, simulate
from .observation import TrafficControlObservation

# config values a batch cannot hold: (key, value, why)
UNSUPPORTED = (("new_map_each_reset", True, "the sub-envs of a batch share one map"),
               ("manual_control", True, "no keyboard in a batch"))
MAP_KEYS = ("map_seed", "features", "feature_space", "generation", "map_file", "map")  # fixed for a batch's life


class MapVectorEnv(SyncVectorEnv):
    """N `env_class` sub-envs of one config whose traffic shares one core (module docstring)."""

    def __init__(self, env_class: type[MapEnv], num_envs: int, config: dict | None = None,
                 render_mode: str | None = None, autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
                 render_env: int = 0, copy: bool = True) -> None:
        if int(num_envs) < 1:
            raise Feat2MapError(f"must be >= 1, got {num_envs}", "num_envs")
        check_config(config or {})
        if not 0 <= render_env < num_envs:
            raise Feat2MapError(f"must be in [0, {num_envs}), got {render_env}", "render_env")
        self.render_env = render_env
        fns = [(lambda k=k: env_class(config=config, render_mode=render_mode if k == render_env else None))
               for k in range(int(num_envs))]
        super().__init__(fns, copy=copy, autoreset_mode=autoreset_mode)
        self.render_mode = render_mode
        envs: list[Any] = list(self.envs)  # MapEnvs (gymnasium types them as Env)
        net = envs[0].net
        self.core = TrafficCore(net, self.num_envs)
        for k, env in enumerate(envs):
            env.core_slot = (self.core, k)
            env._network = lambda net=net: net  # the map of the batch, for every reset

    def reset(self, *, seed=None, options: dict[str, Any] | None = None):
        """Reset the sub-envs (all, or those of `options["reset_mask"]`); `options["config"]`
        may change anything but the map and the keys the batch refuses."""
        cfg = dict((options or {}).get("config") or {})
        check_config(cfg)
        for key in MAP_KEYS:
            if key in cfg:
                raise Feat2MapError("the sub-envs of a batch keep the map they were made with: make a new batch",
                                    f"options.config.{key}")
        return super().reset(seed=seed, options=options)

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
        self.core.sync()  # respawns of every sub-env taken in at once (not one observation at a time)
        observed = self.observe(envs)
        for i, env, obs in zip(stepping, envs, observed):
            self._env_obs[i], self._rewards[i], self._terminations[i], self._truncations[i], done_infos[i] = \
                env._end_step(acts[i], obs)
        finals = []
        for i, env in enumerate(self.envs):
            if self.autoreset_mode == AutoresetMode.SAME_STEP and (self._terminations[i] or self._truncations[i]):
                finals.append((i, {"final_obs": self._env_obs[i], "final_info": done_infos[i]}))
                self._env_obs[i], done_infos[i] = env.reset()
        infos = self.stack_infos(finals + sorted(done_infos.items()))
        self._observations = concatenate(self.single_observation_space, self._env_obs, self._observations)
        self._autoreset_envs = np.logical_or(self._terminations, self._truncations)
        obs = self._observations
        return (np.copy(obs) if self.copy and isinstance(obs, np.ndarray) else obs, np.copy(self._rewards),
                np.copy(self._terminations), np.copy(self._truncations), infos)

    def observe(self, envs: list[MapEnv]) -> list:
        """The observations of `envs` where one array program over the batch makes them (the
        Kinematics egos, `kinematics_batch.observe_egos`, also inside the traffic-control dict),
        None for the others (each observes itself)."""
        if len(envs) < core.BATCH_MIN_EGOS:  # too few for the array program to pay
            return [None] * len(envs)
        types = [env.observation_type for env in envs]
        wrapped = isinstance(types[0], TrafficControlObservation)
        kin = observe_egos([t.inner if wrapped else t for t in types], self.core)
        if not wrapped:
            return kin
        return [None if o is None else {"observation": o, "traffic_control": env.traffic_control_vector()}
                for env, o in zip(envs, kin)]

    def stack_infos(self, items: list[tuple[int, dict]]) -> dict[str, Any]:
        """The batched info of (sub-env, info) pairs: what `VectorEnv._add_info` makes of them
        one by one (arrays per key, "_key" masks, nested dicts alike), a key at a time."""
        n = self.num_envs
        keys: dict[str, None] = {}
        for _, d in items:
            keys.update(dict.fromkeys(d))
        out: dict[str, Any] = {}
        for key in keys:
            sub = [(i, d[key]) for i, d in items if key in d]
            idx = [i for i, _ in sub]
            first = sub[0][1]
            if isinstance(first, dict) and key != "final_obs":
                array: Any = self.stack_infos(sub)
            elif key != "final_obs" and (type(first) in (int, float, bool) or issubclass(type(first), np.number)):
                array = np.zeros(n, dtype=type(first))
                array[idx] = [v for _, v in sub]
            elif key != "final_obs" and isinstance(first, np.ndarray):
                array = np.zeros((n, *first.shape), dtype=first.dtype)
                array[idx] = np.stack([v for _, v in sub])
            else:
                array = np.full(n, None, dtype=object)
                for i, v in sub:
                    array[i] = v
            mask = np.zeros(n, dtype=np.bool_)
            mask[idx] = True
            out[key], out[f"_{key}"] = array, mask
        return out

    def render(self):
        """The frame of sub-env `render_env` (None without a render mode)."""
        return self.envs[self.render_env].render() if self.render_mode is not None else None


def check_config(config: dict) -> None:
    """A Feat2MapError naming the first config key whose value the batch cannot hold."""
    for key, value, why in UNSUPPORTED:
        if config.get(key) == value:
            raise Feat2MapError(f"{value!r} is not supported by the batched vector env ({why})", f"config.{key}")


def junction_grid_vector(num_envs: int, **kwargs) -> MapVectorEnv:
    """`vector_entry_point` of feat2map/JunctionGrid-v0."""
    from .junction_env import JunctionGridEnv

    return MapVectorEnv(JunctionGridEnv, num_envs, **kwargs)


def map_file_vector(num_envs: int, **kwargs) -> MapVectorEnv:
    """`vector_entry_point` of feat2map/MapFile-v0."""
    from .junction_env import MapFileEnv

    return MapVectorEnv(MapFileEnv, num_envs, **kwargs)


def info_of(infos: dict[str, Any], i: int) -> dict[str, Any]:
    """Sub-env i's info from a vector env's batched info (the "_key" masks say which it has)."""
    out: dict[str, Any] = {}
    for key, value in infos.items():
        if key.startswith("_") or not infos.get(f"_{key}", np.ones(i + 1, dtype=bool))[i]:
            continue
        out[key] = info_of(value, i) if isinstance(value, dict) else value[i]
    return out


def sb3_vec_env(venv) -> Any:
    """A Stable-Baselines3 `VecEnv` over a Gymnasium vector env with same-step autoreset (such
    as `MapVectorEnv(..., autoreset_mode=AutoresetMode.SAME_STEP)` or a wrapper of it): SB3's conventions
    (done = terminated or truncated, the final observation in info["terminal_observation"],
    info["TimeLimit.truncated"]); infos are built only for the sub-envs whose episode ended."""
    from stable_baselines3.common.vec_env import VecEnv

    class GymnasiumVecEnv(VecEnv):
        def __init__(self, venv) -> None:
            if venv.metadata.get("autoreset_mode") != AutoresetMode.SAME_STEP:
                raise Feat2MapError("SB3 needs a vector env with autoreset_mode='same-step'", "autoreset_mode")
            self.venv = venv
            self._actions: np.ndarray | None = None
            super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)

        def reset(self):
            seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
            obs, _ = self.venv.reset(seed=seeds)
            self._reset_seeds()
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = actions

        def step_wait(self):
            obs, rew, term, trunc, info = self.venv.step(self._actions)
            done = term | trunc
            infos: list[dict] = [{} for _ in range(self.num_envs)]
            for i in np.nonzero(done)[0].tolist():
                infos[i] = info_of(info["final_info"], i)
                infos[i]["terminal_observation"] = info["final_obs"][i]
                infos[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
            return obs, rew.astype(np.float32), done, infos

        def close(self) -> None:
            self.venv.close()

        def _subs(self, indices) -> list:
            subs = self.venv.unwrapped.envs
            return [subs[i] for i in self._get_indices(indices)]

        def get_attr(self, attr_name: str, indices=None) -> list:
            return [getattr(e, attr_name) for e in self._subs(indices)]

        def set_attr(self, attr_name: str, value, indices=None) -> None:
            for e in self._subs(indices):
                setattr(e, attr_name, value)

        def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list:
            return [getattr(e, method_name)(*args, **kwargs) for e in self._subs(indices)]

        def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
            return [False for _ in self._subs(indices)]

    return GymnasiumVecEnv(venv)
