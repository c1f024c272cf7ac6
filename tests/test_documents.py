"""The one JSON/YAML loader: nesting, alias and size limits fail fast with one short line; no
NaN/inf gets through; specs, suites, feature spaces and native maps all read through it."""
from __future__ import annotations

import json
import time

import pytest

from feat2map.config import raised_limits
from feat2map.documents import load_document, parse_document
from feat2map.errors import ERROR_MAX_CHARS, Feat2MapError, FeatureError, MapFormatError
from feat2map.features import FeatureSpace
from feat2map.formats import native
from feat2map.scenarios.scenario import ScenarioError, load_suite
from feat2map.spec import SpecError, load_spec


def alias_bomb() -> str:
    """The classic billion-laughs YAML: nine levels of nine aliases, about 420 bytes."""
    lines = ['a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    lines += [f"a{i}: &a{i} [{','.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    return "\n".join(lines + ["junctions: *a8"]) + "\n"


def test_a_yaml_alias_bomb_fails_fast_with_a_short_error(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(alias_bomb())
    assert len(path.read_bytes()) < 450
    t0 = time.process_time()
    with pytest.raises(SpecError, match="aliases are expanded") as err:
        load_spec(path)
    assert time.process_time() - t0 < 5.0  # a bound against the 88 s and 1.8 GB of the unguarded loader
    assert len(str(err.value)) <= ERROR_MAX_CHARS and str(path) in str(err.value)


@pytest.mark.parametrize("fmt, text", [("json", "[" * 5000 + "]" * 5000), ("yaml", "a: " + "[" * 5000 + "]" * 5000),
                                       ("yaml", "".join(" " * i + "- \n" for i in range(0, 400, 2))),
                                       ("json", '["' + "]" * 3000 + '", ' + "[" * 3000 + "]" * 3000 + "]")])
def test_deep_nesting_is_an_error_not_a_recursion_error(fmt, text):
    with pytest.raises(Feat2MapError, match="nested deeper than the limit max_nesting"):
        parse_document(text, "deep", fmt)


def test_nesting_limit_can_be_raised():
    doc = "[" * 150 + "]" * 150
    with pytest.raises(Feat2MapError):
        parse_document(doc, "d", "json")
    with raised_limits(max_nesting=200):
        assert parse_document(doc, "d", "json") == eval(doc)


@pytest.mark.parametrize("fmt, text, where", [("json", '{"a": NaN}', "d"), ("json", '{"a": [1, 1e400]}', "a[1]"),
                                              ("yaml", "a: {b: .inf}", "a.b"), ("yaml", "a: [.NaN]", "a[0]")])
def test_non_finite_numbers_are_refused_naming_the_element(fmt, text, where):
    with pytest.raises(Feat2MapError, match="not a finite number") as err:
        parse_document(text, "d", fmt)
    assert where in str(err.value)


def test_recursive_aliases_and_python_tags_are_refused():
    with pytest.raises(Feat2MapError, match="recursive"):
        parse_document("a: &x [*x]", "d", "yaml")
    with pytest.raises(Feat2MapError, match="not valid YAML"):
        parse_document("a: !!python/object/apply:os.system [echo hi]", "d", "yaml")


def test_plain_anchors_and_aliases_still_work():
    doc = parse_document("base: &b {lanes: 2}\nother: *b\n", "d", "yaml")
    assert doc == {"base": {"lanes": 2}, "other": {"lanes": 2}}


def test_file_size_limit(tmp_path):
    path = tmp_path / "big.json"
    path.write_text(json.dumps({"x": "y" * 5000}))
    with raised_limits(max_document_bytes=1000), pytest.raises(Feat2MapError, match="max_document_bytes"):
        load_document(path)


def test_every_document_kind_uses_the_loader_and_quotes_no_content(tmp_path):
    """A file that is not a document of the kind is refused without echoing its content."""
    secret = "root:x:0:0:root:/root:/bin/bash\ndaemon:x:1:1::/usr/sbin:/usr/sbin/nologin\n"
    cases = [(load_spec, "s.yaml", SpecError), (load_suite, "u.yaml", ScenarioError),
             (FeatureSpace.load, "f.json", FeatureError), (native.load, "m.json", MapFormatError)]
    for load, name, error in cases:
        path = tmp_path / name
        path.write_text(secret)
        with pytest.raises(error) as err:
            load(path)
        assert "root:x:0" not in str(err.value) and "nologin" not in str(err.value), (name, str(err.value))
        assert "\n" not in str(err.value)
