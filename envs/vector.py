"""A native batched vector env: N sub-envs of one map whose traffic lives in one `TrafficCore`
(one table of rows with a slot per row), stepped together by one call per simulation frame.

`gym.make_vec("feat2map/JunctionGrid-v0", num_envs=N, vectorization_mode="vector_entry_point",
config={...})` (and for MapFile-v0) returns a `MapVectorEnv`. Each sub-env is an ordinary
`MapEnv` (the same code: its ego, rules, judge, observation, reward and info) whose road is a
slot of the shared core; `map_env.simulate` steps all of them frame by frame, the traffic of all
sub-envs in one array program (`TrafficCore.act` / `step`). With the same seeds and actions a
sub-env gives exactly what a single env gives (tests/envs/test_vector_native.py).

Gymnasium's conventions as in its `SyncVectorEnv` (reset seeds per sub-env, `options["reset_mask"]`,
autoreset next-step by default, `autoreset_mode` honoured, info as arrays with "_key" masks).
`render()` draws one sub-env (`render_env`, default 0).
"""
from __future__ import annotations

import contextlib
from copy import deepcopy
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, SyncVectorEnv, VectorEnv
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array, iterate

from ..errors import Feat2MapError
from .core import TrafficCore
from .driver_view import DriverViewObservation, driver_views
from .info_columns import Records, SignalStates
from .map_env import (MapEnv, check_action, check_options, held_feature_info, info_dicts, simulate,
                      step_ends)
from .observation import Kinematics, TrafficControlObservation
from .sim.observe import kinematics

# config values a batch cannot hold: (key, value, why)
UNSUPPORTED = (("new_map_each_reset", True, "the sub-envs of a batch share one map"),
               ("manual_control", True, "no keyboard in a batch"))
MAP_KEYS = ("map_seed", "features", "feature_space", "generation", "map_file", "map")  # fixed for a batch's life


class MapVectorEnv(VectorEnv):
    """N `env_class` sub-envs of one config whose traffic shares one core (module docstring).
    A `gymnasium.vector.VectorEnv` of its own: it keeps its buffers itself (no other vector
    env's internals)."""

    def __init__(self, env_class: type[MapEnv], num_envs: int, config: dict | None = None,
                 render_mode: str | None = None, autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
                 render_env: int = 0, copy: bool = True) -> None:
        if int(num_envs) < 1:
            raise Feat2MapError(f"must be >= 1, got {num_envs}", "num_envs")
        check_config(config or {})
        if not 0 <= render_env < num_envs:
            raise Feat2MapError(f"must be in [0, {num_envs}), got {render_env}", "render_env")
        self.render_env = render_env
        self.num_envs = int(num_envs)
        self.copy = copy
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        self.envs: list[Any] = [env_class(config=config, render_mode=render_mode if k == render_env else None)
                                for k in range(self.num_envs)]
        first = self.envs[0]
        self.metadata = {**first.metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = render_mode
        self.single_observation_space, self.single_action_space = first.observation_space, first.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        n = self.num_envs
        self._env_obs: list[Any] = [None] * n  # each sub-env's latest observation
        self._obs = create_empty_array(self.single_observation_space, n=n, fn=np.zeros)  # them, batched
        self._rewards = np.zeros(n, dtype=np.float64)
        self._terminations = np.zeros(n, dtype=np.bool_)
        self._truncations = np.zeros(n, dtype=np.bool_)
        self._ended = np.zeros(n, dtype=np.bool_)  # ended at the last step: next-step autoreset resets them
        self._step_values: tuple = ({}, {})  # the last step's info columns, the column of each sub-env
        net = first.net
        self.core = TrafficCore(net, n)
        for k, env in enumerate(self.envs):
            env.share(self.core, k, net)

    def reset(self, *, seed=None, options: dict[str, Any] | None = None):
        """Reset the sub-envs (all, or those of `options["reset_mask"]`, a bool array of N) with
        seeds `seed` (an int: seed + k for sub-env k; or one per sub-env); `options["config"]`
        may change anything but the map and the keys the batch refuses. Everything is checked
        before any sub-env is reset."""
        check_options(options)
        options = dict(options or {})
        cfg = dict(options.get("config") or {})
        check_config(cfg)
        for key in MAP_KEYS:
            if key in cfg:
                raise Feat2MapError("the sub-envs of a batch keep the map they were made with: make a new batch",
                                    f"options.config.{key}")
        n = self.num_envs
        seeds = [None] * n if seed is None else [seed + k for k in range(n)] if isinstance(seed, int) else list(seed)
        if len(seeds) != n:
            raise Feat2MapError(f"must be one seed per sub-env ({n}), got {len(seeds)}", "seed")
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = np.ones(n, dtype=np.bool_)
        elif not (isinstance(mask, np.ndarray) and mask.dtype == np.bool_ and mask.shape == (n,) and mask.any()):
            raise Feat2MapError(f"must be a bool array of shape ({n},) with a True, got {mask!r}",
                                "options.reset_mask")
        items = []
        for k in np.nonzero(mask)[0].tolist():
            self._env_obs[k], info = self.envs[k].reset(seed=seeds[k], options=options)
            items.append((k, info))
        self._terminations[mask] = self._truncations[mask] = self._ended[mask] = False
        return self._batch_obs(), self.stack_infos(items)

    def step(self, actions):
        """Step every sub-env (next-step autoreset: those that ended last step are reset
        instead), all stepping ones together (`map_env.simulate`). A bad batch action is refused
        before any sub-env changes (`batch_actions`)."""
        acts = self.batch_actions(actions)
        done_infos: dict[int, dict] = {}
        ended = np.flatnonzero(self._ended).tolist()
        stepping = list(range(self.num_envs))
        if ended and self.autoreset_mode == AutoresetMode.DISABLED:
            raise Feat2MapError(f"sub-env {ended[0]} ended: with autoreset_mode disabled, reset it (options "
                                "reset_mask) before stepping it again", "step")
        if ended and self.autoreset_mode == AutoresetMode.NEXT_STEP:
            for i in ended:
                self._env_obs[i], done_infos[i] = self.envs[i].reset()
            self._rewards[ended] = 0.0
            self._terminations[ended] = self._truncations[ended] = False
            stepping = np.flatnonzero(~self._ended).tolist()
        envs = [self.envs[i] for i in stepping]
        acts = acts if len(stepping) == self.num_envs else [acts[i] for i in stepping]
        for env, act in zip(envs, acts):
            env.begin_step(act, checked=True)
        simulate(envs, acts)
        observed = self.observe(envs)
        infos: dict[str, Any] = {}
        own = np.array([env.vehicle.row for env, obs in zip(envs, observed) if obs is None], dtype=np.int64)
        with self.core.observing(own) if len(own) else contextlib.nullcontext():  # who observes itself
            if self.batch_end(envs):
                infos = self.end_steps(stepping, envs, acts, observed)
            else:
                for i, env, act, obs in zip(stepping, envs, acts, observed):
                    self._env_obs[i], self._rewards[i], self._terminations[i], self._truncations[i], done_infos[i] = \
                        env.end_step(act, obs)
        finals, ended = [], []
        if self.autoreset_mode == AutoresetMode.SAME_STEP:
            for i in np.flatnonzero(self._terminations | self._truncations).tolist():
                env = self.envs[i]
                if i not in done_infos:  # its info is in the batch's columns
                    cols, column_of = self._step_values
                    done_infos[i] = info_dicts(cols, env.action_space, [column_of[i]])[0]
                    ended.append(i)
                finals.append((i, {"final_obs": self._env_obs[i], "final_info": done_infos[i]}))
                self._env_obs[i], done_infos[i] = env.reset()
        if ended:  # (their info is the new episode's)
            infos = drop_envs(infos, ended)
        items = finals + sorted(done_infos.items())
        if items:  # (their values replace the columns' of the same sub-envs)
            infos = merge_infos(infos, self.stack_infos(items))
        self._ended = self._terminations | self._truncations
        return self._batch_obs(), np.copy(self._rewards), np.copy(self._terminations), np.copy(self._truncations), infos

    def _batch_obs(self):
        """The sub-envs' latest observations as one batch (a copy unless `copy` is False)."""
        self._obs = concatenate(self.single_observation_space, self._env_obs, self._obs)
        return deepcopy(self._obs) if self.copy else self._obs

    def get_attr(self, name: str) -> tuple:
        """Attribute `name` of every sub-env."""
        return tuple(getattr(env, name) for env in self.envs)

    def close_extras(self, **kwargs) -> None:
        for env in self.envs:
            env.close()

    def batch_actions(self, actions) -> list:
        """The sub-envs' actions of a batch action (`batch_actions`), refused before any sub-env
        is reset or stepped (a refused step leaves the batch as it was)."""
        return batch_actions(self.single_action_space, self.action_space, actions, self.num_envs)

    def observe(self, envs: list[MapEnv]) -> list:
        """The observations of `envs` where one program over the batch makes them (the Kinematics
        egos, `sim.observe.kinematics`; the DriverView egos, `driver_view.driver_views`; also
        inside the traffic-control dict), None for the others (each observes itself)."""
        types = [env.observation_type for env in envs]
        wrapped = bool(types) and isinstance(types[0], TrafficControlObservation)
        types = [t.inner if wrapped else t for t in types]
        picks = [k for k, t in enumerate(types) if type(t) is Kinematics]
        kin: list = [None] * len(types)
        for k, o in zip(picks, kinematics([types[k] for k in picks], self.core)):
            kin[k] = o
        views = [k for k, t in enumerate(types) if type(t) is DriverViewObservation]
        for k, o in zip(views, driver_views([envs[k] for k in views]) if views else ()):
            kin[k] = o
        if not wrapped:
            return kin
        return [None if o is None else {"observation": o, "traffic_control": env.traffic_control_vector()}
                for env, o in zip(envs, kin)]

    def batch_end(self, envs: list[MapEnv]) -> bool:
        """Whether `end_steps` stands in for the `end_step`s of `envs` (their classes keep
        MapEnv's reward, termination and info: asked of one env of each class)."""
        return bool(envs) and all(env.keeps_step_hooks() for env in {type(env): env for env in envs}.values())

    def end_steps(self, stepping: list[int], envs: list[MapEnv], actions: list, observed: list) -> dict:
        """What `MapEnv.end_step` does for each of `envs` (sub-envs `stepping`): their rewards,
        ends and info columns at once (`map_env.step_ends`), the batched info of the columns."""
        for i, env, obs in zip(stepping, envs, observed):
            self._env_obs[i] = env.observation_type.observe() if obs is None else obs
        self._rewards[stepping], self._terminations[stepping], self._truncations[stepping], cols = \
            step_ends(envs, actions, batch=True)
        shown = self.envs[self.render_env]  # (the one sub-env with a render mode)
        if shown.render_mode == "human" and shown in envs:
            shown.render()
        self._step_values = (cols, {i: k for k, i in enumerate(stepping)})  # for the final info of same-step autoresets
        return self.stack_columns(stepping, cols)

    def stack_columns(self, idx: list[int], cols: dict[str, Any]) -> dict[str, Any]:
        """The batched info of the info columns `cols` of sub-envs `idx` (`info_columns.columns`):
        what `stack_infos` makes of the same values (held containers are copied into the arrays,
        never kept)."""
        n = self.num_envs
        out: dict[str, Any] = {}
        mask = np.zeros(n, dtype=np.bool_)
        mask[idx] = True
        space = self.single_action_space
        for key, col in cols.items():
            if key == "action":  # (the actions given, as the action space's arrays)
                array = np.zeros((n, *(space.shape or ())), dtype=space.dtype)
                array[idx] = np.array(col, dtype=space.dtype)
                out[key], out[f"_{key}"] = array, mask.copy()
            elif key == "junction_feature":  # (the features ahead: their info dicts, `map_env.feature_info`)
                out[key], out[f"_{key}"] = self.stack_features(idx, col), mask.copy()
            elif isinstance(col, np.ndarray):
                array = np.zeros(n, dtype=col.dtype) if col.dtype != object else np.full(n, None, dtype=object)
                array[idx] = col
                out[key], out[f"_{key}"] = array, mask.copy()
            elif isinstance(col, Records):
                out[key], out[f"_{key}"] = self.stack_table(idx, col.keys, col.values), mask.copy()
            elif isinstance(col, SignalStates):
                out[key], out[f"_{key}"] = col.stacked(n, idx), mask.copy()
            else:
                out[key], out[f"_{key}"] = self.stack_values(key, idx, col)
        return out

    def stack_features(self, idx: list[int], features: np.ndarray) -> dict[str, Any]:
        """`stack_infos` of the info dicts (`map_env.held_feature_info`) of sub-envs `idx`' junction
        features (`features`, an object array): each key's few distinct values (a batch has few
        junctions) stacked once, then spread to the sub-envs by one index (`stack_values`)."""
        feats = features.tolist()
        ids = np.fromiter(map(id, feats), dtype=np.uint64, count=len(feats))
        _, first, where = np.unique(ids, return_index=True, return_inverse=True)
        infos = [held_feature_info(feats[k])[1] for k in first.tolist()]
        out: dict[str, Any] = {}
        for key in infos[0]:  # (every feature's dict has these keys, of these types)
            out[key], out[f"_{key}"] = self.stack_values(key, idx, [info[key] for info in infos], where)
        return out

    def stack_infos(self, items: list[tuple[int, dict]]) -> dict[str, Any]:
        """The batched info of (sub-env, info) pairs: what `VectorEnv._add_info` makes of them
        one by one (arrays per key, "_key" masks, nested dicts alike), a key at a time."""
        columns: dict[str, tuple[list[int], list]] = {}  # one pass: each key's (sub-envs, values)
        for i, d in items:
            for key, value in d.items():
                idx, vals = columns.setdefault(key, ([], []))
                idx.append(i)
                vals.append(value)
        out: dict[str, Any] = {}
        for key, (idx, vals) in columns.items():
            out[key], out[f"_{key}"] = self.stack_values(key, idx, vals)
        return out

    def stack_values(self, key: str, idx: list[int], vals: list, where: np.ndarray | None = None) -> tuple[Any, np.ndarray]:
        """(array, mask) of one info key's values of sub-envs `idx` (`stack_infos`): `vals` one per
        sub-env, or with `where` the distinct values, sub-env `idx[k]`'s being `vals[where[k]]`."""
        n = self.num_envs
        first = vals[0]
        scalar = type(first) in (int, float, bool) or issubclass(type(first), np.number)
        if where is not None and not (key != "final_obs" and (scalar or isinstance(first, np.ndarray))):
            vals, where = [vals[w] for w in where.tolist()], None  # (one value per sub-env: the cases below)
        if isinstance(first, dict) and key != "final_obs":
            array: Any = self.stack_records(idx, vals)
            if array is None:
                array = self.stack_infos(list(zip(idx, vals)))
        elif key != "final_obs" and scalar:
            array = np.zeros(n, dtype=type(first))
            array[idx] = vals if where is None else np.array(vals, dtype=type(first))[where]
        elif key != "final_obs" and isinstance(first, np.ndarray):
            array = np.zeros((n, *first.shape), dtype=first.dtype)
            array[idx] = stack_held(vals) if where is None else np.stack(vals)[where]
        else:
            array = np.full(n, None, dtype=object)
            for i, v in zip(idx, vals):
                array[i] = list(v) if key == "new_violations" else v
        mask = np.zeros(n, dtype=np.bool_)
        mask[idx] = True
        return array, mask

    def stack_records(self, idx: list[int], vals: list[dict]) -> dict[str, Any] | None:
        """`stack_infos` of dicts that all have the same keys in the same order (None for other
        dicts): values of one scalar type in the first (the violation counts, the reward terms)
        as one table whose columns are the arrays, others (a junction's feature) a key at a time."""
        first = vals[0]
        keys = tuple(first)
        if any(tuple(d) != keys for d in vals):
            return None
        kinds = {type(v) for v in first.values()}
        if len(kinds) != 1 or (kind := kinds.pop()) not in (int, float, bool):
            out: dict[str, Any] = {}
            for key in keys:
                out[key], out[f"_{key}"] = self.stack_values(key, idx, [d[key] for d in vals])
            return out
        return self.stack_table(idx, keys, np.array([list(d.values()) for d in vals], dtype=kind))

    def stack_table(self, idx: list[int], keys: tuple[str, ...], values: np.ndarray) -> dict[str, Any]:
        """`stack_records` of dicts given as a [len(idx), keys] table of their values."""
        table = np.zeros((len(keys), self.num_envs), dtype=values.dtype)
        table[:, idx] = values.T
        mask = np.zeros(self.num_envs, dtype=np.bool_)
        mask[idx] = True
        out: dict[str, Any] = {}
        for key, column in zip(keys, table):
            out[key], out[f"_{key}"] = column, mask.copy()
        return out

    def render(self):
        """The frame of sub-env `render_env` (None without a render mode)."""
        return self.envs[self.render_env].render() if self.render_mode is not None else None


def merge_infos(infos: dict[str, Any], more: dict[str, Any]) -> dict[str, Any]:
    """Batched infos `infos` with the sub-envs' values of batched infos `more` in them (where
    `more`'s masks say; its keys and nested keys added), in place."""
    for key, value in more.items():
        if key.startswith("_") and key[1:] in more:
            continue
        mask = more[f"_{key}"]
        if key not in infos:
            infos[key], infos[f"_{key}"] = value, mask
            continue
        if isinstance(value, dict):
            merge_infos(infos[key], value)
        else:
            infos[key][mask] = value[mask]
        infos[f"_{key}"] = infos[f"_{key}"] | mask
    return infos


def drop_envs(infos: dict[str, Any], idx: list[int]) -> dict[str, Any]:
    """Batched infos `infos` without the values of sub-envs `idx` (as if they had none: their
    masks False, their values blank, a key that no sub-env is left with gone), a new dict."""
    out: dict[str, Any] = {}
    for key, value in infos.items():
        if key.startswith("_") and key[1:] in infos:
            continue
        mask = infos[f"_{key}"].copy()
        mask[idx] = False
        if not mask.any():
            continue
        if isinstance(value, dict):
            value = drop_envs(value, idx)
        else:
            value = value.copy()
            value[idx] = None if value.dtype == object else 0
        out[key], out[f"_{key}"] = value, mask
    return out


def stack_held(arrays: list[np.ndarray]) -> np.ndarray:
    """`np.stack(arrays)`, each array object stacked once where many sub-envs hold the same one
    (a junction feature's arrays are held per feature: a batch has few junctions)."""
    of: dict[int, int] = {}
    where = [of.setdefault(id(a), len(of)) for a in arrays]
    if 2 * len(of) > len(arrays):
        return np.stack(arrays)
    return np.stack(list({id(a): a for a in arrays}.values()))[where]


def batch_actions(single: spaces.Space, batched: spaces.Space, actions: Any, n: int) -> list:
    """The `n` sub-envs' actions of batch action `actions` (of space `batched`, `n` actions of
    space `single`), each checked (`map_env.check_action`); else a Feat2MapError naming the
    sub-env and its value. An array of valid actions is checked at once (`valid_batch`)."""
    if isinstance(actions, np.ndarray) and valid_batch(single, actions, n):
        return actions.tolist() if type(single) is spaces.Discrete else list(actions)  # (ints; else what `iterate` gives)
    try:
        acts = list(iterate(batched, actions))
    except (TypeError, ValueError, AssertionError, IndexError):
        raise Feat2MapError(f"must be one action per sub-env ({n}), got {type(actions).__name__} "
                            f"{np.shape(actions) if isinstance(actions, np.ndarray) else ''}".rstrip(),
                            "actions") from None
    if len(acts) != n:
        raise Feat2MapError(f"must be one action per sub-env: {n}, got {len(acts)}", "actions")
    for i, a in enumerate(acts):
        try:
            check_action(single, a)
        except Feat2MapError as exc:
            raise Feat2MapError(exc.message, f"actions[{i}] (sub-env {i})") from None
    return acts


def valid_batch(space: spaces.Space, actions: np.ndarray, n: int) -> bool:
    """Whether array `actions` holds `n` actions that `map_env.check_action` passes, checked at
    once: integers in range for a Discrete space, finite values of its shape for a Box; False for
    anything else, which the checks action by action then name."""
    if actions.shape[:1] != (n,):
        return False
    if type(space) is spaces.Discrete:
        k = actions - int(space.start)
        return actions.ndim == 1 and actions.dtype.kind in "iu" and bool(((k >= 0) & (k < space.n)).all())
    if type(space) is spaces.Box:
        return actions.shape[1:] == space.shape and actions.dtype.kind == "f" and bool(np.isfinite(actions).all())
    return False


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


SAME_STEP_HOWTO = ("make it with same-step autoreset: gym.make_vec(ID, num_envs=N, autoreset_mode='SameStep') "
                   "(a keyword of make_vec itself: Gymnasium refuses vector_kwargs for a vector_entry_point env), "
                   "or vectorization_mode='async', vector_kwargs={'autoreset_mode': 'SameStep'}")


def same_step(venv) -> None:
    """Switch `venv` (a `MapVectorEnv` or a `SyncVectorEnv`, or a wrapper of one) to same-step
    autoreset before its next reset; a Feat2MapError saying how to make it so for any other."""
    base = venv.unwrapped
    if venv.metadata.get("autoreset_mode") == AutoresetMode.SAME_STEP:
        return
    if not isinstance(base, (MapVectorEnv, SyncVectorEnv)):  # an AsyncVectorEnv's mode lives in its workers
        raise Feat2MapError(f"SB3 needs same-step autoreset and {type(base).__name__} cannot switch to it: "
                            + SAME_STEP_HOWTO, "autoreset_mode")
    base.autoreset_mode = AutoresetMode.SAME_STEP
    base.metadata["autoreset_mode"] = AutoresetMode.SAME_STEP  # in place: vector wrappers share this dict
