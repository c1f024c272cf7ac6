"""The `info` dict of the envs as one table: each key, its type and what it holds. The README's
info table and the docstrings point here; tests/envs/test_config.py checks that a real step's
info has exactly these keys with these types (single env, native vector env, multi-agent env).

Every key is in every info (reset and step), a new dict each time, each key of one type (arrays
of one dtype and shape) in every step and env, so that vector envs stack them: "none" is "" for
strings, -1 for counts, inf for distances and times, never None (nor NaN, which Gymnasium's
determinism checks cannot compare).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import MAP_ENV, MULTI


@dataclass(frozen=True)
class InfoKey:
    """One info key; a dotted key is a key of the dict under its first part."""
    key: str
    type: type
    doc: str
    env: str = MAP_ENV  # MapEnv (every env, the multi-agent env's agents too) or multi-agent (its own)


INFO_KEYS: tuple[InfoKey, ...] = (
    InfoKey("speed", float, "[m/s] the ego's speed"),
    InfoKey("crashed", bool, "the ego has crashed (highway-env's key)"),
    InfoKey("action", np.ndarray, "a copy of the action taken, in the action space's dtype (after reset, none was "
            "taken: the no-op, a meta-action's IDLE or the space's first value)"),
    InfoKey("junction", str, "id of the junction the ego is in, else the next one on its route (\"\")"),
    InfoKey("junction_feature", dict, "that junction's feature (the keys below)"),
    InfoKey("junction_feature.n_roads", int, "roads of the junction (-1 without one)"),
    InfoKey("junction_feature.control", str, "\"signal\" | \"stop\" | \"bare\" (\"\")"),
    InfoKey("junction_feature.crosswalk", bool, "the junction has crosswalks"),
    InfoKey("junction_feature.rotation", np.ndarray, "[deg] socket angles, MAX_LEGS (8) floats, inf padded"),
    InfoKey("junction_feature.lanes_in", np.ndarray, "incoming lanes per leg, 8 int64, -1 padded"),
    InfoKey("junction_feature.lanes_out", np.ndarray, "outgoing lanes per leg, 8 int64, -1 padded"),
    InfoKey("manoeuvre", str, "the ego's manoeuvre there: \"left\" | \"straight\" | \"right\" | \"uturn\" | a ramp's \"merge\" | "
            "\"diverge\" (\"\")"),
    InfoKey("control_ahead", str, "\"signal\" | \"stop\" | \"yield\" | \"bare\" for the next stop line on the "
            "route (\"yield\": the entry of a filter lane behind a yield sign), a mid-block crossing's light's "
            "included (\"\" past the last)"),
    InfoKey("signal_id", str, "the signal governing the ego's next stop line (\"\")"),
    InfoKey("signal_state", str, "its state: \"green\" | \"amber\" | \"red\" (\"\")"),
    InfoKey("signal_time_to_change", float, "[s] until its state changes (inf)"),
    InfoKey("signal_states", dict, "{signal id: state} of the next junction's signals (before a mid-block "
            "crossing's line: of the signals outside junctions)"),
    InfoKey("distance_to_stop_line", float, "[m] along the route from the ego centre to the next stop line (the "
            "junction entry where bare; inf if none)"),
    InfoKey("violations", dict, "counts {\"red_light\", \"stop_sign\", \"pedestrian_yield\"} so far this episode "
            "(the multi-agent env adds \"not_yielding\", \"stop_order\")"),
    InfoKey("new_violations", list, "violations committed during this step, e.g. [\"red_light\"]"),
    InfoKey("collision", bool, "the ego has collided"),
    InfoKey("off_road", bool, "the ego has left the road"),
    InfoKey("route_progress", float, "fraction of the route driven, 0..1"),
    InfoKey("route_completed", bool, "the ego is goal_distance into the route's last lane"),
    InfoKey("lane_id", str, "the map lane the ego is on (\"\")"),
    InfoKey("time", float, "[s] since reset"),
    InfoKey("rewards", dict, "{term: value} of this step's reward terms (zeros after reset)"),
    InfoKey("agent_collision", bool, "the agent crashed into another agent (collision is any crash)", MULTI),
    InfoKey("wait_time", float, "[s] stopped so far", MULTI),
)


def info_keys(*envs: str) -> dict[str, type]:
    """{key: type} of the top-level keys of `envs`' infos (every env's without arguments)."""
    return {k.key: k.type for k in INFO_KEYS if "." not in k.key and (not envs or k.env in envs)}


def markdown_table() -> str:
    """The info table of envs/README.md, made from INFO_KEYS."""
    rows = ["| key | type | what |", "|---|---|---|"]
    for k in INFO_KEYS:
        where = "" if k.env == MAP_ENV else f" ({k.env} only)"
        rows.append(f"| `{k.key}` | {k.type.__name__} | {k.doc.replace('|', chr(92) + '|')}{where} |")
    return "\n".join(rows) + "\n"
