"""Stable-Baselines3 `VecEnv`s over Gymnasium vector envs (the native batched env above all):
`sb3_vec_env` in this process, `sb3_workers` over several worker processes, each stepping a
vector env of its own share of the sub-envs (what one batched env, a single process, cannot:
use more than one core). SB3 is imported only when an adapter is made (the `rl` extra)."""
from __future__ import annotations

import contextlib
import multiprocessing as mp
import traceback
from multiprocessing.connection import Connection
from typing import Any, Callable

import numpy as np
from gymnasium.vector.utils import batch_space

from ..errors import Feat2MapError
from .vector import batch_actions, info_of, same_step


def sb3_vec_env(venv) -> Any:
    """A Stable-Baselines3 `VecEnv` over a Gymnasium vector env: SB3's conventions (done =
    terminated or truncated, the final observation in info["terminal_observation"],
    info["TimeLimit.truncated"]); infos are built only for the sub-envs whose episode ended.
    SB3 needs same-step autoreset: a `gym.make_vec` env of the default mode (next-step) is
    switched to it (`same_step`; the adapter resets it first); an async one must be made so."""
    from stable_baselines3.common.vec_env import VecEnv

    class GymnasiumVecEnv(VecEnv):
        def __init__(self, venv) -> None:
            same_step(venv)
            self.venv = venv
            self._actions: np.ndarray | None = None
            super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)

        def reset(self):
            seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
            obs, _ = self.venv.reset(seed=seeds)
            self._reset_seeds()
            return obs

        def reset_with(self, seeds: list) -> np.ndarray:
            """`reset` with one seed (or None) per sub-env: what a worker of `sb3_workers` is sent."""
            self._seeds = list(seeds)
            return self.reset()

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


def sb3_workers(make: Callable[[int], Any], num_envs: int, workers: int = 2) -> Any:
    """A Stable-Baselines3 `VecEnv` of `num_envs` sub-envs split over `workers` processes: worker
    w holds `make(n_w)`, a Gymnasium vector env of its n_w sub-envs (the shares differ by one at
    most), adapted by `sb3_vec_env`; sub-env i is the i-th of the workers' sub-envs in worker
    order. A step sends each worker its actions and gathers what all return, so the workers step
    at once; seeds are SB3's per sub-env, so with the same seeds the sub-envs step as they would
    in one batch. `make` is called in the workers (started by fork where the platform has it, else
    by spawn, which needs a picklable `make`)."""
    from stable_baselines3.common.vec_env import VecEnv

    if not 1 <= int(workers) <= int(num_envs):
        raise Feat2MapError(f"must be in [1, num_envs={num_envs}], got {workers}", "workers")
    sizes = [len(a) for a in np.array_split(np.arange(int(num_envs)), int(workers))]

    class WorkersVecEnv(VecEnv):
        def __init__(self) -> None:
            method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
            ctx: Any = mp.get_context(method)
            self.pipes: list[Connection] = []
            self.procs: list[Any] = []
            for w, n in enumerate(sizes):
                here, there = ctx.Pipe()
                proc = ctx.Process(target=_worker, args=(there, here, make, n), daemon=True, name=f"feat2map-sb3-{w}")
                proc.start()
                there.close()
                self.pipes.append(here)
                self.procs.append(proc)
            self.first = np.cumsum([0] + sizes)
            self.closed = False
            obs_space, act_space = self._ask(0, "spaces", None)
            super().__init__(int(num_envs), obs_space, act_space)
            self.batched = batch_space(act_space, self.num_envs)

        def _ask(self, w: int, cmd: str, data: Any) -> Any:
            self.pipes[w].send((cmd, data))
            return self._answer(w)

        def _answer(self, w: int) -> Any:
            return self._answers([w])[0]

        def _answers(self, workers) -> list:
            """The answers of `workers`, every one read before a failure is raised (the pipes stay
            in step)."""
            got = [self.pipes[w].recv() for w in workers]
            for w, (ok, out) in zip(workers, got):
                if not ok:
                    raise RuntimeError(f"sb3_workers: worker {w} failed:\n{out}")
            return [out for _, out in got]

        def _all(self, cmd: str, data: list) -> list:
            for w, d in enumerate(data):
                self.pipes[w].send((cmd, d))
            return self._answers(range(len(self.pipes)))

        def _split(self, values) -> list:
            return [values[a:b] for a, b in zip(self.first[:-1], self.first[1:])]

        def reset(self):
            obs = self._all("reset", self._split(list(self._seeds)))
            self._reset_seeds()
            return np.concatenate(obs)

        def step_async(self, actions: np.ndarray) -> None:
            """Every worker's actions, the whole batch checked first (`vector.batch_actions`): a
            refused step reaches no worker."""
            batch_actions(self.action_space, self.batched, actions, self.num_envs)
            for w, a in enumerate(self._split(np.asarray(actions))):
                self.pipes[w].send(("step", a))

        def step_wait(self):
            obs, rew, done, infos = zip(*self._answers(range(len(self.pipes))))
            return np.concatenate(obs), np.concatenate(rew), np.concatenate(done), [i for part in infos for i in part]

        def close(self) -> None:
            if self.closed:
                return
            self.closed = True
            for pipe in self.pipes:
                with contextlib.suppress(BrokenPipeError, EOFError, ConnectionResetError):  # a worker already gone
                    pipe.send(("close", None))
                    pipe.recv()
            for proc in self.procs:
                proc.join(timeout=10)
                if proc.is_alive():
                    proc.terminate()

        def _by_worker(self, indices) -> dict[int, list[int]]:
            """The local indices of `indices` (SB3's: None, an int or a list) per worker."""
            out: dict[int, list[int]] = {}
            for i in self._get_indices(indices):
                w = int(np.searchsorted(self.first, i, side="right")) - 1
                out.setdefault(w, []).append(i - int(self.first[w]))
            return out

        def _each(self, what: str, args: tuple, indices) -> list:
            parts = self._by_worker(indices)
            for w, local in parts.items():
                self.pipes[w].send((what, (args, local)))
            return [x for part in self._answers(list(parts)) for x in part or ()]

        def get_attr(self, attr_name: str, indices=None) -> list:
            return self._each("get_attr", (attr_name,), indices)

        def set_attr(self, attr_name: str, value, indices=None) -> None:
            self._each("set_attr", (attr_name, value), indices)

        def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list:
            return self._each("env_method", (method_name, args, kwargs), indices)

        def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
            return self._each("env_is_wrapped", (wrapper_class,), indices)

    return WorkersVecEnv()


def _worker(pipe: Connection, parent: Connection, make: Callable[[int], Any], n: int) -> None:
    """A worker of `sb3_workers`: its vector env of `n` sub-envs, adapted by `sb3_vec_env`, answers
    each command with (True, result), or (False, the traceback) when it raised."""
    parent.close()
    venv = None
    while True:
        try:
            cmd, data = pipe.recv()
        except EOFError:
            break
        if cmd == "close":
            if venv is not None:
                venv.close()
            pipe.send((True, None))
            break
        try:
            if venv is None:
                venv = sb3_vec_env(make(n))
            if cmd == "step":
                venv.step_async(data)
                out: Any = venv.step_wait()
            elif cmd == "reset":
                out = venv.reset_with(data)
            elif cmd == "spaces":
                out = (venv.observation_space, venv.action_space)
            elif cmd == "get_attr":
                out = venv.get_attr(data[0][0], data[1])
            elif cmd == "set_attr":
                out = venv.set_attr(*data[0], indices=data[1])
            elif cmd == "env_method":
                name, args, kwargs = data[0]
                out = venv.env_method(name, *args, indices=data[1], **kwargs)
            elif cmd == "env_is_wrapped":
                out = venv.env_is_wrapped(data[0][0], data[1])
            else:
                raise ValueError(f"unknown command {cmd!r}")
        except Exception:  # noqa: BLE001 (the main process raises it, naming this worker)
            pipe.send((False, traceback.format_exc()))
            continue
        pipe.send((True, out))
    pipe.close()
