"""Diversity metrics of suite results (the paper's Section V, RQ2): behaviour coverage (the
planner's (scenario, stage path) pairs and stage transitions, Fig. 7) and line coverage of the
planner under test (Fig. 6a), per junction and accumulated in junction order; `compare` puts
several maps' suites side by side.

Junction order: the order in which the suite's scenarios first drive into each junction
(suite order, then driving order), so "junction index" is reproducible for a fixed suite.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence, cast

from .rollout import MIXED_DIGEST, ROAD_CONTEXT, Outcome, SuiteResult

FULL_COVERAGE_SHARE = 0.95  # "junctions to reach 95% of the suite's lines/transitions"
LABELLED_POINTS_MAX = 40  # coverage plots name each junction up to this many per suite

Pair = tuple[str, tuple[str, ...]]  # (planner scenario, its stage path)
Transition = tuple[str, str]  # ("Scenario.Stage", "Scenario.Stage")


# ---- behaviour ----------------------------------------------------------------------------------
def outcome_behaviour(o: Outcome) -> dict[str, tuple[frozenset[Pair], frozenset[Transition]]]:
    """Per junction of one outcome: the (scenario, stage path) pairs and the stage transitions
    the planner made there (a transition belongs to the junction of the stage it enters, or,
    entering a road stage, to the junction of the stage it leaves)."""
    pairs: dict[str, set[Pair]] = {}
    trans: dict[str, set[Transition]] = {}
    run_j: str | None = None
    run_sc: str | None = None
    run: list[str] = []
    prev: str | None = None
    prev_j: str | None = None

    def flush() -> None:
        if run_sc is not None:
            pairs.setdefault(run_j or ROAD_CONTEXT, set()).add((run_sc, tuple(run)))

    for _, _, junction, scenario, stage in o.events:
        j = junction or ROAD_CONTEXT
        name = f"{scenario}.{stage}"
        if scenario != run_sc or j != run_j:
            flush()
            run_j, run_sc, run = j, scenario, []
        if not run or run[-1] != stage:
            run.append(stage)
        if prev is not None and prev != name:
            trans.setdefault(junction or prev_j or ROAD_CONTEXT, set()).add((prev, name))
        pairs.setdefault(j, set())
        prev, prev_j = name, junction
    flush()
    keys = set(pairs) | set(trans)
    return {j: (frozenset(pairs.get(j, ())), frozenset(trans.get(j, ()))) for j in keys}


def junction_order(outcomes: Iterable[Outcome]) -> tuple[str, ...]:
    """Junctions in the order the suite first reaches them (driven into, then only approached)."""
    order: dict[str, None] = {}
    outcomes = list(outcomes)
    for o in outcomes:
        for j in o.junctions:
            order.setdefault(j, None)
    for o in outcomes:
        for e in o.events:
            if e[2] is not None:
                order.setdefault(e[2], None)
        for j in o.junction_lines:
            if j != ROAD_CONTEXT:
                order.setdefault(j, None)
    return tuple(order)


@dataclass(frozen=True)
class Coverage:
    """One suite's coverage: per junction sets, and accumulated counts in junction order."""

    junctions: tuple[str, ...]
    pairs: Mapping[str, frozenset[Pair]]
    transitions: Mapping[str, frozenset[Transition]]
    lines: Mapping[str, frozenset[str]]  # empty when the suite ran without coverage
    paths: frozenset[tuple[str, tuple[str, ...]]]  # (suite scenario, whole stage path)

    def _accumulate(self, per: Mapping[str, frozenset]) -> tuple[int, ...]:
        seen: set = set(per.get(ROAD_CONTEXT, ()))
        out = []
        for j in self.junctions:
            seen |= per.get(j, frozenset())
            out.append(len(seen))
        return tuple(out)

    @property
    def accumulated_lines(self) -> tuple[int, ...]:
        return self._accumulate(self.lines)

    @property
    def accumulated_transitions(self) -> tuple[int, ...]:
        return self._accumulate(self.transitions)

    @property
    def accumulated_pairs(self) -> tuple[int, ...]:
        return self._accumulate(self.pairs)

    @property
    def all_pairs(self) -> frozenset[Pair]:
        return frozenset().union(*self.pairs.values()) if self.pairs else frozenset()

    @property
    def all_transitions(self) -> frozenset[Transition]:
        return frozenset().union(*self.transitions.values()) if self.transitions else frozenset()

    @property
    def all_lines(self) -> frozenset[str]:
        return frozenset().union(*self.lines.values()) if self.lines else frozenset()

    def new_lines(self) -> tuple[int, ...]:
        """Lines each junction adds to those of the junctions before it (Fig. 6a's steps)."""
        acc = self.accumulated_lines
        base = len(self.lines.get(ROAD_CONTEXT, ()))
        return tuple(b - a for a, b in zip((base,) + acc[:-1], acc))


def suite_coverage(result: SuiteResult | Sequence[Outcome]) -> Coverage:
    """Behaviour and line coverage of a suite result, per junction."""
    outcomes = list(cast(Iterable[Outcome], getattr(result, "outcomes", result)))
    pairs: dict[str, set[Pair]] = {}
    trans: dict[str, set[Transition]] = {}
    lines: dict[str, set[str]] = {}
    for o in outcomes:
        for j, (p, t) in outcome_behaviour(o).items():
            pairs.setdefault(j, set()).update(p)
            trans.setdefault(j, set()).update(t)
        for j, ls in o.junction_lines.items():
            lines.setdefault(j, set()).update(ls)
    freeze = lambda d: {k: frozenset(v) for k, v in sorted(d.items())}  # noqa: E731
    return Coverage(junctions=junction_order(outcomes), pairs=freeze(pairs), transitions=freeze(trans),
                    lines=freeze(lines), paths=frozenset((o.name, o.stage_path) for o in outcomes))


def junctions_to_reach(acc: Sequence[int], share: float = FULL_COVERAGE_SHARE) -> int:
    """How many junctions (in order) reach `share` of the final accumulated count (0 if none)."""
    if not acc or acc[-1] == 0:
        return 0
    target = share * acc[-1]
    return next(i + 1 for i, v in enumerate(acc) if v >= target)


# ---- comparison ----------------------------------------------------------------------------------
COMPARE_COLUMNS = ("suite", "planner", "scenarios", "completed", "failed", "junctions", "stage paths",
                   "scenario/stage pairs", "transitions", "lines", f"junctions to {int(FULL_COVERAGE_SHARE * 100)}% lines",
                   "unique transitions", "unique lines")


@dataclass(frozen=True)
class Comparison:
    """Side-by-side coverage of several suites' results."""

    names: tuple[str, ...]
    coverages: tuple[Coverage, ...]
    rows: tuple[tuple, ...]  # one per suite, COMPARE_COLUMNS
    warnings: tuple[str, ...] = ()

    def to_markdown(self) -> str:
        head = "| " + " | ".join(COMPARE_COLUMNS) + " |"
        sep = "|" + "|".join("---" if i < 2 else "---:" for i in range(len(COMPARE_COLUMNS))) + "|"
        body = ["| " + " | ".join(str(c) for c in r) + " |" for r in self.rows]
        notes = [""] + [f"Warning: {w}" for w in self.warnings] if self.warnings else []
        return "\n".join([head, sep, *body, *notes]) + "\n"

    def to_dict(self) -> dict:
        return {"columns": list(COMPARE_COLUMNS), "rows": [list(r) for r in self.rows], "warnings": list(self.warnings)}


def compare(results: Mapping[str, SuiteResult] | Sequence[SuiteResult]) -> Comparison:
    """A table comparing suites (e.g. one per map): outcomes, behaviour and line coverage, and
    what each suite covers that none of the others does."""
    if isinstance(results, Mapping):
        names, res = tuple(results), tuple(results.values())
    else:
        res = tuple(results)
        names = _unique_names([r.name for r in res])
    covs = tuple(suite_coverage(r) for r in res)
    rows = []
    for i, (name, r, c) in enumerate(zip(names, res, covs)):
        others_t = frozenset().union(*(x.all_transitions for k, x in enumerate(covs) if k != i))
        others_l = frozenset().union(*(x.all_lines for k, x in enumerate(covs) if k != i))
        counts = r.counts()
        measured = r.coverage and not r.sent_no_coverage
        lines = len(c.all_lines) if measured else "-"
        reach = junctions_to_reach(c.accumulated_lines) if measured else "-"
        rows.append((name, r.planner, len(r.outcomes), counts["completed"],
                     sum(v for k, v in counts.items() if k != "completed"), len(c.junctions),
                     len({p for _, p in c.paths}), len(c.all_pairs), len(c.all_transitions), lines, reach,
                     len(c.all_transitions - others_t), len(c.all_lines - others_l) if measured else "-"))
    digests = {r.planner_digest for r in res if r.coverage}
    warnings = [f"{n}: the planner's sources changed during the run: its line counts mix versions"
                for n, r in zip(names, res) if r.coverage and r.planner_digest == MIXED_DIGEST]
    warnings += [f"{n}: the planner sent no coverage (its bridge `bye` carried none): its line counts are "
                 f"unknown ('-'), not 0" for n, r in zip(names, res) if r.sent_no_coverage]
    if len(digests - {MIXED_DIGEST}) > 1:
        warnings.append("the suites measured different planner sources (planner_digest differs): "
                        "their line counts are not comparable")
    return Comparison(names=names, coverages=covs, rows=tuple(rows), warnings=tuple(warnings))


def _unique_names(names: Sequence[str]) -> tuple[str, ...]:
    out: list[str] = []
    seen: dict[str, int] = {}
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n} ({seen[n]})")
    return tuple(out)


def plot_accumulated(comparison: Comparison, path: str | Path, title: str = "") -> None:
    """Accumulated lines covered (left, as the paper's Fig. 6a) and stage transitions (right)
    against the junctions in the order each suite reaches them, one curve per suite; the x axis
    names the junctions (one suite), or each point carries its junction's id (several suites).
    PNG or SVG by the file name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, (ax_l, ax_t) = plt.subplots(1, 2, figsize=(12, 4.6))
    any_lines = False
    single = len(comparison.coverages) == 1
    longest = max([len(c.junctions) for c in comparison.coverages] + [1])
    for k, (name, c) in enumerate(zip(comparison.names, comparison.coverages)):
        x = list(range(1, len(c.junctions) + 1))
        curves = [(ax_t, c.accumulated_transitions)]
        if c.lines:
            any_lines = True
            curves.append((ax_l, c.accumulated_lines))
        for ax, y in curves:
            (line,) = ax.step(x, y, where="post", marker="o", ms=3, label=name)
            if not single and len(x) <= LABELLED_POINTS_MAX:
                for xi, yi, j in zip(x, y, c.junctions):
                    ax.annotate(j, (xi, yi), textcoords="offset points", xytext=(2, 4 + 8 * k), fontsize=6,
                                color=line.get_color())
    xlabel = ("junction, in the order the suite first reaches it" if single
              else "junction index (each suite's order; ids at the points)")
    ax_l.set(xlabel=xlabel, ylabel="accumulated planner lines covered",
             title="line coverage" if any_lines else "line coverage (not measured)")
    ax_t.set(xlabel=xlabel, ylabel="accumulated stage transitions", title="behaviour coverage")
    for ax in (ax_l, ax_t):
        ax.grid(alpha=0.3)
        ax.set_ylim(0, max(1.0, ax.get_ylim()[1]) * 1.08)  # room for the ids above the curves
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        if single and len(comparison.coverages[0].junctions) <= LABELLED_POINTS_MAX:
            js = comparison.coverages[0].junctions
            ax.set_xticks(range(1, len(js) + 1), [f"{i}\n{j}" for i, j in enumerate(js, 1)],
                          fontsize=7 if len(js) <= 20 else 5, rotation=0 if len(js) <= 20 else 90)
        elif longest <= LABELLED_POINTS_MAX:
            ax.set_xticks(range(1, longest + 1))
        else:
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlim(0.5, longest + 0.5)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
