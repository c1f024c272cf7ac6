"""The junction feature model of the paper (Sec. III-B/C): values, validation, normalization.

A junction is `[road count n, rotation, control, crosswalk]`; the rotation is the list of
road-socket angles (degrees, counter-clockwise from East) in the normalized frame: sockets
start right after the largest gap between neighbouring sockets, and the whole junction is
rotated by the angle that best aligns its sockets with East/North/West/South (eqs. 3-8).
Angles are unwrapped: alpha_1 in [-45, 45), strictly increasing, alpha_n < alpha_1 + 360.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from .angles import positive_degrees, turn_name
from .config import (MAX_LEGS, MAX_MOTORWAY_LANES, MIN_LEG_SEPARATION_DEG, RAMP_LANE_M, RAMP_MAIN_BEND_DEG,
                     RAMP_MAX_ANGLE_DEG, RAMP_MIN_ANGLE_DEG)
from .errors import FeatureError, snippet

CONTROLS: tuple[str, ...] = ("bare", "signal", "stop")
# mid-block crosswalk values of a map feature: "none" (roads between junctions without one), a bare
# crossing, or one with a signal per direction
MIDBLOCK: tuple[str, ...] = ("none", "bare", "signal")
# filter lane (slip lane) values of a socket: "none", or a lane that leaves the approach before the
# junction, turns right round its core into the next socket counter-clockwise and gives way at a
# yield sign ("yield") or a light of its own ("signal")
FILTERS: tuple[str, ...] = ("none", "yield", "signal")
# motorway ramp values of a socket: "none" (a main leg, or a junction without ramps), an on-ramp ("on": one-way
# in, joining its main leg's carriageway, the previous socket counter-clockwise, on its right) or an off-ramp
# ("off": one-way out, leaving the carriageway that exits at the next socket counter-clockwise, on its right)
RAMPS: tuple[str, ...] = ("none", "on", "off")
# the map feature's ramp values: ramp junctions with an on-ramp, an off-ramp or one of each, and
# motorway-to-motorway junctions whose ramps are motorway links (`Socket.link`): "link-" and the same
RAMP_VALUES: tuple[str, ...] = ("none", "on", "off", "both", "link-on", "link-off", "link-both")
LINK_PREFIX = "link-"
ROAD_TYPES: tuple[str, ...] = ("in-out", "in", "out")
QUARTER = 90.0
# Float noise of rotated, re-measured angles (~1e-7 deg) must not decide ties of symmetric junctions
# (equal gaps, equally good alignments): gaps this close are equal, costs equal to this many digits.
ANGLE_NOISE_DEG = 1e-4
COST_DIGITS = 3


@dataclass(frozen=True)
class Socket:
    """One road socket: its angle and the lanes that enter (`lanes_in`) and leave (`lanes_out`);
    `filter`: a filter lane from this approach into the next socket counter-clockwise (the right
    turn), "none" (default), "yield" or "signal"; `island`: a traffic island (kerbs) separates
    it from the junction's core (default), else painted lines do; `ramp`: "none" (default), or
    an on-ramp ("on") or off-ramp ("off") beside a main leg (`ramp_main`); `link`: the ramp is a
    motorway link (a motorway-to-motorway junction): its carriageway gains the link's lanes (on)
    or drops them into it (off), lane for lane, instead of a merge into (diverge from) its
    rightmost lane."""

    angle: float
    lanes_in: int = 1
    lanes_out: int = 1
    filter: str = "none"
    island: bool = True
    ramp: str = "none"
    link: bool = False

    @property
    def road_type(self) -> str:
        if self.lanes_in and self.lanes_out:
            return "in-out"
        return "in" if self.lanes_in else "out"


def socket_lanes(road_type: str, lanes: int = 1) -> tuple[int, int]:
    """(lanes_in, lanes_out) for a road type and a lane count per direction."""
    if road_type not in ROAD_TYPES:
        raise FeatureError(f"unknown road type {road_type!r}, expected one of {ROAD_TYPES}")
    return (lanes if road_type != "out" else 0, lanes if road_type != "in" else 0)


def filter_exit(feature: "JunctionFeature", i: int) -> int | None:
    """The socket a filter lane from socket `i` leads into: the next one counter-clockwise, when
    driving into it from socket `i` is a right turn (`angles.turn_name`); None otherwise."""
    n = feature.n_roads
    c = (i + 1) % n
    gap = (feature.sockets[c].angle - feature.sockets[i].angle) % 360.0
    return c if turn_name(gap - 180.0) == "right" else None


def with_filter(feature: "JunctionFeature", control: str, island: bool = True) -> "JunctionFeature":
    """`feature` with a filter lane (`control` "yield" or "signal") on the approach whose right
    turn into the next socket is closest to a quarter turn (the first such socket on ties); the
    feature as it is for "none". A FeatureError when no approach has such a right turn."""
    if control == "none":
        return feature
    n = feature.n_roads
    legs = [i for i in range(n) if feature.sockets[i].lanes_in and feature.sockets[(i + 1) % n].lanes_out
            and filter_exit(feature, i) is not None
            and any(o.lanes_out for k, o in enumerate(feature.sockets) if k not in (i, (i + 1) % n))]
    if not legs:
        raise FeatureError(f"no approach of the junction at {list(feature.rotation)} turns right into the next "
                           "socket: it has no place for a filter lane")
    gap = [abs((feature.sockets[(i + 1) % n].angle - feature.sockets[i].angle) % 360.0 - QUARTER) for i in legs]
    leg = legs[gap.index(min(gap))]
    sockets = tuple(replace(s, filter=control, island=island) if i == leg else s
                    for i, s in enumerate(feature.sockets))
    return replace(feature, sockets=sockets)


def ramp_main(feature: "JunctionFeature", i: int) -> int:
    """The main leg of ramp socket `i`: the previous socket counter-clockwise for an on-ramp
    (right-hand traffic from that leg has the ramp on its right), the next one for an off-ramp."""
    n = feature.n_roads
    return (i - 1) % n if feature.sockets[i].ramp == "on" else (i + 1) % n


def ramp_angle(feature: "JunctionFeature", i: int) -> float:
    """The merge (on-ramp) or diverge (off-ramp) angle of ramp socket `i` from its main leg, degrees."""
    m = feature.sockets[ramp_main(feature, i)].angle
    a = feature.sockets[i].angle
    return (a - m) % 360.0 if feature.sockets[i].ramp == "on" else (m - a) % 360.0


def ramp_carriageway(feature: "JunctionFeature", i: int) -> tuple[int, int]:
    """(upstream, downstream) main legs of the carriageway that ramp socket `i` joins or leaves."""
    m = ramp_main(feature, i)
    a, b = ramp_mains(feature)
    other = b if m == a else a
    return (m, other) if feature.sockets[i].ramp == "on" else (other, m)


def ramp_mains(feature: "JunctionFeature") -> tuple[int, int]:
    """The two main legs (the sockets without a ramp) of a ramp junction."""
    a, b = (i for i, s in enumerate(feature.sockets) if s.ramp == "none")
    return a, b


def ramp_junction(kind: str, angle_deg: float, main_lanes: int = 1, ramp_lanes: int = 1,
                  length: float = RAMP_LANE_M) -> "JunctionFeature":
    """A ramp junction on a straight two-way main road with `main_lanes` per direction: an on-ramp
    ("on"), an off-ramp ("off") or one of each ("both"), `angle_deg` from the main road,
    `ramp_lanes` each, acceleration/deceleration lanes `length` long. A "link-" kind makes the
    ramps motorway links (`Socket.link`) beside the western main leg (socket 180), which keeps
    `main_lanes`: the on-link joins the eastbound carriageway, the off-link leaves the westbound
    one, and the eastern leg has their lanes added."""
    if kind not in RAMP_VALUES[1:]:
        raise FeatureError(f"unknown ramp {kind!r}, expected one of {RAMP_VALUES[1:]}")
    link = kind.startswith(LINK_PREFIX)
    kind = kind.removeprefix(LINK_PREFIX)
    on, off = kind in ("on", "both"), kind in ("off", "both")
    east = (main_lanes + ramp_lanes * (link and off), main_lanes + ramp_lanes * (link and on))
    sockets = [Socket(0.0, *east), Socket(180.0, main_lanes, main_lanes)]
    if off:  # a ramp leaves the eastbound carriageway, a link the westbound one
        off_ramp = Socket(180.0 - float(angle_deg) if link else -float(angle_deg), 0, ramp_lanes, ramp="off", link=link)
        sockets.insert(1 if link else 0, off_ramp)
    if on:
        sockets.append(Socket(180.0 + float(angle_deg), ramp_lanes, 0, ramp="on", link=link))
    return JunctionFeature(tuple(sockets), ramp_length=float(length))


@dataclass(frozen=True)
class JunctionFeature:
    """A junction feature F_J = [n, rotation, control, crosswalk] plus per-socket lanes; a ramp
    junction (a socket with `ramp`) also has `ramp_length`, its acceleration/deceleration lanes'
    length (the distance between its main legs' sockets; ignored without ramps)."""

    sockets: tuple[Socket, ...]
    control: str = "bare"
    crosswalk: bool = False
    min_separation_deg: float = field(default=MIN_LEG_SEPARATION_DEG, compare=False, repr=False)
    ramp_length: float = RAMP_LANE_M

    def __post_init__(self) -> None:
        object.__setattr__(self, "sockets", tuple(self.sockets))
        n = len(self.sockets)
        if not 3 <= n <= MAX_LEGS:
            raise FeatureError(f"a junction needs at least 3 roads and at most {MAX_LEGS}, got {n}")
        if self.control not in CONTROLS:
            raise FeatureError(f"unknown control {self.control!r}, expected one of {CONTROLS}")
        if not isinstance(self.crosswalk, bool):
            raise FeatureError(f"crosswalk must be true or false, got {self.crosswalk!r}")
        angles = self.rotation
        if any(isinstance(a, bool) or not isinstance(a, (int, float)) or not math.isfinite(a) for a in angles):
            raise FeatureError(f"socket angles must be finite, got {list(angles)}")
        for i in range(n - 1):
            if angles[i + 1] <= angles[i]:
                raise FeatureError(f"socket angles must be strictly increasing (counter-clockwise), got {list(angles)}")
        if angles[-1] - angles[0] >= 360.0:
            raise FeatureError(f"socket angles must span less than 360 degrees, got {list(angles)}")
        for i, s in enumerate(self.sockets):
            if s.ramp not in RAMPS:
                raise FeatureError(f"socket {i}: unknown ramp {s.ramp!r}, expected one of {RAMPS}")
            if not isinstance(s.link, bool) or (s.link and s.ramp == "none"):
                raise FeatureError(f"socket {i}: link must be true or false, and true only on a ramp, got "
                                   f"{snippet(s.link)}")
        ramps = self.has_ramp
        # a ramp and its main leg keep the ramp angles (RAMP_MIN_ANGLE_DEG..RAMP_MAX_ANGLE_DEG) instead
        gaps = [angles[i + 1] - angles[i] for i in range(n - 1)] + [angles[0] + 360.0 - angles[-1]]
        gaps = [g for i, g in enumerate(gaps) if not ramps or (self.sockets[(i + 1) % n].ramp != "on"
                                                                and self.sockets[i].ramp != "off")] or [360.0]
        if min(gaps) < self.min_separation_deg - 1e-9:
            raise FeatureError(
                f"sockets {min(gaps):.2f} degrees apart, closer than the minimum separation "
                f"{self.min_separation_deg} degrees: {list(angles)}"
            )
        for i, s in enumerate(self.sockets):
            if not all(isinstance(x, int) and not isinstance(x, bool) for x in (s.lanes_in, s.lanes_out)):
                raise FeatureError(f"socket {i} lane counts must be integers, got in={s.lanes_in!r} out={s.lanes_out!r}")
            if s.lanes_in < 0 or s.lanes_out < 0 or s.lanes_in + s.lanes_out == 0:
                raise FeatureError(f"socket {i} must have at least one lane, got in={s.lanes_in} out={s.lanes_out}")
        if not any(s.lanes_in for s in self.sockets) or not any(s.lanes_out for s in self.sockets):
            raise FeatureError("a junction needs at least one incoming and one outgoing road")
        for i, s in enumerate(self.sockets):
            if s.filter not in FILTERS:
                raise FeatureError(f"socket {i}: unknown filter lane {s.filter!r}, expected one of {FILTERS}")
            if not isinstance(s.island, bool):
                raise FeatureError(f"socket {i}: island must be true or false, got {s.island!r}")
            if s.filter != "none" and (not s.lanes_in or not self.sockets[(i + 1) % n].lanes_out
                                       or filter_exit(self, i) is None
                                       or not any(o.lanes_out for k, o in enumerate(self.sockets)
                                                  if k not in (i, (i + 1) % n))):
                raise FeatureError(f"socket {i}: a filter lane needs incoming lanes there, a right turn into "
                                   "the next socket counter-clockwise with outgoing lanes, and another exit for "
                                   "the approach's lanes through the core")
        if ramps:
            self._check_ramps()
        for i, s in enumerate(self.sockets):  # every approach has a way through (a U-turn is not one)
            others = [o for k, o in enumerate(self.sockets) if k != i]
            if s.lanes_in and not any(o.lanes_out for o in others):
                raise FeatureError(f"socket {i} has incoming lanes but no other socket has outgoing ones: "
                                   "they would be dead ends")
            if s.lanes_out and not any(o.lanes_in for o in others):
                raise FeatureError(f"socket {i} has outgoing lanes but no other socket has incoming ones: "
                                   "nothing could drive into them")

    def _check_ramps(self) -> None:
        """A ramp junction: two main legs near straight on, bare, without crosswalks or filter
        lanes; each ramp one-way, on the right of its main leg's carriageway, at a ramp angle."""
        mains = [i for i, s in enumerate(self.sockets) if s.ramp == "none"]
        if len(mains) != 2:
            raise FeatureError(f"a ramp junction has two main legs (sockets without a ramp), got {len(mains)}")
        a, b = mains
        bend = abs((self.sockets[b].angle - self.sockets[a].angle) % 360.0 - 180.0)
        if bend > RAMP_MAIN_BEND_DEG + 1e-9:
            raise FeatureError(f"a ramp junction's main legs lie {bend:.2f} degrees off straight on, more than "
                               f"{RAMP_MAIN_BEND_DEG:g}")
        if self.control != "bare" or self.crosswalk or self.has_filter:
            raise FeatureError("a ramp junction is bare, without crosswalks or filter lanes")
        if isinstance(self.ramp_length, bool) or not isinstance(self.ramp_length, (int, float)) \
                or not math.isfinite(self.ramp_length) or self.ramp_length <= 0:
            raise FeatureError(f"ramp_length must be a positive number of metres, got {snippet(self.ramp_length)}")
        for i, s in enumerate(self.sockets):
            if s.ramp == "none":
                continue
            m = ramp_main(self, i)
            if self.sockets[m].ramp != "none":
                raise FeatureError(f"socket {i}: an {s.ramp}-ramp lies next to its main leg (the "
                                   f"{'previous' if s.ramp == 'on' else 'next'} socket counter-clockwise)")
            other = b if m == a else a
            theta = ramp_angle(self, i)
            if not RAMP_MIN_ANGLE_DEG - 1e-9 <= theta <= RAMP_MAX_ANGLE_DEG + 1e-9:
                raise FeatureError(f"socket {i}: the ramp lies {theta:.2f} degrees from its main leg, outside "
                                   f"{RAMP_MIN_ANGLE_DEG:g} to {RAMP_MAX_ANGLE_DEG:g}")
            if s.ramp == "on" and (s.lanes_out or not self.sockets[other].lanes_out):
                raise FeatureError(f"socket {i}: an on-ramp is one-way in and joins a carriageway leaving at the "
                                   "other main leg")
            if s.ramp == "off" and (s.lanes_in or not self.sockets[other].lanes_in):
                raise FeatureError(f"socket {i}: an off-ramp is one-way out and leaves a carriageway entering at "
                                   "the other main leg")
        self._check_links()

    def _check_links(self) -> None:
        """Motorway links (`Socket.link`): a junction's ramps are all links or none; a link's
        carriageway has no other ramp, and its lanes add up: downstream = upstream + the link's."""
        linked = [s.link for s in self.sockets if s.ramp != "none"]
        if any(linked) and not all(linked):
            raise FeatureError("a junction's ramps are all motorway links (link: true) or none are")
        for i, s in enumerate(self.sockets):
            if not s.link:
                continue
            up, down = ramp_carriageway(self, i)
            if any(k != i and t.ramp != "none" and ramp_carriageway(self, k) == (up, down)
                   for k, t in enumerate(self.sockets)):
                raise FeatureError(f"socket {i}: a motorway link's carriageway has no other ramp")
            u, d = self.sockets[up].lanes_in, self.sockets[down].lanes_out
            if s.ramp == "on" and d != u + s.lanes_in:
                raise FeatureError(f"socket {i}: the lanes of a motorway link (on-ramp) do not add up: the carriageway "
                                   f"leaves at socket {down} with {d} lane(s), not the {u} entering at socket {up} "
                                   f"plus the link's {s.lanes_in}")
            if s.ramp == "off" and u != d + s.lanes_out:
                raise FeatureError(f"socket {i}: the lanes of a motorway link (off-ramp) do not add up: the carriageway "
                                   f"enters at socket {up} with {u} lane(s), not the {d} leaving at socket {down} "
                                   f"plus the link's {s.lanes_out}")

    @classmethod
    def make(
        cls,
        angles: Sequence[float],
        control: str = "bare",
        crosswalk: bool = False,
        road_types: Sequence[str] | None = None,
        lanes: Sequence[int] | int = 1,
        min_separation_deg: float = MIN_LEG_SEPARATION_DEG,
    ) -> "JunctionFeature":
        """Build a feature from plain angles, road types and lanes per direction."""
        n = len(angles)
        types = list(road_types) if road_types is not None else ["in-out"] * n
        counts = [lanes] * n if isinstance(lanes, int) else list(lanes)
        if len(types) != n or len(counts) != n:
            raise FeatureError(f"{n} angles but {len(types)} road types and {len(counts)} lane counts")
        sockets = tuple(Socket(float(a), *socket_lanes(t, int(c))) for a, t, c in zip(angles, types, counts))
        return cls(sockets, control, bool(crosswalk), min_separation_deg)

    @property
    def n_roads(self) -> int:
        return len(self.sockets)

    @property
    def rotation(self) -> tuple[float, ...]:
        return tuple(s.angle for s in self.sockets)

    @property
    def road_types(self) -> tuple[str, ...]:
        return tuple(s.road_type for s in self.sockets)

    @property
    def filters(self) -> tuple[str, ...]:
        """The filter lane value of every socket ("none" where it has none)."""
        return tuple(s.filter for s in self.sockets)

    @property
    def has_filter(self) -> bool:
        return any(s.filter != "none" for s in self.sockets)

    @property
    def ramps(self) -> tuple[str, ...]:
        """The ramp value of every socket ("none" for main legs and junctions without ramps)."""
        return tuple(s.ramp for s in self.sockets)

    @property
    def has_ramp(self) -> bool:
        return any(s.ramp != "none" for s in self.sockets)

    @property
    def has_link(self) -> bool:
        return any(s.link for s in self.sockets)

    @property
    def ramp_value(self) -> str:
        """The map feature's ramp value of this junction: "none", "on", "off" or "both", with
        LINK_PREFIX when its ramps are motorway links."""
        kinds = set(self.ramps) - {"none"}
        value = "both" if len(kinds) == 2 else kinds.pop() if kinds else "none"
        return LINK_PREFIX + value if self.has_link else value

    def normalization(self) -> "Normalization":
        """How `normalized` turns and re-orders the sockets: the paper's rotation normalization,
        or a ramp junction's (`ramp_normalization`)."""
        return ramp_normalization(self) if self.has_ramp else normalize_rotation(self.rotation)

    def normalized(self) -> "JunctionFeature":
        """The same junction in the normalized frame (sockets re-ordered and rotated)."""
        norm = self.normalization()
        sockets = tuple(replace(self.sockets[i], angle=a) for a, i in zip(norm.angles, norm.order))
        return replace(self, sockets=sockets)

    def to_dict(self) -> dict[str, Any]:
        """The JSON form; `filter` and `island` (per socket) only when a socket has a filter lane,
        so that a feature without one writes exactly what it always did."""
        out: dict[str, Any] = {
            "n_roads": self.n_roads,
            "rotation": list(self.rotation),
            "control": self.control,
            "crosswalk": self.crosswalk,
            "lanes_in": [s.lanes_in for s in self.sockets],
            "lanes_out": [s.lanes_out for s in self.sockets],
        }
        if self.has_filter:
            out["filter"] = list(self.filters)
            out["island"] = [s.island for s in self.sockets]
        if self.has_ramp:
            out["ramp"] = list(self.ramps)
            out["ramp_length"] = self.ramp_length
        if self.has_link:
            out["link"] = [s.link for s in self.sockets]
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "junction feature") -> "JunctionFeature":
        try:
            angles = [float(a) for a in data["rotation"]]
            n = len(angles)
            if "n_roads" in data and int(data["n_roads"]) != n:
                raise FeatureError(f"n_roads is {data['n_roads']} but rotation has {n} angles")
            lanes_in = list(data.get("lanes_in", [1] * n))
            lanes_out = list(data.get("lanes_out", [1] * n))
            if len(lanes_in) != n or len(lanes_out) != n:
                raise FeatureError("lanes_in and lanes_out need one entry per socket")
            filters = list(data.get("filter", ["none"] * n))
            islands = list(data.get("island", [True] * n))
            if len(filters) != n or len(islands) != n:
                raise FeatureError("filter and island need one entry per socket")
            ramps = list(data.get("ramp", ["none"] * n))
            links = list(data.get("link", [False] * n))
            if len(ramps) != n or len(links) != n:
                raise FeatureError("ramp and link need one entry per socket")
            sockets = tuple(Socket(a, int(i), int(o), str(f), isl, str(r), lk) for a, i, o, f, isl, r, lk
                            in zip(angles, lanes_in, lanes_out, filters, islands, ramps, links))
            return cls(sockets, str(data.get("control", "bare")), bool(data.get("crosswalk", False)),
                       ramp_length=float(data.get("ramp_length", RAMP_LANE_M)))
        except FeatureError as exc:
            raise FeatureError(exc.message, where) from None
        except (KeyError, TypeError, ValueError) as exc:
            raise FeatureError(f"malformed feature ({exc!r})", where) from None


@dataclass(frozen=True)
class Normalization:
    """Result of rotation normalization: angles in the normalized frame, socket order, rotation."""

    angles: tuple[float, ...]
    order: tuple[int, ...]  # order[i] = index of the input socket that became socket i
    rotation_deg: float  # added to input angles (mod 360) to get `angles`


def _wrap_quarter(x: float) -> float:
    """Signed distance of an angle to its nearest cardinal direction, in [-45, 45)."""
    return (x + 45.0) % QUARTER - 45.0


def alignment_cost(alpha: float, offsets: Sequence[float]) -> float:
    """The paper's objective: sum of squared deviations of each socket from its nearest cardinal."""
    return sum(_wrap_quarter(alpha + c) ** 2 for c in offsets)


def best_alignment(offsets: Sequence[float]) -> float:
    """Exact minimiser in [-45, 45) of `alignment_cost` (a periodic piecewise quadratic).

    Between consecutive breakpoints (where a socket switches nearest cardinal) the cost is
    one quadratic whose minimum is the mean of the per-socket targets; the global minimum is
    the best clamped piece minimum. Ties go to the smallest |alpha|.
    """
    breaks = sorted({_wrap_quarter(45.0 - c) for c in offsets} | {-45.0, 45.0})
    best: tuple[float, float, float] | None = None
    for lo, hi in zip(breaks[:-1], breaks[1:]):
        if hi - lo <= 0:
            continue
        mid = 0.5 * (lo + hi)
        targets = [QUARTER * round((mid + c) / QUARTER) - c for c in offsets]
        alpha = min(max(sum(targets) / len(targets), lo), hi)
        if alpha >= 45.0:
            alpha -= QUARTER
        cost = alignment_cost(alpha, offsets)
        key = (round(cost, COST_DIGITS), round(abs(alpha), 6), round(alpha, 6))
        if best is None or key < best:
            best = key
    assert best is not None
    return best[2]


def normalize_rotation(angles: Sequence[float], tie_tol_deg: float = 0.0) -> Normalization:
    """Rotation normalization (paper eqs. 3-8) of absolute socket angles in degrees.

    Sockets are ordered counter-clockwise starting right after the largest gap (so the
    largest gap closes the cycle, as in the paper's Table II), then rotated by the exact
    optimal alpha. Among equally large gaps the start with the lowest cost wins, then the
    smallest |alpha|, then the smallest angle list, so every orientation of one shape gives the
    same feature; gaps within `tie_tol_deg` of the largest count as equal (measured maps: a
    4-way junction's gaps differ by noise, and the start should not flip with it).
    """
    n = len(angles)
    if n == 0:
        raise FeatureError("no sockets to normalize")
    order = sorted(range(n), key=lambda i: positive_degrees(angles[i]))
    sorted_angles = [positive_degrees(angles[i]) for i in order]
    gaps = [positive_degrees(sorted_angles[(i + 1) % n] - sorted_angles[i]) for i in range(n)]
    if n == 1:
        gaps = [360.0]
    largest = max(gaps)
    candidates = []
    for i, g in enumerate(gaps):
        if g < largest - max(tie_tol_deg, ANGLE_NOISE_DEG):
            continue
        start = (i + 1) % n
        offsets = [positive_degrees(sorted_angles[(start + k) % n] - sorted_angles[start]) for k in range(n)]
        alpha = best_alignment(offsets)
        shape = tuple(round(alpha + c, 4) for c in offsets)  # the same for every orientation of the junction
        candidates.append((round(alignment_cost(alpha, offsets), COST_DIGITS), round(abs(alpha), 6), shape, start,
                           alpha, offsets))
    *_, start, alpha, offsets = min(candidates, key=lambda c: c[:4])
    return Normalization(
        angles=tuple(alpha + c for c in offsets),
        order=tuple(order[(start + k) % n] for k in range(n)),
        rotation_deg=positive_degrees(alpha - sorted_angles[start]),
    )


def ramp_normalization(feature: JunctionFeature) -> Normalization:
    """A ramp junction's normalized frame: turned so that its main legs best align with the
    cardinal directions (the paper's objective over the main legs alone: the main road runs
    along a grid direction, or nearly, its ramps beside it), sockets listed counter-clockwise
    from the first one at or after -45 degrees. Of the four quarter turns that align them, the
    one listing the smallest angles wins (so every orientation of one shape gives one feature)."""
    a, b = ramp_mains(feature)
    base = feature.sockets[a].angle
    alpha = best_alignment([0.0, positive_degrees(feature.sockets[b].angle - base)])
    best: tuple[tuple[float, ...], float, list[float]] | None = None
    for k in range(4):
        rotation = positive_degrees(alpha - base + QUARTER * k)
        turned = [positive_degrees(s.angle + rotation + 45.0) - 45.0 for s in feature.sockets]
        key = tuple(sorted(round(t, 6) + 0.0 for t in turned))
        if best is None or key < best[0]:
            best = (key, rotation, turned)
    assert best is not None
    _, rotation, turned = best
    order = tuple(sorted(range(feature.n_roads), key=lambda i: turned[i]))
    return Normalization(tuple(turned[i] for i in order), order, rotation)


@dataclass(frozen=True)
class MidblockFeature:
    """A crosswalk on a road between two junctions: `control` "bare" or "signal" (a light per
    direction of travel), its centre `position` (0..1) of the road's length from the junction
    that asks for it (the upstream one, for sampled crossings: the road's start)."""

    control: str = "bare"
    position: float = 0.5

    def __post_init__(self) -> None:
        if self.control not in MIDBLOCK[1:]:
            raise FeatureError(f"unknown mid-block crosswalk control {self.control!r}, expected one of {MIDBLOCK[1:]}")
        if isinstance(self.position, bool) or not isinstance(self.position, (int, float)) \
                or not 0.0 < self.position < 1.0:
            raise FeatureError(f"a mid-block crosswalk's position is a fraction of its road, strictly between 0 "
                               f"and 1, got {snippet(self.position)}")


Range = tuple[float, float]


@dataclass(frozen=True)
class FeatureSpace:
    """The paper's map feature: discrete value sets and per-n socket angle ranges, plus the
    mid-block crosswalk values (`midblock`, a subset of MIDBLOCK) sampled on the roads between
    junctions and the filter lane values (`filter`, a subset of FILTERS) sampled per junction
    combination and the ramp values (`ramp`, a subset of RAMP_VALUES: ramp junctions sampled beside
    the junction combinations) with their main roads' lanes per direction (`motorway_lanes`, each
    value sampled with each ramp value); the defaults ("none",) and (1,) are the paper's map
    feature, with none and with one lane per direction as its junctions have."""

    road_counts: tuple[int, ...]
    controls: tuple[str, ...]
    crosswalks: tuple[bool, ...]
    rotation_ranges: Mapping[int, tuple[Range, ...]]
    midblock: tuple[str, ...] = ("none",)
    filter: tuple[str, ...] = ("none",)
    ramp: tuple[str, ...] = ("none",)
    motorway_lanes: tuple[int, ...] = (1,)

    def __post_init__(self) -> None:
        object.__setattr__(self, "road_counts", tuple(sorted(set(int(n) for n in self.road_counts))))
        object.__setattr__(self, "controls", tuple(c for c in CONTROLS if c in set(self.controls)))
        object.__setattr__(self, "crosswalks", tuple(sorted(set(bool(c) for c in self.crosswalks), reverse=True)))
        unknown = [v for v in self.midblock if v not in MIDBLOCK]
        if unknown:
            raise FeatureError(f"unknown mid-block crosswalk value(s) {snippet(unknown)}, expected {list(MIDBLOCK)}",
                               "midblock")
        object.__setattr__(self, "midblock", tuple(v for v in MIDBLOCK if v in set(self.midblock)))
        unknown = [v for v in self.filter if v not in FILTERS]
        if unknown:
            raise FeatureError(f"unknown filter lane value(s) {snippet(unknown)}, expected {list(FILTERS)}", "filter")
        object.__setattr__(self, "filter", tuple(v for v in FILTERS if v in set(self.filter)))
        unknown = [v for v in self.ramp if v not in RAMP_VALUES]
        if unknown:
            raise FeatureError(f"unknown ramp value(s) {snippet(unknown)}, expected {list(RAMP_VALUES)}", "ramp")
        object.__setattr__(self, "ramp", tuple(v for v in RAMP_VALUES if v in set(self.ramp)))
        bad = [v for v in self.motorway_lanes if isinstance(v, bool) or not isinstance(v, int)
               or not 1 <= v <= MAX_MOTORWAY_LANES]
        if bad or not self.motorway_lanes:
            raise FeatureError(f"must be lanes per direction, 1 to {MAX_MOTORWAY_LANES}, got "
                               f"{snippet(bad or list(self.motorway_lanes))}", "motorway_lanes")
        object.__setattr__(self, "motorway_lanes", tuple(sorted(set(self.motorway_lanes))))
        ranges = {int(n): tuple((float(lo), float(hi)) for lo, hi in r) for n, r in self.rotation_ranges.items()}
        object.__setattr__(self, "rotation_ranges", dict(sorted(ranges.items())))
        self.validate()

    def validate(self) -> None:
        if not self.midblock or not self.filter or not self.ramp:
            raise FeatureError("road_counts, controls, crosswalks, midblock, filter and ramp must each be non-empty")
        junctions = (bool(self.road_counts), bool(self.controls), bool(self.crosswalks))
        if not all(junctions) and (any(junctions) or not self.ramp_kinds):
            raise FeatureError("road_counts, controls and crosswalks must each be non-empty (all three empty: a map "
                               "feature of ramp junctions only, with ramp values other than none)")
        if self.road_counts and (min(self.road_counts) < 3 or max(self.road_counts) > MAX_LEGS):
            raise FeatureError(f"road counts must be 3 to {MAX_LEGS}, got {list(self.road_counts)}")
        for n in self.road_counts:
            ranges = self.rotation_ranges.get(n)
            if ranges is None:
                raise FeatureError(f"no rotation ranges for n={n}", "rotation_ranges")
            if len(ranges) != n:
                raise FeatureError(f"n={n} needs {n} angle ranges, got {len(ranges)}", f"rotation_ranges.{n}")
            for i, (lo, hi) in enumerate(ranges):
                if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
                    raise FeatureError(f"range [{lo}, {hi}] is empty or not finite", f"rotation_ranges.{n}[{i}]")
            for i in range(n - 1):
                if ranges[i + 1][1] <= ranges[i][0]:
                    raise FeatureError(
                        f"socket {i + 1} range lies entirely before socket {i}: angles must increase counter-clockwise",
                        f"rotation_ranges.{n}[{i + 1}]",
                    )
            if ranges[-1][0] - ranges[0][1] >= 360.0:
                raise FeatureError("socket ranges span 360 degrees or more", f"rotation_ranges.{n}")

    @property
    def filter_controls(self) -> tuple[str, ...]:
        """The filter lane controls sampled (the values other than "none")."""
        return tuple(v for v in self.filter if v != "none")

    @property
    def ramp_kinds(self) -> tuple[str, ...]:
        """The ramp junction values sampled (the values other than "none")."""
        return tuple(v for v in self.ramp if v != "none")

    @property
    def midblock_controls(self) -> tuple[str, ...]:
        """The mid-block crosswalk controls sampled (the values other than "none")."""
        return tuple(v for v in self.midblock if v != "none")

    @classmethod
    def from_features(cls, features: Iterable[JunctionFeature],
                      midblock: Iterable[MidblockFeature] = (), ramps: Iterable[str] = ()) -> "FeatureSpace":
        """Merge junction features into one map feature (union of values, per-n min/max angle);
        `midblock`: the mid-block crosswalks seen (their controls join "none", the roads without);
        ramp junctions give their ramp values and no road count or angle ranges; `ramps`: the kinds
        ("on", "off") of ramps found outside ramp junctions (`extract_ramps.extract_ramps`)."""
        every = list(features)
        feats = [f for f in every if not f.has_ramp]
        kinds = [*(f.ramp_value for f in every if f.has_ramp), *ramps]
        lanes = {n for f in every if f.has_ramp for i in ramp_mains(f)
                 for n in (f.sockets[i].lanes_in, f.sockets[i].lanes_out) if 0 < n <= MAX_MOTORWAY_LANES}
        if not every and not kinds:
            raise FeatureError("no junction features to merge")
        ranges: dict[int, list[list[float]]] = {}
        for f in feats:
            r = ranges.setdefault(f.n_roads, [[a, a] for a in f.rotation])
            for i, a in enumerate(f.rotation):
                r[i][0] = min(r[i][0], a)
                r[i][1] = max(r[i][1], a)
        return cls(
            road_counts=tuple(ranges),
            controls=tuple({f.control for f in feats}),
            crosswalks=tuple({f.crosswalk for f in feats}),
            rotation_ranges={n: tuple((lo, hi) for lo, hi in r) for n, r in ranges.items()},
            midblock=("none", *(c.control for c in midblock)),
            filter=tuple({v for f in feats for v in (set(f.filters) - {"none"} or {"none"})}) or ("none",),
            ramp=("none", *kinds),
            motorway_lanes=tuple(lanes) or (1,),
        )

    def merge(self, other: "FeatureSpace") -> "FeatureSpace":
        """Union of two map features (ranges widened per socket)."""
        ranges = dict(self.rotation_ranges)
        for n, r in other.rotation_ranges.items():
            mine = ranges.get(n)
            ranges[n] = r if mine is None else tuple((min(a[0], b[0]), max(a[1], b[1])) for a, b in zip(mine, r))
        return FeatureSpace(
            self.road_counts + other.road_counts,
            self.controls + other.controls,
            self.crosswalks + other.crosswalks,
            ranges,
            self.midblock + other.midblock,
            self.filter + other.filter,
            self.ramp + other.ramp,
            tuple(n for x in (self, other) if x.ramp_kinds for n in x.motorway_lanes) or (1,),
        )

    def to_dict(self) -> dict[str, Any]:
        """The JSON form; `midblock`, `filter`, `ramp` and `motorway_lanes` only off their defaults,
        so that a map feature without them writes (and its maps record) exactly what it always did."""
        out: dict[str, Any] = {
            "road_counts": list(self.road_counts),
            "controls": list(self.controls),
            "crosswalks": list(self.crosswalks),
            "rotation_ranges": {str(n): [list(r) for r in rs] for n, rs in self.rotation_ranges.items()},
        }
        if self.midblock != ("none",):
            out["midblock"] = list(self.midblock)
        if self.filter != ("none",):
            out["filter"] = list(self.filter)
        if self.ramp != ("none",):
            out["ramp"] = list(self.ramp)
        if self.motorway_lanes != (1,):
            out["motorway_lanes"] = list(self.motorway_lanes)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "feature space") -> "FeatureSpace":
        if not isinstance(data, Mapping):
            raise FeatureError(f"expected a JSON object, got a {type(data).__name__}", where)
        missing = {"road_counts", "controls", "crosswalks", "rotation_ranges"} - set(data)
        if missing:
            raise FeatureError(f"missing field(s): {', '.join(sorted(missing))}", where)
        for key, kind, name in (("road_counts", int, "integers"), ("controls", str, "strings"),
                                ("crosswalks", bool, "true/false"), ("midblock", str, "strings"),
                                ("filter", str, "strings"), ("ramp", str, "strings"),
                                ("motorway_lanes", int, "integers")):
            if key not in data:
                continue
            value = data[key]
            if not isinstance(value, list) or not all(isinstance(x, kind) and (kind is bool or not isinstance(
                    x, bool)) for x in value):
                raise FeatureError(f"must be a list of {name}, got {snippet(value)}", f"{where}: {key}")
        unknown = [c for c in data["controls"] if c not in CONTROLS]
        if unknown:
            raise FeatureError(f"unknown control(s) {snippet(unknown)}, expected {list(CONTROLS)}", f"{where}: controls")
        midblock = data.get("midblock", ["none"])
        unknown = [c for c in midblock if c not in MIDBLOCK]
        if unknown:
            raise FeatureError(f"unknown value(s) {snippet(unknown)}, expected {list(MIDBLOCK)}", f"{where}: midblock")
        filters = data.get("filter", ["none"])
        unknown = [c for c in filters if c not in FILTERS]
        if unknown:
            raise FeatureError(f"unknown value(s) {snippet(unknown)}, expected {list(FILTERS)}", f"{where}: filter")
        ramps = data.get("ramp", ["none"])
        unknown = [c for c in ramps if c not in RAMP_VALUES]
        if unknown:
            raise FeatureError(f"unknown value(s) {snippet(unknown)}, expected {list(RAMP_VALUES)}", f"{where}: ramp")
        rr = data["rotation_ranges"]
        if not isinstance(rr, Mapping):
            raise FeatureError(f"must be an object n -> ranges, got {snippet(rr)}", f"{where}: rotation_ranges")
        ranges = {}
        for n, rs in rr.items():
            at = f"{where}: rotation_ranges.{n}"
            if not (isinstance(n, str) and n.isdigit()) or not isinstance(rs, list) or not all(
                    isinstance(r, list) and len(r) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                                for x in r) for r in rs):
                raise FeatureError(f"must map a road count to a list of [low, high] angles, got {snippet(rs)}", at)
            ranges[int(n)] = tuple((float(r[0]), float(r[1])) for r in rs)
        try:
            return cls(tuple(data["road_counts"]), tuple(data["controls"]), tuple(data["crosswalks"]), ranges,
                       tuple(midblock), tuple(filters), tuple(ramps), tuple(data.get("motorway_lanes", [1])))
        except FeatureError as exc:
            raise FeatureError(exc.message, f"{where}: {exc.where}" if exc.where else where) from None

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True) + "\n"

    @classmethod
    def from_json(cls, text: str, where: str = "feature space") -> "FeatureSpace":
        from .documents import parse_document

        return cls.from_dict(parse_document(text, where, "json", FeatureError), where)

    @classmethod
    def load(cls, path: str | Path) -> "FeatureSpace":
        """A feature-space JSON file (as `extract --out` writes it)."""
        from .documents import load_document

        return cls.from_dict(load_document(path, FeatureError, fmt="json"), str(path))


# The San Francisco feature space of the paper's Table I, in this module's convention.
# Table I prints some bounds wrapped into (-180, 180] and some not; each bound is put back
# on the counter-clockwise, unwrapped scale (alpha_1 in [-45, 45), increasing):
#   n=3 socket 3: "-143.45, 200.92" -> [143.45, 200.92] (a T-junction's third leg follows its second);
#   n=4 socket 2: "-75.63, 93.10"   -> [75.63, 93.10];  socket 3: "-176.85, 191.76" -> [176.85, 191.76];
#   n=4 socket 4: "-109.24, -87.91" -> [250.76, 272.09] (the same directions, +360).
PAPER_SF_FEATURE_SPACE = FeatureSpace(
    road_counts=(3, 4),
    controls=("signal", "stop"),
    crosswalks=(True, False),
    rotation_ranges={
        3: ((-22.62, 9.81), (61.40, 126.22), (143.45, 200.92)),
        4: ((-5.26, 13.61), (75.63, 93.10), (176.85, 191.76), (250.76, 272.09)),
    },
)

# The paper's San Francisco space with every value of the features its future work names (mid-block
# crosswalks, filter lanes, motorway ramps): a highway-and-city map feature (examples/experiments.py's
# RQ4, examples/planner_experiments.py's "hc")
HIGHWAY_CITY_FEATURE_SPACE = replace(PAPER_SF_FEATURE_SPACE, midblock=MIDBLOCK, filter=FILTERS, ramp=RAMP_VALUES)
