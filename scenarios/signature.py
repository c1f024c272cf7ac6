"""Failure signatures: what kind of failure a rollout outcome is, so that a search counts distinct
failures and merges duplicates. A signature is the junction feature where the drive failed (legs,
control, crosswalk, lanes per direction, one-way legs; not the exact angles), the ego's manoeuvre
there, the outcome, the planner's stage path in that junction and the rule involved (the violated
rule, else the rule that governs the junction: its signal, its stop sign, or right of way).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Mapping

from .rollout import Outcome

CONTROL_RULES = {"signal": "signal", "stop": "stop_sign", "bare": "right_of_way"}  # the rule a junction's control sets


@dataclass(frozen=True, order=True)
class Signature:
    """One kind of failure (module docstring); `key` is its one-line form."""

    junction: str  # e.g. "4-leg stop, crosswalk, 2 lanes, 1 one-way leg"
    manoeuvre: str  # left, straight, right, uturn ("-" when the drive failed before any junction)
    outcome: str  # collision, off_road, violation, timeout, error
    stage_path: tuple[str, ...]  # the planner's stages in that junction
    rule: str  # red_light, stop_sign, pedestrian_yield; else the junction's CONTROL_RULES

    @property
    def key(self) -> str:
        return f"{self.outcome} | {self.rule} | {self.junction} | {self.manoeuvre} | {' > '.join(self.stage_path) or '-'}"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["stage_path"] = list(self.stage_path)
        return d


def junction_kind(site: Mapping[str, Any]) -> str:
    """A junction feature without its angles: legs, control, crosswalk, lanes, one-way legs."""
    n = int(site.get("n_roads", -1))
    if n < 0:
        return "-"
    lanes_in, lanes_out = list(site.get("lanes_in", ())), list(site.get("lanes_out", ()))
    parts = [f"{n}-leg {site.get('control') or 'bare'}"]
    if site.get("crosswalk"):
        parts.append("crosswalk")
    most = max([*lanes_in, *lanes_out, 1])
    if most > 1:
        parts.append(f"{most} lanes")
    one_way = sum(1 for i, o in zip(lanes_in, lanes_out) if not i or not o)
    if one_way:
        parts.append(f"{one_way} one-way leg{'s' if one_way > 1 else ''}")
    return ", ".join(parts)


def signature_of(o: Outcome) -> Signature | None:
    """The signature of an outcome that did not complete (None for a completed one)."""
    if o.passed:
        return None
    site = dict(o.site)
    junction = str(site.get("junction") or "")
    stages: list[str] = []
    for e in o.events:
        if junction and e[2] == junction and (not stages or stages[-1] != e[4]):
            stages.append(str(e[4]))
    rule = str(site.get("rule") or CONTROL_RULES.get(str(site.get("control") or ""), "-"))
    return Signature(junction_kind(site), str(site.get("manoeuvre") or "-"), o.outcome, tuple(stages), rule)
