"""Deliberately weakened baseline planners: planted faults that `feat2map search` must find (its
known-answer check in tests/scenarios/test_search.py and benchmarks/bench_search.py). Each one is
the baseline planner (scenarios/planner.py) with one rule bent the way human drivers bend it, so
its failures show only in some junctions and traffic, never in every drive:

- `StopSignRoller` rolls through stop signs: it slows to a creep near the line but never makes the
  full stop (a `stop_sign` violation, found at any stop-controlled junction);
- `AmberRunner` takes an amber light for a green one: it neither stops at amber nor keeps out of the
  dilemma zone, so a light that turns amber while it is too far from the line to clear it before red
  sends it across on red (a `red_light` violation, found only when the signal timing, the ego's
  start and speed meet).

Use them as planner specs: `--planner feat2map.scenarios.faulty_planners:AmberRunner`.
"""
from __future__ import annotations

import math

from .planner import CREEP_TRIGGER_M, STOP_SIGN, BaselinePlanner


class StopSignRoller(BaselinePlanner):
    """The baseline planner that creeps through stop signs without the full stop: past its
    pre-stop stage it ignores the stop sign (arrival order included) and creeps across at the
    baseline's creep speed, still yielding to conflicting traffic and pedestrians."""

    def _transition(self) -> None:
        if self.scenario == STOP_SIGN and self.stage == "S_PS" and self._line_distance() <= CREEP_TRIGGER_M:
            self._go("S_C")  # the full stop of S_S skipped
            return
        super()._transition()

    def _rule_ignore(self) -> frozenset[str]:
        if self.scenario == STOP_SIGN and self.stage in ("S_PS", "S_C"):
            return super()._rule_ignore() | {"stop"}
        return super()._rule_ignore()


class AmberRunner(BaselinePlanner):
    """The baseline planner that treats amber as green: while its next signal shows amber it
    ignores the signal, and it never slows to stay out of the dilemma zone. Red is still obeyed,
    when it can still stop."""

    def _rule_ignore(self) -> frozenset[str]:
        env = self.env
        sl, _, _, _ = env.rules.line_ahead(env.vehicle)
        if sl is not None and sl.kind == "signal" and env.rules.signal_state(sl.control_id) == "amber":
            return super()._rule_ignore() | {"signal"}
        return super()._rule_ignore()

    def _amber_acceleration(self) -> float:
        return math.inf
