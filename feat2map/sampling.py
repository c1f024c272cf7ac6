"""Combinatorial sampling of junction features (Algorithm 1, lines 1-11)."""
from __future__ import annotations

import itertools

import numpy as np

from .config import MAX_ORDER_RETRIES, MIDBLOCK_POSITION_RANGE, RAMP_ANGLE_RANGE_DEG, RAMP_LANE_M, GenerationConfig, limits
from .errors import FeatureError
from .features import FeatureSpace, JunctionFeature, MidblockFeature, normalize_rotation, ramp_junction, with_filter


def sample_rotation(ranges: tuple[tuple[float, float], ...], rng: np.random.Generator,
                    min_separation_deg: float) -> tuple[float, ...]:
    """Angles drawn uniformly and independently in their per-socket ranges.

    Counter-clockwise order and the minimum separation are kept by rejection: a draw whose
    angles are not increasing by at least `min_separation_deg` (cyclically) is drawn again,
    which leaves the accepted angles uniform on the feasible part of the box. The drawn set
    is then rotation-normalized, so the junction realizes exactly the feature it records. Ranges that
    never yield a feasible draw raise a FeatureError.
    """
    lo = np.array([r[0] for r in ranges])
    hi = np.array([r[1] for r in ranges])
    for _ in range(MAX_ORDER_RETRIES):
        a = rng.uniform(lo, hi)
        gaps = np.diff(np.append(a, a[0] + 360.0))
        if gaps.min() >= min_separation_deg:
            return tuple(float(x) for x in a)
    raise FeatureError(
        f"no ordered socket angles {min_separation_deg} degrees apart found in "
        f"{MAX_ORDER_RETRIES} draws from {[list(r) for r in ranges]}",
        f"rotation_ranges.{len(ranges)}",
    )


def sample_features(space: FeatureSpace, rng: np.random.Generator,
                    config: GenerationConfig = GenerationConfig()) -> list[JunctionFeature]:
    """One feature per (n, control, crosswalk, filter) combination, `samples_per_combination`
    times; a filter lane value other than "none" puts one filter lane with that control on the
    junction (`features.with_filter`: the approach whose right turn is nearest a quarter turn)."""
    combos = len(space.road_counts) * len(space.controls) * len(space.crosswalks) * len(space.filter)
    limits().check("max_junctions", combos * int(config.samples_per_combination),
                   f"the junction count ({combos} feature combinations x samples_per_combination)")
    out: list[JunctionFeature] = []
    for n, control, crosswalk, filt in itertools.product(space.road_counts, space.controls, space.crosswalks,
                                                         space.filter):
        for _ in range(int(config.samples_per_combination)):
            drawn = sample_rotation(space.rotation_ranges[n], rng, config.min_socket_separation_deg)
            # a drawn angle set is a junction shape; its feature is that shape normalized
            angles = normalize_rotation(drawn).angles
            out.append(with_filter(JunctionFeature.make(angles, control, crosswalk,
                                                        min_separation_deg=config.min_socket_separation_deg), filt))
    return out


def sample_midblock(space: FeatureSpace, rng: np.random.Generator,
                    config: GenerationConfig = GenerationConfig()) -> list[MidblockFeature]:
    """One mid-block crosswalk per control the map feature asks for ("bare", "signal"),
    `samples_per_combination` times, each at a position drawn uniformly in
    MIDBLOCK_POSITION_RANGE (its "none" value is every road left without one)."""
    out = []
    for control in space.midblock_controls:
        for _ in range(int(config.samples_per_combination)):
            out.append(MidblockFeature(control, round(float(rng.uniform(*MIDBLOCK_POSITION_RANGE)), 6)))
    return out


def ramp_angle_range(main_lanes: int, config: GenerationConfig) -> tuple[float, float]:
    """Where a sampled ramp's angle is drawn: RAMP_ANGLE_RANGE_DEG, less the angles too shallow for
    its ramp to clear a main road of `main_lanes` per direction within RAMP_LANE_M
    (`ramps.min_ramp_angle`; the range's own bounds as they are for one lane, the paper's junctions'),
    and that least angle alone when it lies beyond the range (a wide motorway)."""
    from .ramps import min_ramp_angle

    lo, hi = RAMP_ANGLE_RANGE_DEG
    least = min_ramp_angle(main_lanes, RAMP_LANE_M, config)
    return (lo, hi) if least <= lo else (least, max(least, hi))


def sample_ramps(space: FeatureSpace, rng: np.random.Generator,
                 config: GenerationConfig = GenerationConfig()) -> list[JunctionFeature]:
    """One ramp junction per ramp value the map feature asks for ("on", "off", "both", and the
    motorway-to-motorway "link-" values) and main road lanes per direction (`motorway_lanes`; one,
    the default, connects to the sampled junctions lane for lane; a link adds its lane to one main
    leg, `features.ramp_junction`), `samples_per_combination` times: a straight main road, ramps of
    one lane joining or leaving its rightmost lane at an angle drawn uniformly in
    `ramp_angle_range`, acceleration/deceleration lanes RAMP_LANE_M long (its "none" value is every
    junction without ramps)."""
    combos = len(space.ramp_kinds) * len(space.motorway_lanes)
    limits().check("max_junctions", combos * int(config.samples_per_combination),
                   f"the ramp junction count ({len(space.ramp_kinds)} ramp values x {len(space.motorway_lanes)} "
                   "motorway lanes x samples_per_combination)")
    out = []
    for kind, lanes in itertools.product(space.ramp_kinds, space.motorway_lanes):
        span = ramp_angle_range(lanes, config)
        for _ in range(int(config.samples_per_combination)):
            angle = round(float(rng.uniform(*span)), 6)
            out.append(ramp_junction(kind, angle, lanes, 1, RAMP_LANE_M).normalized())
    return out
