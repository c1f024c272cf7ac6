"""The native map file: versioned JSON that loads back to an equal `HDMap`."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from ... import atomic
from ...bezier import Bezier
from ...config import MAP_FORMAT_VERSION
from ...errors import MapFormatError
from ...features import JunctionFeature
from ...model import Crosswalk, HDMap, Junction, Lane, Road, Signal, StopSign, YieldSign

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
    if isinstance(value, list):
        return tuple(_tuples(v) for v in value)
    return value


def _decode(cls: type, data: dict[str, Any], where: str) -> Any:
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise MapFormatError(f"unknown field(s) {sorted(unknown)}", where)
    kw: dict[str, Any] = {}
    for key, value in data.items():
        if key == "bezier" or (key == "reference" and value is not None):
            kw[key] = None if value is None else Bezier(*(tuple(p) for p in value))
        elif key == "feature":
            kw[key] = None if value is None else JunctionFeature.from_dict(value, where)
        else:
            kw[key] = _tuples(value)
    try:
        return cls(**kw)
    except TypeError as exc:
        raise MapFormatError(f"missing or malformed fields ({exc})", where) from None


def from_dict(data: Any, where: str = "map") -> HDMap:
    if not isinstance(data, dict) or data.get("format") != FORMAT_NAME:
        raise MapFormatError(f"not a {FORMAT_NAME} document", where)
    if data.get("version") != MAP_FORMAT_VERSION:
        raise MapFormatError(f"unsupported version {data.get('version')!r} (this is {MAP_FORMAT_VERSION})", where)
    parts: dict[str, dict[str, Any]] = {}
    for kind, cls in _KINDS.items():
        items = data.get(kind, [])
        if not isinstance(items, list):
            raise MapFormatError(f"'{kind}' must be a list", where)
        parts[kind] = {}
        for i, item in enumerate(items):
            ident = item.get("id") if isinstance(item, dict) else None
            at = f"{where}: {kind}[{i}]" + (f" id={ident}" if ident else "")
            if not isinstance(item, dict) or not isinstance(ident, str):
                raise MapFormatError("element without an id", at)
            if ident in parts[kind]:
                raise MapFormatError("duplicate id", at)
            parts[kind][ident] = _decode(cls, item, at)
    m = HDMap(**parts, origin=tuple(data.get("origin", (0.0, 0.0))), meta=data.get("meta", {}))
    check_references(m, where)
    return m


def check_references(m: HDMap, where: str = "map") -> None:
    """Every id an element refers to exists; raises MapFormatError naming the element."""
    for ln in m.lanes.values():
        if ln.road_id not in m.roads:
            raise MapFormatError(f"unknown road id {ln.road_id!r}", f"{where}: lane {ln.id}")
        if ln.junction_id is not None and ln.junction_id not in m.junctions:
            raise MapFormatError(f"unknown junction id {ln.junction_id!r}", f"{where}: lane {ln.id}")
        for ref in ln.predecessors + ln.successors + ln.left_neighbors + ln.right_neighbors + ln.left_reverse_neighbors:
            if ref not in m.lanes:
                raise MapFormatError(f"unknown lane id {ref!r}", f"{where}: lane {ln.id}")
        if len(ln.centerline) < 2:
            raise MapFormatError("centerline has fewer than 2 points", f"{where}: lane {ln.id}")
    for r in m.roads.values():
        for ref in r.lane_ids:
            if ref not in m.lanes:
                raise MapFormatError(f"unknown lane id {ref!r}", f"{where}: road {r.id}")
    for kind in ("signals", "stop_signs", "yield_signs"):
        for s in getattr(m, kind).values():
            for ref in s.lane_ids:
                if ref not in m.lanes:
                    raise MapFormatError(f"unknown lane id {ref!r}", f"{where}: {kind[:-1]} {s.id}")
    for kind in ("signals", "stop_signs", "yield_signs", "crosswalks"):
        for s in getattr(m, kind).values():
            if s.junction_id is not None and s.junction_id not in m.junctions:
                raise MapFormatError(f"unknown junction id {s.junction_id!r}", f"{where}: {kind[:-1]} {s.id}")


def dumps(m: HDMap) -> str:
    return json.dumps(to_dict(m), separators=(",", ":"), sort_keys=False) + "\n"


def save(m: HDMap, path: str | Path) -> None:
    atomic.write_text(path, dumps(m))


def load(path: str | Path) -> HDMap:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise MapFormatError(f"cannot read ({exc})", str(path)) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MapFormatError(f"not valid JSON, truncated or corrupt ({exc})", str(path)) from None
    return from_dict(data, str(path))
