"""Feat2MapError's place among Python's errors (issue 35): bad input is a ValueError, so a caller
that catches ValueError catches every feat2map error; code that wraps bad input keeps the inner
error's own message instead of swallowing it into a vaguer one."""
from __future__ import annotations

import pytest

from feat2map.errors import (ConfigError, CrossingRoadsError, Feat2MapError, FeatureError, LayoutError, LimitError,
                             MapFormatError)
from feat2map.formats import read_map
from feat2map.scenarios.rollout import SuiteResult
from feat2map.scenarios.scenario import ScenarioError
from feat2map.spec import SpecError


@pytest.mark.parametrize("cls", [Feat2MapError, FeatureError, MapFormatError, LayoutError, CrossingRoadsError,
                                 ConfigError, LimitError, SpecError, ScenarioError])
def test_every_feat2map_error_is_a_value_error(cls):
    assert issubclass(cls, ValueError)
    try:
        raise cls("bad value", "file.json: element")
    except ValueError as exc:  # what a caller that knows only Python's errors writes
        assert str(exc) == "file.json: element: bad value"


def test_a_bad_map_file_is_a_value_error_naming_the_file(tmp_path):
    bad = tmp_path / "m.json"
    bad.write_text("{")
    with pytest.raises(ValueError, match=f"^{bad}: not valid JSON"):
        read_map(bad)


def test_a_malformed_outcome_in_a_suite_result_keeps_its_own_message():
    """SuiteResult.from_dict catches ValueError around its outcomes: an outcome's own Feat2MapError
    passes through as it is (not re-wrapped as a vague "malformed suite result")."""
    with pytest.raises(Feat2MapError) as info:
        SuiteResult.from_dict({"name": "s", "planner": "p", "outcomes": [{"name": "a"}]}, "r/summary.json")
    assert str(info.value).startswith("r/summary.json: outcome 0: malformed outcome (KeyError('outcome'))")
    assert "malformed suite result" not in str(info.value)
