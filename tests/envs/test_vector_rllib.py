"""RLlib trains on the native batched vector env through its env runner: two PPO iterations
with `gym_env_vectorize_mode="vector_entry_point"`, the env runner's env being `MapVectorEnv`.

RLlib 2.60 pins gymnasium 1.2.2 (this project's venv runs 1.4), so it lives in a venv of its own,
`.venv-rllib` (`bash scripts/setup_rllib.sh`, which CI runs): where `ray.rllib` is not importable
here, the test runs itself in that venv; it skips only where neither has RLlib."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import pytest

import feat2map

REPO = Path(__file__).resolve().parents[2]
RLLIB_PYTHON = REPO / os.environ.get("RLLIB_VENV", ".venv-rllib") / "bin" / "python"

J = feat2map.JunctionFeature.make
CONFIG = {"features": [J([0, 90, 180], "signal", True).to_dict(), J([0, 90, 180, 270], "stop", False).to_dict()],
          "traffic_vehicles": 3, "route_junctions": 1, "duration": 4.0, "policy_frequency": 2,
          "observation": {"type": "DriverView"}}


def _has_rllib() -> bool:
    try:
        import ray.rllib  # noqa: F401
    except ImportError:
        return False
    return True


def train_two_iterations() -> None:
    """Two PPO iterations of 128 env steps each, sampled by the env runner from MapVectorEnv."""
    import ray
    from ray.rllib.algorithms.ppo import PPOConfig

    from feat2map.envs.vector import MapVectorEnv

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        config = (PPOConfig().environment("feat2map/JunctionGrid-v0", env_config={"config": CONFIG})
                  .env_runners(num_env_runners=0, num_envs_per_env_runner=4, rollout_fragment_length=32,
                               gym_env_vectorize_mode="vector_entry_point")
                  .training(train_batch_size_per_learner=128, minibatch_size=64, num_epochs=1))
        algo = config.build_algo()
        assert isinstance(algo.env_runner.env.unwrapped, MapVectorEnv)
        steps = []
        for _ in range(2):
            steps.append(algo.train()["env_runners"]["num_env_steps_sampled_lifetime"])
        assert steps == [128, 256]
        algo.stop()
    finally:
        ray.shutdown()


@pytest.mark.slow
def test_rllib_ppo_trains_on_the_batched_env():
    if _has_rllib():
        train_two_iterations()
        return
    if not RLLIB_PYTHON.exists():
        pytest.skip(f"ray[rllib] is not installed here (it pins gymnasium 1.2.2) and {RLLIB_PYTHON} is absent: "
                    "bash scripts/setup_rllib.sh builds it")
    code = f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import test_vector_rllib as t; " \
           "t.train_two_iterations(); print('rllib ok')"
    p = subprocess.run([str(RLLIB_PYTHON), "-c", code], cwd=REPO, capture_output=True, text=True, timeout=900,
                       env={**os.environ, "SDL_VIDEODRIVER": "offscreen"})
    assert p.returncode == 0 and "rllib ok" in p.stdout, (p.stdout[-2000:] + p.stderr[-4000:])
