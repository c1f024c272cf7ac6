"""The native map file: versioned JSON that loads back to an equal `HDMap`."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from ... import atomic
from ...bezier import Bezier
from ...config import MAP_FORMAT_VERSION
from ...documents import load_document
from ...errors import FeatureError, MapFormatError, snippet
from ...features import JunctionFeature
from ...model import Crosswalk, HDMap, Junction, Lane, Road, Signal, StopSign, YieldSign
from ...validation import validate_model

FORMAT_NAME = "feat2map-map"
_KINDS: dict[str, type] = {
    "lanes": Lane, "roads": Road, "junctions": Junction,
    "signals": Signal, "stop_signs": StopSign, "crosswalks": Crosswalk, "yield_signs": YieldSign,
}
_OPTIONAL = frozenset({"yield_signs"})  # written only when the map has some


def _encode(value: Any) -> Any:
    if isinstance(value, Bezier):
        return [list(value.p0), list(value.p1), list(value.p2), list(value.p3)]
    if isinstance(value, JunctionFeature):
        return value.to_dict()
    if isinstance(value, tuple):
        return [_encode(v) for v in value]
    return value


def _element_dict(obj: Any) -> dict[str, Any]:
    return {f.name: _encode(getattr(obj, f.name)) for f in dataclasses.fields(obj)}


def to_dict(m: HDMap) -> dict[str, Any]:
    out: dict[str, Any] = {"format": FORMAT_NAME, "version": MAP_FORMAT_VERSION, "origin": list(m.origin),
                           "meta": dict(m.meta)}
    for kind in _KINDS:
        if kind in _OPTIONAL and not getattr(m, kind):
            continue  # files of maps without them stay as they were
        out[kind] = [_element_dict(e) for e in getattr(m, kind).values()]
    return out


def _tuples(value: Any) -> Any:
    """JSON lists as tuples (the model's sequences); nesting is bounded by the document loader."""
    if isinstance(value, list):
        return tuple(_tuples(v) for v in value)
    return value


def _bezier(value: Any, where: str, key: str) -> Bezier | None:
    if value is None:
        return None
    try:
        pts = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        pts = None
    if pts is None or pts.shape != (4, 2):
        raise MapFormatError(f"{key} must be 4 [x, y] control points, got {snippet(value)}", where)
    return Bezier(*((float(p[0]), float(p[1])) for p in pts))


def _decode(cls: type, data: dict[str, Any], where: str) -> Any:
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise MapFormatError(f"unknown field(s) {snippet(sorted(map(str, unknown)), 80)}", where)
    kw: dict[str, Any] = {}
    for key, value in data.items():
        if key in ("bezier", "reference"):
            kw[key] = _bezier(value, where, key)
        elif key == "feature":
            if value is not None and not isinstance(value, dict):
                raise MapFormatError(f"feature must be an object, got {snippet(value)}", where)
            try:
                kw[key] = None if value is None else JunctionFeature.from_dict(value, where)
            except FeatureError as exc:
                raise MapFormatError(f"feature: {exc.message}", where) from None
        else:
            kw[key] = _tuples(value)
    try:
        return cls(**kw)
    except TypeError:
        missing = sorted(names - set(data))
        raise MapFormatError(f"missing field(s) {snippet(missing, 80)}", where) from None


def from_dict(data: Any, where: str = "map") -> HDMap:
    """The map of a parsed map document, checked by `validate_model` (MapFormatError naming
    the file and element)."""
    if not isinstance(data, dict) or data.get("format") != FORMAT_NAME:
        raise MapFormatError(f"not a {FORMAT_NAME} document", where)
    if data.get("version") != MAP_FORMAT_VERSION:
        raise MapFormatError(f"unsupported version {snippet(data.get('version'))} (this is {MAP_FORMAT_VERSION})",
                             where)
    parts: dict[str, dict[str, Any]] = {}
    for kind, cls in _KINDS.items():
        items = data.get(kind, [])
        if not isinstance(items, list):
            raise MapFormatError(f"'{kind}' must be a list", where)
        parts[kind] = {}
        for i, item in enumerate(items):
            ident = item.get("id") if isinstance(item, dict) else None
            at = f"{where}: {kind}[{i}]" + (f" id={ident}" if isinstance(ident, str) else "")
            if not isinstance(item, dict) or not isinstance(ident, str) or not ident:
                raise MapFormatError("element without an id", at)
            if ident in parts[kind]:
                raise MapFormatError("duplicate id", at)
            parts[kind][ident] = _decode(cls, item, at)
    meta = data.get("meta", {})
    if not isinstance(meta, dict):
        raise MapFormatError(f"meta must be an object, got {snippet(meta)}", where)
    m = HDMap(**parts, origin=_tuples(data.get("origin", [0.0, 0.0])), meta=meta)
    from ...semantics import check_map

    return check_map(validate_model(m, where), where)


def dumps(m: HDMap) -> str:
    """The map file's text; a map holding NaN/inf is refused (JSON has no such numbers)."""
    try:
        return json.dumps(to_dict(m), separators=(",", ":"), sort_keys=False, allow_nan=False) + "\n"
    except ValueError:
        validate_model(m, "map to write")  # names the element
        raise MapFormatError("refusing to write a non-finite number (in the map's meta)", "map to write") from None


def save(m: HDMap, path: str | Path) -> None:
    atomic.write_text(path, dumps(m))


def load(path: str | Path) -> HDMap:
    return from_dict(load_document(path, MapFormatError, fmt="json", finite=False), str(path))
