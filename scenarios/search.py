"""`feat2map search`: search maps and traffic together for a planner's failures.

An Optuna study (TPE by default: it models mixed categorical, integer and float parameters and
conditional spaces, and Optuna is well kept; `sampler="random"` is the baseline it is measured
against) draws candidates from `search_space` in batches of `batch`, asked and told in trial
order, so that a seed gives the same candidates and outcomes whatever the worker count or backend.
Each candidate is a scenario, driven headless by the planner under test over the rollout
backends (a kept-open process pool, or Ray). Its value, maximised, is its criticality
(`criticality.score`: time-to-collision, distance, braking, time blocked) plus
SEARCH_FAILURE_BONUS when it fails, divided by one plus the earlier finds of its signature, so
the search keeps looking for new kinds of failure rather than the same one again.

Budgets: scenarios driven (`budget_scenarios`) or CPU seconds (`budget_seconds`: the workers'
CPU time per scenario plus this process's), checked after each batch, so a seconds budget ends
on a prefix of the same sequence of candidates. Each failure signature's first scenario is then
shrunk (`shrink`), and `write_search` writes the regression suite, its OpenSCENARIO export and the
report, replaying every written scenario to check that it fails the same way.
"""
from __future__ import annotations

import contextlib
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from feat2map.config import (BLOCKED_AFTER_S, SEARCH_BATCH, SEARCH_FAILURE_BONUS, SEARCH_MAX_INFEASIBLE,
                             SEARCH_STARTUP_TRIALS)
from feat2map.errors import Feat2MapError

from .criticality import score
from .rollout import BACKENDS, FAIL_POLICIES, Outcome, as_factory, check_blocked_after, run_suite
from .scenario import Scenario
from .search_space import Infeasible, MapCache, Start, suggest
from .shrink import shrink
from .signature import Signature, signature_of

SAMPLERS = ("tpe", "random")


@dataclass(frozen=True)
class Trial:
    """One candidate driven: its Optuna number and parameters, scenario, outcome and value."""

    number: int
    params: dict[str, Any]
    scenario: Scenario
    outcome: Outcome
    value: float
    signature: Signature | None
    cpu_s: float  # the search's CPU seconds when this candidate's batch ended

    def to_dict(self) -> dict[str, Any]:
        return {"number": self.number, "params": self.params, "scenario": self.scenario.to_dict(),
                "outcome": self.outcome.outcome, "message": self.outcome.message,
                "criticality": dict(self.outcome.criticality), "value": round(self.value, 6),
                "signature": self.signature.key if self.signature else None, "cpu_s": round(self.cpu_s, 3)}


@dataclass(frozen=True)
class Finding:
    """One failure signature: the trial that found it first, and its shrunk scenario and outcome."""

    signature: Signature
    trial: Trial
    scenario: Scenario  # shrunk (the trial's own scenario when no smaller one fails the same way)
    outcome: Outcome  # of `scenario`
    finds: int  # trials with this signature

    def to_dict(self) -> dict[str, Any]:
        return {"signature": self.signature.to_dict(), "key": self.signature.key, "found_by": self.trial.number,
                "found_at_cpu_s": round(self.trial.cpu_s, 3), "finds": self.finds, "params": self.trial.params,
                "criticality": dict(self.trial.outcome.criticality), "message": self.outcome.message,
                "original": self.trial.scenario.to_dict(), "shrunk": self.scenario.to_dict()}


@dataclass(frozen=True)
class SearchResult:
    """What a search drove and found; `history` is (CPU seconds, scenarios, distinct signatures)
    after each batch."""

    start: Start
    planner: str
    sampler: str
    seed: int
    trials: tuple[Trial, ...]
    findings: tuple[Finding, ...]
    history: tuple[tuple[float, int, int], ...]
    cpu_s: float
    infeasible: int
    stopped: str = ""
    budget: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"start": self.start.to_dict(), "planner": self.planner, "sampler": self.sampler, "seed": self.seed,
                "budget": self.budget, "scenarios": len(self.trials), "infeasible": self.infeasible,
                "cpu_s": round(self.cpu_s, 3), "stopped": self.stopped,
                "history": [[round(c, 3), n, k] for c, n, k in self.history],
                "findings": [f.to_dict() for f in self.findings], "trials": [t.to_dict() for t in self.trials]}


class Evaluator:
    """Drives batches of scenarios with one planner on a kept-open pool (or Ray): `__call__`
    returns their outcomes in order. A scenario the env refuses (bad input) is an `error` outcome
    of its own, not the end of the search. `cpu_s` adds up the workers' CPU seconds."""

    def __init__(self, planner: Any, *, workers: int, backend: str, blocked_after: float, executor: Any) -> None:
        self.factory = as_factory(planner)
        self.workers, self.backend, self.blocked_after, self.executor = workers, backend, blocked_after, executor
        self.cpu_s = 0.0

    def __call__(self, scenarios: Sequence[Scenario], gifs: bool = False) -> list[Outcome]:
        try:
            outcomes = list(self._run(scenarios, gifs))
        except Feat2MapError:
            if len(scenarios) == 1:
                from .rollout import _error_outcome

                return [_error_outcome(scenarios[0], 0, "the env refused the scenario")]
            outcomes = [o for sc in scenarios for o in self([sc], gifs)]
        self.cpu_s += sum(o.cpu_s for o in outcomes)
        return outcomes

    def _run(self, scenarios: Sequence[Scenario], gifs: bool) -> Sequence[Outcome]:
        result = run_suite(list(scenarios), self.factory, workers=self.workers, backend=self.backend, progress=False,
                           record_failure_gif=gifs, blocked_after=self.blocked_after, executor=self.executor)
        return result.outcomes


@contextlib.contextmanager
def evaluator(planner: Any, *, workers: int = 1, backend: str = "process",
              blocked_after: float = BLOCKED_AFTER_S) -> Iterator[Evaluator]:
    """An Evaluator whose workers live as long as the `with` block (spawned once, not per batch)."""
    from .rollout import _picklable, ray_session, worker_pool

    if backend not in BACKENDS:
        raise Feat2MapError(f"unknown backend (choose {', '.join(BACKENDS)})", f"backend {backend!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise Feat2MapError("must be an integer of at least 1", f"workers {workers!r}")
    check_blocked_after(blocked_after)
    factory = as_factory(planner)
    if not _picklable(factory):
        raise Feat2MapError("cannot be pickled for worker processes: use a module-level class or function",
                            f"planner {getattr(factory, 'name', planner)!r}")
    if backend == "ray":
        with ray_session(workers):
            yield Evaluator(factory, workers=workers, backend=backend, blocked_after=blocked_after, executor=None)
    else:
        with worker_pool(workers) as pool:
            yield Evaluator(factory, workers=workers, backend=backend, blocked_after=blocked_after, executor=pool)


def check_budget(budget_seconds: Any, budget_scenarios: Any) -> None:
    """At least one budget, each positive (errors name the option)."""
    if budget_seconds is None and budget_scenarios is None:
        raise Feat2MapError("give a budget: --budget-seconds or --budget-scenarios", "command line")
    if budget_seconds is not None and (isinstance(budget_seconds, bool) or not isinstance(budget_seconds, (int, float))
                                       or not 0 < budget_seconds < float("inf")):
        raise Feat2MapError(f"must be a positive number of CPU seconds, got {budget_seconds!r:.40}", "--budget-seconds")
    if budget_scenarios is not None and (isinstance(budget_scenarios, bool) or not isinstance(budget_scenarios, int)
                                         or budget_scenarios < 1):
        raise Feat2MapError(f"must be a positive integer, got {budget_scenarios!r:.40}", "--budget-scenarios")


def make_study(sampler: str, seed: int, startup: int = SEARCH_STARTUP_TRIALS) -> Any:
    """An Optuna study maximising the value, with a seeded TPE (drawing its first `startup`
    candidates at random) or random sampler."""
    try:
        import optuna
    except ImportError:
        raise Feat2MapError("Optuna is not installed (pip install 'feat2map[search]')", "feat2map search") from None
    if sampler not in SAMPLERS:
        raise Feat2MapError(f"unknown sampler (choose {', '.join(SAMPLERS)})", f"--sampler {sampler!r:.40}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
        raise Feat2MapError(f"must be an integer from 0 to 2**32-1, got {seed!r:.40}", "--seed")
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)  # multivariate, group, constant_liar
        chosen = (optuna.samplers.RandomSampler(seed=seed) if sampler == "random" else
                  optuna.samplers.TPESampler(seed=seed, n_startup_trials=startup, multivariate=True,
                                             group=True, constant_liar=True))
    return optuna.create_study(direction="maximize", sampler=chosen)


def search(start: Start, evaluate: Evaluator, *, workdir: Path, budget_seconds: float | None = None,
           budget_scenarios: int | None = None, seed: int = 0, sampler: str = "tpe", batch: int = SEARCH_BATCH,
           fail_on: str = "any", shrink_failures: bool = True, startup: int = SEARCH_STARTUP_TRIALS,
           log: Callable[[str], None] | None = None, progress: bool = False) -> SearchResult:
    """Search `start`'s space with the planner `evaluate` drives, until a budget is spent; returns
    every trial and one Finding per failure signature (shrunk unless `shrink_failures` is off).
    `fail_on` says which outcomes are failures (rollout's policies); TPE draws its first `startup`
    candidates at random. `log` gets a line per batch."""
    import optuna
    from tqdm import tqdm

    check_budget(budget_seconds, budget_scenarios)
    if fail_on not in FAIL_POLICIES:
        raise Feat2MapError(f"unknown failure policy (choose {', '.join(FAIL_POLICIES)})", f"--fail-on {fail_on!r:.40}")
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise Feat2MapError(f"must be a positive integer, got {batch!r:.40}", "--batch")
    study = make_study(sampler, seed, startup)
    maps = MapCache(workdir / "maps")
    cpu0 = time.process_time()
    trials: list[Trial] = []
    history: list[tuple[float, int, int]] = []
    seen: dict[Signature, int] = {}
    infeasible, stopped = 0, ""
    bar = tqdm(total=budget_scenarios or None, desc="search", unit="scenario", disable=not progress)

    cpu_before = evaluate.cpu_s  # an Evaluator may serve several searches

    def spent() -> float:
        return evaluate.cpu_s - cpu_before + time.process_time() - cpu0

    try:
        while True:
            left = batch if budget_scenarios is None else min(batch, budget_scenarios - len(trials))
            if left <= 0 or (budget_seconds is not None and spent() >= budget_seconds):
                break
            asked: list[tuple[Any, Scenario]] = []
            while len(asked) < left:
                trial = study.ask()
                try:
                    asked.append((trial, suggest(trial, start, maps, f"t{trial.number:05d}")))
                except Infeasible:
                    study.tell(trial, state=optuna.trial.TrialState.FAIL)
                    infeasible += 1
                    if infeasible > SEARCH_MAX_INFEASIBLE:
                        raise Feat2MapError(f"more than {SEARCH_MAX_INFEASIBLE} candidates could not be built: the "
                                            "feature space's ranges leave the legs too close", start.label) from None
            outcomes = evaluate([sc for _, sc in asked])
            now = spent()
            for (trial, sc), o in zip(asked, outcomes):
                sig = signature_of(o) if o.fails(fail_on) else None
                value = score(o.criticality, evaluate.blocked_after)
                if sig is not None:
                    value += SEARCH_FAILURE_BONUS / (1 + seen.get(sig, 0))
                    seen[sig] = seen.get(sig, 0) + 1
                study.tell(trial, value)
                trials.append(Trial(trial.number, dict(trial.params), sc, o, value, sig, now))
            history.append((now, len(trials), len(seen)))
            bar.update(len(asked))
            bar.set_postfix(signatures=len(seen))
            if log is not None:
                fails = sum(t.signature is not None for t in trials[-len(asked):])
                log(f"[{len(trials)} scenarios, {now:.0f} CPU s] {fails} of {len(asked)} failed; "
                    f"{len(seen)} distinct failure signatures")
    except KeyboardInterrupt:
        stopped = "interrupted (KeyboardInterrupt)"
    finally:
        bar.close()
    first: dict[Signature, Trial] = {}
    for t in trials:
        if t.signature is not None:
            first.setdefault(t.signature, t)
    found = {sig: (t.scenario, t.outcome) for sig, t in first.items()}
    if shrink_failures and found and not stopped:
        found = shrink(found, evaluate)
    findings = tuple(Finding(sig, first[sig], *found[sig], seen[sig]) for sig in first)
    return SearchResult(start, getattr(evaluate.factory, "name", "planner"), sampler, seed, tuple(trials), findings,
                        tuple(history), spent(), infeasible, stopped,
                        {"seconds": budget_seconds, "scenarios": budget_scenarios, "batch": batch, "fail_on": fail_on})
