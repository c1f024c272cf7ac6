"""Smoke version of examples/train_marl.py: a few seconds of shared-policy PPO over the agents of
one world per junction type, then the per-type table against the scripted driver."""
from __future__ import annotations

import csv
import importlib.util
import os
import sys
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import pytest
from conftest import SKIP_RL

pytest.importorskip("torch", reason=SKIP_RL)

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "train_marl.py"


def test_train_marl_writes_the_per_junction_table(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("train_marl", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["train_marl"] = mod
    spec.loader.exec_module(mod)
    assert mod.main(["--out", str(tmp_path), "--train-minutes", "0.03", "--episodes", "1", "--agents", "3",
                     "--rollout", "4"]) == 0
    rows = list(csv.DictReader((tmp_path / "table.csv").open()))
    assert [r["junction"] for r in rows] == [f"{n}-way {c}" for n, c in mod.TYPES]
    for r in rows:
        assert int(r["agents"]) == 3
        # the rule-following driver takes every agent through without agent collisions or order violations
        assert float(r["scripted_success"]) >= 2 / 3, r
        assert float(r["scripted_agent_collisions"]) == 0 and float(r["scripted_stop_order"]) == 0, r
    summary = (tmp_path / "summary.md").read_text()
    assert "| 4-way stop |" in summary and summary in capsys.readouterr().out
    assert (tmp_path / "policy.pt").stat().st_size > 0
