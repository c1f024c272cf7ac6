"""RLlib trains on the native batched vector env through its env runner: two PPO iterations
with `gym_env_vectorize_mode="vector_entry_point"`, the env runner's env being `MapVectorEnv`.

Needs `ray[rllib]`; RLlib 2.60 pins gymnasium 1.2.2 (this project runs 1.4), so it is skipped in
the project's venv. Run it in a venv with RLlib (docs/benchmarks.md gives the command)."""
from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import pytest

import feat2map
from feat2map.envs.vector import MapVectorEnv

rllib = pytest.importorskip("ray.rllib", reason="ray[rllib] is not installed (it pins gymnasium 1.2.2)")

J = feat2map.JunctionFeature.make
CONFIG = {"features": [J([0, 90, 180], "signal", True).to_dict(), J([0, 90, 180, 270], "stop", False).to_dict()],
          "traffic_vehicles": 3, "route_junctions": 1, "duration": 4.0, "policy_frequency": 2,
          "observation": {"type": "DriverView"}}


@pytest.mark.slow
def test_rllib_ppo_trains_on_the_batched_env():
    import ray
    from ray.rllib.algorithms.ppo import PPOConfig

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
