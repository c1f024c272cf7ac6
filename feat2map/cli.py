"""The `feat2map` command line: generate, extract, export."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

from tqdm import tqdm

from . import atomic
from .formats import FORMATS, detect, native, read_map, write_map
from .config import GenerationConfig
from .errors import Feat2MapError
from .features import PAPER_SF_FEATURE_SPACE, FeatureSpace


class _Parser(argparse.ArgumentParser):
    """argparse with exit code 2 and a one-line message on bad arguments."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _overrides(args: argparse.Namespace) -> dict:
    return {k: getattr(args, k) for k in ("grid_gap", "lane_width", "crosswalk_width",
                                          "samples_per_combination") if getattr(args, k) is not None}


def _config(args: argparse.Namespace) -> GenerationConfig:
    overrides = _overrides(args)
    try:
        return GenerationConfig.from_dict(overrides)
    except ValueError as exc:
        raise Feat2MapError(str(exc), "command line") from None


def _extract_maps(paths: Sequence[str], skipped: list | None = None):
    from .extract import extract_junctions

    import warnings

    junctions = []
    with warnings.catch_warnings(record=True) as caught:  # one line each, not Python's format
        warnings.simplefilter("always")
        for p in tqdm(paths, desc="reading maps", unit="map", disable=len(paths) < 2):
            junctions += extract_junctions(read_map(p), map_name=str(p), skipped=skipped)
    for w in caught:
        print(f"feat2map: warning: {w.message}", file=sys.stderr)
    if not junctions:
        raise Feat2MapError("no junctions with 3 or more arms found", ", ".join(paths))
    return junctions


def cmd_generate(args: argparse.Namespace) -> int:
    from .generate import generate
    from .render import render_junctions, render_map

    cfg = _config(args)
    stages = tqdm(total=4, desc="generate", unit="stage", disable=True if args.quiet else None)
    if args.features:
        path = Path(args.features)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise Feat2MapError(f"cannot read ({exc.strerror})", str(path)) from None
        space = FeatureSpace.from_json(text, str(path))
    elif args.from_maps:
        from .extract import map_feature

        space = map_feature(_extract_maps(args.from_maps))
    elif not args.spec:
        space = PAPER_SF_FEATURE_SPACE
    else:
        space = None
    stages.set_postfix_str("layout")
    if args.spec:  # hand-written junctions and chains, on top of `space` when one was given
        from .spec import build_spec, load_spec

        spec = load_spec(args.spec)
        m = build_spec(spec, seed=args.seed, config=spec.generation_config(_overrides(args)), space=space)
        feats = [j.feature for j in m.junctions.values() if j.feature is not None]
        space = FeatureSpace.from_features(feats) if feats else None
    else:
        m = generate(space, seed=args.seed, config=cfg)
    stages.update(2)
    with atomic.staged_dir(args.out) as tmp:
        native.save(m, tmp / "map.json")
        if space is not None:
            atomic.write_text(tmp / "features.json", space.to_json())
        stages.set_postfix_str("picture")
        if not args.no_picture:
            render_map(m, tmp / "map.png", title=f"feat2map seed {args.seed}: {len(m.junctions)} junctions")
            if 0 < len(m.junctions) <= 64:
                render_junctions(m, tmp / "junctions.png")
        stages.update(1)
        if args.opendrive:
            write_map(m, tmp / "map.xodr", "opendrive")
        if not args.no_apollo:  # OUT/apollo/ is what a user copies to Apollo's modules/map/data/<name>/
            write_map(m, tmp / "apollo", "apollo")
        stages.update(1)
    stages.close()
    print(f"wrote {args.out}: {len(m.junctions)} junctions, {len(m.roads)} roads, {len(m.lanes)} lanes, "
          f"{len(m.signals)} signals, {len(m.stop_signs)} stop signs, {len(m.crosswalks)} crosswalks")
    return 0


def cmd_extract(args: argparse.Namespace) -> int:
    from .extract import map_feature

    skipped: list = []
    junctions = _extract_maps(args.maps, skipped)
    space = map_feature(junctions)
    if args.out:
        atomic.write_text(args.out, space.to_json())
    if args.picture:
        from .render import render_map

        first = read_map(args.maps[0])
        ctrl = {j.id: j.feature.control for j in junctions if j.map_name == str(args.maps[0])}
        ctrl.update({s.id: s.control for s in skipped if s.map_name == str(args.maps[0])})
        render_map(first, args.picture, title=str(args.maps[0]), controls=ctrl)
    if args.json:
        doc = {"maps": [str(p) for p in args.maps], "junctions": [j.to_dict() for j in junctions],
               "feature_space": space.to_dict(), "skipped": [s.to_dict() for s in skipped]}
        print(json.dumps(doc, indent=2))
        return 0
    print(f"{'map':<40} {'junction':<14} {'n':>2} {'control':<7} {'xwalk':<5} rotation (deg)")
    for j in junctions:
        rot = ", ".join(f"{a:7.2f}" for a in j.feature.rotation)
        print(f"{j.map_name[-40:]:<40} {j.id[:14]:<14} {j.feature.n_roads:>2} {j.feature.control:<7} "
              f"{str(j.feature.crosswalk):<5} [{rot}]")
    for s in skipped:
        print(f"{s.map_name[-40:]:<40} {s.id[:14]:<14} {s.n_arms:>2} {s.control:<7} {str(s.crosswalk):<5} "
              f"skipped: {s.reason}")
    print(f"\n{len(junctions)} junctions ({len(skipped)} skipped); map feature:\n{space.to_json()}", end="")
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    fmt = FORMATS[args.format] if args.format else detect(args.path, "validate")
    if fmt.validate is None:
        raise Feat2MapError(f"format {fmt.name} has no validator", "--format")
    problems = fmt.face("validate")(args.path, progress=True)
    for p in problems:
        print(p)
    if args.picture:
        if fmt.picture is None:
            raise Feat2MapError(f"format {fmt.name} draws no problem picture", "--picture")
        fmt.face("picture")(args.path, args.picture, problems, title=f"{args.path}: {len(problems)} problems")
    print(f"{args.path}: {len(problems)} problem{'s' if len(problems) != 1 else ''}")
    return 1 if problems else 0


def cmd_export(args: argparse.Namespace) -> int:
    fmt = FORMATS[args.format]
    m = read_map(args.map)
    if not m.lanes:
        raise Feat2MapError("map has no lanes", str(args.map))
    options = {o.kwarg: getattr(args, o.kwarg) for o in fmt.options if getattr(args, o.kwarg) is not None}
    if "origin" in options:
        options["origin"] = tuple(options["origin"])
    try:
        write_map(m, args.out, fmt.name, **options)
    except OSError as exc:
        raise Feat2MapError(f"cannot write ({exc.strerror or exc})", str(args.out)) from None
    print(f"wrote {args.out} ({fmt.title}): {len(m.roads)} roads, {len(m.lanes)} lanes, {len(m.junctions)} junctions, "
          f"{len(m.signals)} signals, {len(m.stop_signs)} stop signs, {len(m.crosswalks)} crosswalks")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="feat2map", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    g = sub.add_parser("generate", help="generate a map from a feature space, input maps or a spec")
    src = g.add_mutually_exclusive_group()
    src.add_argument("--features", help="feature-space JSON (default: the paper's San Francisco Table I)")
    src.add_argument("--from-maps", nargs="+", metavar="MAP", help="extract the feature space from these maps")
    g.add_argument("--spec", metavar="FILE", help="hand-written junctions/road chains (YAML or JSON, see "
                   "docs/specs.md); with --features/--from-maps they are added to the sampled junctions")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--out", required=True, help="output directory")
    g.add_argument("--samples-per-combination", type=int)
    g.add_argument("--grid-gap", type=float)
    g.add_argument("--lane-width", type=float)
    g.add_argument("--crosswalk-width", type=float)
    g.add_argument("--opendrive", action="store_true", help="also export OUT/map.xodr")
    g.add_argument("--no-apollo", action="store_true", help="skip the Apollo export (OUT/apollo/)")
    g.add_argument("--no-picture", action="store_true")
    g.add_argument("--quiet", action="store_true")
    g.set_defaults(func=cmd_generate)

    e = sub.add_parser("extract", help="extract junction features and the map feature from maps")
    e.add_argument("maps", nargs="+", help="Apollo .bin/.txt, OpenDRIVE .xodr or feat2map .json maps")
    e.add_argument("--out", help="write the feature-space JSON here")
    e.add_argument("--json", action="store_true", help="print one JSON document")
    e.add_argument("--picture", help="bird's-eye PNG/SVG of the first map, junctions coloured by control")
    e.set_defaults(func=cmd_extract)

    ex = sub.add_parser("export", help="export a feat2map map to another format")
    exsub = ex.add_subparsers(dest="format", required=True, parser_class=_Parser)
    for fmt in FORMATS.values():
        if fmt.write is None:
            continue
        f = exsub.add_parser(fmt.name, help=f"export as {fmt.title}")
        f.add_argument("map", help="feat2map .json map (or any map feat2map reads)")
        f.add_argument("--out", required=True, help="output folder" if fmt.output == "dir"
                       else f"output file ({fmt.suffixes[0]})")
        for o in fmt.options:
            f.add_argument(o.flag, dest=o.kwarg, **o.argparse)
        f.set_defaults(func=cmd_export)

    v = sub.add_parser("validate", help="check a map with its format's rules (Apollo: what Apollo needs to load and route)")
    v.add_argument("path", help="an Apollo map folder (base_map, sim_map, routing_map as .bin/.txt) or one map file")
    v.add_argument("--format", choices=sorted(n for n, f in FORMATS.items() if f.validate),
                   help="the map's format (default: from the path)")
    v.add_argument("--picture", help="PNG/SVG of the map with the problems ringed in red")
    v.set_defaults(func=cmd_validate)

    from .cli_scenarios import add_scenario_commands

    add_scenario_commands(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except Feat2MapError as exc:
        print(f"feat2map: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
