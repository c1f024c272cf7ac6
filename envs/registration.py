"""Gymnasium registration of the feat2map environments (string entry points, no import cost);
each id has a native batched vector env (envs/vector.py) as its `vector_entry_point`."""
from __future__ import annotations

import gymnasium

ENV_IDS = {
    "feat2map/JunctionGrid-v0": "feat2map.envs.junction_env:JunctionGridEnv",
    "feat2map/MapFile-v0": "feat2map.envs.junction_env:MapFileEnv",
}
VECTOR_ENTRY_POINTS = {
    "feat2map/JunctionGrid-v0": "feat2map.envs.vector:junction_grid_vector",
    "feat2map/MapFile-v0": "feat2map.envs.vector:map_file_vector",
}


def register_envs() -> None:
    """Register every id once (safe to call repeatedly)."""
    for env_id, entry in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry, vector_entry_point=VECTOR_ENTRY_POINTS[env_id])
