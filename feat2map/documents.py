"""JSON and YAML documents (specs, scenario suites, feature spaces, native maps) read through
one function, `load_document`, with the limits of `feat2map.config.Limits`: file size, nesting
depth (checked before parsing, so 5,000 nested brackets are an error, not a RecursionError),
YAML aliases (the expanded node count is counted from the event stream, so a 400-byte alias
bomb fails in milliseconds), and no NaN/inf numbers (JSON's `NaN`/`Infinity`, YAML's `.nan`/
`.inf`, overflowing literals such as 1e400). Errors are the caller's `Feat2MapError` subclass,
naming the file (and the line where the parser knows it) in one short line.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from .config import limits
from .errors import Feat2MapError, snippet

_BRACKETS = b"[]{}\""
_DELETE = bytes(c for c in range(256) if c not in _BRACKETS)
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_document(path: str | Path, error: type[Feat2MapError] = Feat2MapError, *, fmt: str | None = None,
                  finite: bool = True) -> Any:
    """Read and parse a JSON (`.json`) or YAML (any other suffix) file, within the limits.
    `fmt` ("json"/"yaml") overrides the suffix; `finite` rejects NaN/inf anywhere (native maps
    leave it to the map validation, which checks coordinates in bulk)."""
    path = Path(path)
    where = str(path)
    try:
        if path.is_dir():
            raise error("is a folder, not a file", where)
        limits().check("max_document_bytes", path.stat().st_size, "the file size (bytes)")
        data = path.read_bytes()
    except Feat2MapError as exc:
        raise error(exc.message, where) from None
    except OSError as exc:
        raise error(f"cannot read ({exc.strerror or type(exc).__name__})", where) from None
    kind = fmt or ("json" if path.suffix.lower() == ".json" else "yaml")
    return parse_document(data, where, kind, error, finite=finite)


def parse_document(data: bytes | str, where: str, fmt: str, error: type[Feat2MapError] = Feat2MapError, *,
                   finite: bool = True) -> Any:
    """Parse JSON or YAML text (see `load_document`)."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"not UTF-8 text (byte {exc.start})", where) from None
    if fmt == "json":
        _json_depth(raw, where, error)
        try:
            doc = json.loads(text, parse_constant=_reject_constant) if finite else json.loads(text)
        except ValueError as exc:  # JSONDecodeError, or a NaN/Infinity literal
            at = f"line {exc.lineno}: {exc.msg}" if isinstance(exc, json.JSONDecodeError) else str(exc)
            raise error(f"not valid JSON, truncated or corrupt ({at})", where) from None
        except RecursionError:  # brackets hidden from the depth scan cannot get here; kept as a backstop
            raise error(f"nested deeper than the limit max_nesting={limits().max_nesting}", where) from None
    else:
        _yaml_events(text, where, error)
        try:
            doc = yaml.load(text, Loader=_LOADER)  # noqa: S506 (a safe loader)
        except yaml.YAMLError as exc:
            raise error(f"not valid YAML ({_yaml_problem(exc)})", where) from None
    if finite:
        _check_finite(doc, where, error)
    return doc


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not a finite number")


def _json_depth(raw: bytes, where: str, error: type[Feat2MapError]) -> None:
    """Nesting depth of JSON text without parsing it: brackets outside strings, counted in bulk."""
    cap = limits().max_nesting
    kept = raw.replace(b"\\\\", b"").replace(b'\\"', b"").translate(None, _DELETE)
    if kept.count(b"[") + kept.count(b"{") <= cap:
        return
    a = np.frombuffer(kept, dtype=np.uint8)
    outside = (np.cumsum(a == ord('"'), dtype=np.int64) & 1) == 0
    step = np.zeros(len(a), dtype=np.int32)
    step[((a == ord("[")) | (a == ord("{"))) & outside] = 1
    step[((a == ord("]")) | (a == ord("}"))) & outside] = -1
    if len(step) and int(np.cumsum(step).max()) > cap:
        raise error(f"nested deeper than the limit max_nesting={cap} "
                    f"(raise it with --limit max_nesting=N)", where)


def _line(ev: yaml.Event) -> int | str:
    """The 1-based line an event starts on (the parser always marks it; "?" if not)."""
    return ev.start_mark.line + 1 if ev.start_mark is not None else "?"


def _yaml_events(text: str, where: str, error: type[Feat2MapError]) -> None:
    """Depth and alias-expanded size of a YAML document from its event stream (no recursion,
    nothing built): an alias adds the size of the node it names."""
    lim = limits()
    sizes: dict[str, int] = {}
    stack: list[list] = [[None, 0]]  # [anchor, nodes so far] per open collection
    total = 0
    try:
        for ev in yaml.parse(text, Loader=_LOADER):
            if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                stack.append([ev.anchor, 1])
                if len(stack) - 1 > lim.max_nesting:
                    raise error(f"nested deeper than the limit max_nesting={lim.max_nesting} "
                                f"(raise it with --limit max_nesting=N)", f"{where}: line {_line(ev)}")
            elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                anchor, n = stack.pop()
                if anchor is not None:
                    sizes[anchor] = n
                stack[-1][1] += n
            elif isinstance(ev, yaml.ScalarEvent):
                stack[-1][1] += 1
                if ev.anchor is not None:
                    sizes[ev.anchor] = 1
            elif isinstance(ev, yaml.AliasEvent):
                if ev.anchor not in sizes:
                    raise error(f"alias *{ev.anchor} refers to a node that is not complete (a recursive "
                                "document)", f"{where}: line {_line(ev)}")
                stack[-1][1] += sizes[ev.anchor]
            total = sum(n for _, n in stack)
            if total > lim.max_yaml_nodes:
                raise error(f"more than {lim.max_yaml_nodes} nodes once aliases are expanded (an alias bomb?) "
                            f"(raise it with --limit max_yaml_nodes=N)", where)
    except yaml.YAMLError as exc:
        if "nesting depth" in str(getattr(exc, "problem", "")):  # PyYAML >= 6.0.3 has a depth cap of its own
            raise error(f"nested deeper than the limit max_nesting={lim.max_nesting} "
                        f"(raise it with --limit max_nesting=N)", where) from None
        raise error(f"not valid YAML ({_yaml_problem(exc)})", where) from None


def _yaml_problem(exc: yaml.YAMLError) -> str:
    mark = getattr(exc, "problem_mark", None)
    at = f"line {mark.line + 1}: " if mark is not None else ""
    return f"{at}{getattr(exc, 'problem', None) or type(exc).__name__}"


def _check_finite(doc: Any, where: str, error: type[Feat2MapError]) -> None:
    """No NaN or infinite float anywhere in a parsed document (iterative; shared nodes once)."""
    seen: set[int] = set()
    stack: list[tuple[Any, str]] = [(doc, "")]
    while stack:
        value, path = stack.pop()
        if isinstance(value, float):
            if not math.isfinite(value):
                raise error(f"{value} is not a finite number", f"{where}: {path}" if path else where)
        elif isinstance(value, (dict, list)):
            if id(value) in seen:
                continue
            seen.add(id(value))
            items = value.items() if isinstance(value, dict) else enumerate(value)
            for k, v in items:
                if isinstance(v, (float, dict, list)):
                    stack.append((v, f"{path}[{k}]" if isinstance(k, int) else (f"{path}.{k}" if path else str(k))))


# ------------------------------------------------------------------------------ JSON schema

def element_path(items: Sequence[Any]) -> str:
    """`junctions[0].sockets[2]` from ["junctions", 0, "sockets", 2]."""
    out = ""
    for p in items:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def element_where(where: str, items: Sequence[Any]) -> str:
    """`file: junctions[0].cell`: `where` (a file, or a file and element) and an element path."""
    if not items:
        return where
    path = element_path(items)
    if ": " not in where:
        return f"{where}: {path}"
    return where + (path if path.startswith("[") else "." + path)


_TYPE_NAMES = {"object": "an object (mapping)", "array": "a list", "number": "a number", "integer": "an integer",
               "string": "a string", "boolean": "true or false", "null": "null"}


def _schema_message(err: Any) -> tuple[list[Any], str]:
    """A short message for one jsonschema error (the offending value quoted as a short
    snippet only), and the element path it is about."""
    path = list(err.absolute_path)
    v, val, inst = err.validator, err.validator_value, err.instance
    got = f"got {snippet(inst)}"
    if v in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        op = {"minimum": ">=", "maximum": "<=", "exclusiveMinimum": ">", "exclusiveMaximum": "<"}[v]
        return path, f"must be {op} {val}, {got}"
    if v == "type":
        want = [val] if isinstance(val, str) else list(val)
        return path, f"must be {' or '.join(_TYPE_NAMES.get(t, t) for t in want)}, {got}"
    if v == "enum":
        return path, f"must be one of {', '.join(map(str, val))}, {got}"
    if v == "const":
        return path, f"must be {val!r}, {got}"
    if v == "required":
        missing = [k for k in val if k not in inst]
        return path, f"missing required field {missing[0]!r}"
    if v in ("additionalProperties", "unevaluatedProperties"):
        known = set(err.schema.get("properties", {}))
        extra = sorted(str(k) for k in inst if k not in known)
        expected = f" (expected one of {', '.join(sorted(known))})" if known else ""
        return path + extra[:1], f"unknown field{expected}"
    if v == "minItems":
        return path, f"needs at least {val} entries, got {len(inst)}"
    if v == "maxItems":
        return path, f"takes at most {val} entries, got {len(inst)}"
    if v == "minLength":
        return path, f"must have at least {val} characters, {got}"
    return path, f"does not match the schema ({v})"


def check_schema(doc: Any, schema: Mapping[str, Any], where: str, error: type[Feat2MapError]) -> None:
    """Validate `doc` against a JSON schema; the first error (in document order) is raised as
    `error`, naming the file and element."""
    from jsonschema import Draft202012Validator

    errors = list(Draft202012Validator(schema).iter_errors(doc))
    if not errors:
        return

    def key(e: Any) -> tuple:
        return tuple((0, p, "") if isinstance(p, int) else (1, 0, str(p)) for p in e.absolute_path)

    path, message = _schema_message(min(errors, key=key))
    raise error(message, element_where(where, path))
