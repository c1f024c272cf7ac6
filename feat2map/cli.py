"""feat2map: concise, junction-diverse HD maps for testing driving planners (the Feat2Map
paper). Generate maps from the paper's feature space, real maps or hand-written specs; extract
junction features from maps; export and validate maps; build route-coverage scenario suites,
drive them headless and compare their coverage."""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import difflib
import functools
import importlib.util
import json
import math
import re
import sys
import warnings
from typing import Sequence

from tqdm import tqdm

from . import __version__, atomic
from .config import (CROSSWALK_WIDTH_M, GRID_GAP_M, LANE_WIDTH_M, LIMIT_FLAG, OPENDRIVE_VERSIONS, GenerationConfig,
                     Limits, plain_number, raised_limits)
from .errors import WHERE_MAX_CHARS, ConfigError, Feat2MapError, FeatureError, LayoutError
from .features import LINK_PREFIX, PAPER_SF_FEATURE_SPACE, FeatureSpace
from .formats import FORMATS, check_target, detect, native, read_map, write_map
from .messages import counted, on_terminal, one_line


class _Parser(argparse.ArgumentParser):
    """argparse with exit code 2 and a one-line message on bad arguments; help shows defaults."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {one_line(message)}\n")

    def parse_args(self, args=None, namespace=None):  # type: ignore[override]
        """As argparse, but an unknown option is reported by the command it was given to (its
        usage prefix, `feat2map generate: error: ...`) with the nearest known option."""
        ns, extras = self.parse_known_args(args, namespace)
        if extras:
            parser = self._innermost(ns)
            known = [o for a in parser._actions for o in a.option_strings if o.startswith("--")]
            hints = [difflib.get_close_matches(x.split("=")[0], known, n=1, cutoff=0.75) for x in extras
                     if x.startswith("-")]
            hint = "; ".join(f"did you mean {h[0]}?" for h in hints if h)
            parser.error(f"unrecognized arguments: {' '.join(extras)}" + (f" ({hint})" if hint else ""))
        return ns

    def _innermost(self, ns: argparse.Namespace) -> argparse.ArgumentParser:
        """The (sub)command parser that `ns` was parsed by: `feat2map export apollo`'s, say."""
        parser: argparse.ArgumentParser = self
        while True:
            subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
            chosen = getattr(ns, subs[0].dest, None) if subs else None
            if chosen not in (subs[0].choices if subs else {}):
                return parser
            parser = subs[0].choices[chosen]


class _HelpFormatter(argparse.HelpFormatter):
    """Descriptions filled paragraph by paragraph; every option's help ends with its default, where
    it has one (flags that are off and options whose help says what happens without them are left alone)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n\n".join(super(_HelpFormatter, self)._fill_text(par, width, indent) for par in text.split("\n\n"))

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (action.option_strings and not any(action.default is x for x in (None, False, argparse.SUPPRESS))
                and "default" not in text):
            text += " (default: %(default)s)"
        return text


def _summary(m) -> str:
    """`8 junctions, 92 roads, ...`: what a map holds (crosswalks outside junctions, mid-block
    ones, counted apart when there are any; yield signs and generated filter lanes when there are
    any)."""
    text = ", ".join(counted(n, noun) for n, noun in (
        (len(m.junctions), "junction"), (len(m.roads), "road"), (len(m.lanes), "lane"), (len(m.signals), "signal"),
        (len(m.stop_signs), "stop sign"), (len(m.crosswalks), "crosswalk")))
    midblock = sum(c.junction_id is None for c in m.crosswalks.values())
    filters = sum(1 for r in m.roads.values() if r.junction_id is not None and r.id.startswith(f"{r.junction_id}_f"))
    return (text + (f" ({midblock} outside junctions)" if midblock else "")
            + (f", {counted(len(m.yield_signs), 'yield sign')}" if m.yield_signs else "")
            + (f", {counted(filters, 'filter lane')}" if filters else ""))


GENERATE_MARKERS = ("map.json",)  # a folder holding one is an earlier `generate` output, replaced whole
def seed_arg(text: str) -> int:
    """argparse type of --seed: an integer 0 <= seed < 2**63 (`generate.check_seed`)."""
    from .generate import check_seed

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text[:40]!r}") from None
    try:
        return check_seed(value)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(exc.message) from None


def limit_arg(text: str) -> tuple[str, float]:
    """argparse type of --limit NAME=VALUE."""
    name, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not name or not math.isfinite(number) or number <= 0:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with a positive number, got {text[:60]!r}")
    return name.strip(), number


def _overrides(args: argparse.Namespace) -> dict:
    return {k: getattr(args, k) for k in ("grid_gap", "lane_width", "crosswalk_width",
                                          "samples_per_combination") if getattr(args, k) is not None}


def option_names(message: str) -> str:
    """A config error about fields the command line set, in the options' words:
    "config field 'grid_gap' must be ..." -> "--grid-gap must be ..."."""
    return re.sub(r"config field '(\w+)'", lambda m: "--" + m[1].replace("_", "-"), message)


def _config(args: argparse.Namespace) -> GenerationConfig:
    overrides = _overrides(args)
    try:
        cfg = GenerationConfig.from_dict(overrides)
        cfg.check_limits()
        return cfg
    except ValueError as exc:  # ConfigError, LimitError: about the options just given
        if not isinstance(exc, Feat2MapError):
            raise
        raise type(exc)(option_names(exc.message), "command line") from None


def _extract_maps(paths: Sequence[str], skipped: list | None = None, quiet: bool = False,
                  buildable: GenerationConfig | None = None, midblock: list | None = None,
                  filters: list | None = None, ramps: list | None = None):
    """Junction features of the maps; with `buildable`, only those generation can build with
    that config (the others are skipped with a warning naming map, junction and why); the
    maps' mid-block crosswalks are appended to `midblock`, their filter lanes to `filters` and
    their ramps to `ramps` when given (a map with ramps but no junction of 3 or more arms is no
    error then)."""
    from .extract import extract_filters, extract_junctions, extract_midblock
    from .extract_ramps import extract_ramps
    from .generate import check_buildable

    junctions = []
    for p in tqdm(paths, desc="reading maps", unit="map", disable=quiet or len(paths) < 2 or not on_terminal()):
        m = read_map(p)
        junctions += extract_junctions(m, map_name=str(p), skipped=skipped)
        if midblock is not None:
            midblock += extract_midblock(m, map_name=str(p))
        if filters is not None:
            filters += extract_filters(m, map_name=str(p))
        if ramps is not None:
            ramps += extract_ramps(m, map_name=str(p))
    if not junctions and not ramps:
        raise Feat2MapError("no junctions with 3 or more arms found", ", ".join(paths))
    if buildable is None:
        return junctions
    kept = []
    for j in junctions:
        try:
            check_buildable(j.feature, buildable)
        except (FeatureError, LayoutError) as exc:
            print(f"feat2map: warning: {one_line(f'{j.map_name}: junction {j.id}: cannot be generated ({exc.message})')}"
                  ", skipped", file=sys.stderr)
            continue
        kept.append(j)
    if not kept:
        raise Feat2MapError(f"none of the {counted(len(junctions), 'junction')} found can be generated", ", ".join(paths))
    return kept


def cmd_generate(args: argparse.Namespace) -> int:
    from .generate import generate
    from .render import render_junctions, render_map

    out = atomic.check_dir_target(args.out, GENERATE_MARKERS)
    if args.opendrive:
        check_target(out / "map.xodr", "opendrive")
    cfg = _config(args)
    stages = tqdm(total=4, desc="generate", unit="stage", disable=True if args.quiet else None)
    if args.features:
        space = FeatureSpace.load(args.features)
    elif args.from_maps:
        from .extract import map_feature

        space = map_feature(_extract_maps(args.from_maps, quiet=args.quiet, buildable=cfg))
    elif not args.spec:
        space = PAPER_SF_FEATURE_SPACE
    else:
        space = None
    stages.set_postfix_str("layout")
    if args.spec:  # hand-written junctions and chains, on top of `space` when one was given
        from .spec import build_spec, load_spec

        spec = load_spec(args.spec)
        m = build_spec(spec, seed=args.seed, config=spec.generation_config(_overrides(args)), space=space)
        from .extract import extract_midblock

        feats = [j.feature for j in m.junctions.values() if j.feature is not None]
        space = FeatureSpace.from_features(feats, (c.feature for c in extract_midblock(m))) if feats else None
    else:
        assert space is not None  # set above whenever there is no spec
        m = generate(space, seed=args.seed, config=cfg, progress=not args.quiet)
    stages.update(2)
    with atomic.staged_dir(out, GENERATE_MARKERS) as tmp:
        native.save(m, tmp / "map.json")
        if space is not None:
            atomic.write_text(tmp / "features.json", space.to_json())
        stages.set_postfix_str("picture")
        if not args.no_picture:
            render_map(m, tmp / "map.png", title=f"feat2map seed {args.seed}: {counted(len(m.junctions), 'junction')}")
            if 0 < len(m.junctions) <= 64:
                render_junctions(m, tmp / "junctions.png")
        stages.update(1)
        if args.opendrive:
            write_map(m, tmp / "map.xodr", "opendrive")
        if args.lanelet2:  # DIR/lanelet2/ is an Autoware map folder (lanelet2_map.osm, map_projector_info.yaml)
            write_map(m, tmp / "lanelet2" / "lanelet2_map.osm", "lanelet2")
        if args.commonroad:
            write_map(m, tmp / "commonroad.xml", "commonroad")
        if not args.no_apollo:  # DIR/apollo/ is what a user copies to Apollo's modules/map/data/<name>/
            write_map(m, tmp / "apollo", "apollo")
        stages.update(1)
    stages.close()
    print(f"wrote {args.out}: {_summary(m)}")
    return 0


def cmd_extract(args: argparse.Namespace) -> int:
    from .extract import map_feature

    if args.out:
        atomic.check_file_target(args.out)
    if args.picture:
        from .render import check_picture_path

        check_picture_path(args.picture)
    skipped: list = []
    midblock: list = []
    filters: list = []
    ramps: list = []
    junctions = _extract_maps(args.maps, skipped, quiet=args.quiet, midblock=midblock, filters=filters, ramps=ramps)
    measured = {(j.map_name, j.id) for j in junctions if j.feature.has_ramp}  # their features hold their ramps
    space = map_feature(junctions, midblock, (r.kind for r in ramps if (r.map_name, r.junction) not in measured))
    if args.picture:  # first: it is the step that can fail; nothing is written if it does
        from .render import render_map

        first = read_map(args.maps[0])
        ctrl = {j.id: j.feature.control for j in junctions if j.map_name == str(args.maps[0])}
        ctrl.update({s.id: s.control for s in skipped if s.map_name == str(args.maps[0])})
        render_map(first, args.picture, title=str(args.maps[0]), controls=ctrl)
    if args.out:
        atomic.write_text(args.out, space.to_json())
    if args.json:
        doc = {"maps": [str(p) for p in args.maps], "junctions": [j.to_dict() for j in junctions],
               "feature_space": space.to_dict(), "skipped": [s.to_dict() for s in skipped],
               "midblock_crosswalks": [c.to_dict() for c in midblock], "filter_lanes": [f.to_dict() for f in filters],
               "ramps": [r.to_dict() for r in ramps]}
        print(json.dumps(doc, indent=2))
        return 0
    _print_junction_table(args.maps, junctions, skipped, ramps)
    _print_ramps(ramps)
    signalised = sum(c.feature.control == "signal" for c in midblock)
    found = (f"{counted(len(junctions), 'junction')} ({len(skipped)} skipped), "
             f"{counted(len(midblock), 'mid-block crosswalk')} ({signalised} signalised), "
             f"{counted(len(filters), 'filter lane')} ({sum(f.control == 'signal' for f in filters)} signalised)"
             + (f", {counted(len(ramps), 'ramp')} ({sum(r.kind == 'on' for r in ramps)} on, "
                f"{sum(r.kind == 'off' for r in ramps)} off)" if ramps else ""))
    if args.out:  # the map feature is in the file: not again on the screen
        print(f"\n{found}; map feature written to {args.out}")
        return 0
    shown = space.to_dict()  # angles to 0.001 deg on the screen (the file keeps them exact)
    shown["rotation_ranges"] = {n: [[round(a, 3) for a in r] for r in rs] for n, rs in shown["rotation_ranges"].items()}
    print(f"\n{found}; map feature:\n{json.dumps(shown, indent=2, sort_keys=True)}")
    return 0


def _print_ramps(ramps: list) -> None:
    """One line per ramp found (nothing when there are none): `  on-ramp 42 -> 5 at junction 1:
    56.49 deg, 225.15 m`, under the map's name."""
    for path in dict.fromkeys(r.map_name for r in ramps):
        print(f"{path}: {counted(sum(r.map_name == path for r in ramps), 'ramp')}")
        for r in (r for r in ramps if r.map_name == path):
            at = f"junction {r.junction}" if r.junction is not None else "a direct link"
            way = f"{r.ramp_road} -> {r.road}" if r.kind == "on" else f"{r.road} -> {r.ramp_road}"
            print(f"  {r.kind}-ramp {way} at {at}: {r.angle_deg:.2f} deg, {r.length_m:.2f} m "
                  f"(main road {r.main_road})")


def _ramp_note(feature) -> str:
    """`  ramps: 2 on, 1 off (75.00 m)`: a ramp junction's ramps by socket (`link-on`, `link-off`
    for motorway links) and its acceleration and deceleration lanes' length (nothing for a
    junction without)."""
    if not feature.has_ramp:
        return ""
    return "  ramps: " + ", ".join(f"{k} {LINK_PREFIX if s.link else ''}{s.ramp}" for k, s in enumerate(feature.sockets)
                                   if s.ramp != "none") \
        + f" ({feature.ramp_length:.2f} m)"


def _filter_note(feature) -> str:
    """`  filter lanes: 2 yield (island), 3 signal (painted)`: a junction's filter lanes by socket
    (nothing for a junction without)."""
    if not feature.has_filter:
        return ""
    return "  filter lanes: " + ", ".join(f"{k} {s.filter} ({'island' if s.island else 'painted'})"
                                          for k, s in enumerate(feature.sockets) if s.filter != "none")


def _print_junction_table(maps: Sequence[str], junctions: list, skipped: list, ramps: Sequence = ()) -> None:
    """One table per map, headed by the map's full path; ids in full (columns fit the widest); a
    skipped junction whose lanes join a ramp (`ramps`) says so."""
    joins = {(r.map_name, r.junction): r.kind for r in ramps if r.junction is not None}
    for path in map(str, maps):
        rows = [(j.id, j.feature.n_roads, j.feature.control, j.feature.crosswalk,
                 "[" + ", ".join(f"{a:.2f}" for a in j.feature.rotation) + "]" + _filter_note(j.feature)
                 + _ramp_note(j.feature))
                for j in junctions if j.map_name == path]
        rows += [(s.id, s.n_arms, s.control, s.crosswalk, f"skipped: {s.reason}"
                  + (f" (it joins an {joins[(path, s.id)]}-ramp: see the ramps)" if (path, s.id) in joins else ""))
                 for s in skipped if s.map_name == path]
        print(f"{path}: {counted(len(rows), 'junction')}")
        width = max([len("junction")] + [len(r[0]) for r in rows])
        print(f"  {'junction':<{width}}  {'n':>2}  {'control':<7}  {'crosswalk':<9}  rotation (deg)")
        for jid, n, control, crosswalk, rest in rows:
            print(f"  {jid:<{width}}  {n:>2}  {control:<7}  {'yes' if crosswalk else 'no':<9}  {rest}")


def cmd_validate(args: argparse.Namespace) -> int:
    fmt = FORMATS[args.format] if args.format else detect(args.path, "validate")
    if fmt.validate is None:
        raise Feat2MapError(f"format {fmt.name} has no validator", "--format")
    if args.picture:
        from .render import check_picture_path

        check_picture_path(args.picture)
    problems = fmt.face("validate")(args.path, progress=not args.quiet and on_terminal())
    for p in problems:
        print(one_line(p))
    errors = [p for p in problems if not p.warning]
    said = counted(len(errors), "problem") + (f", {counted(len(problems) - len(errors), 'warning')}"
                                              if len(errors) < len(problems) else "")
    if args.picture:
        if fmt.picture is None:
            raise Feat2MapError(f"format {fmt.name} draws no problem picture", "--picture")
        fmt.face("picture")(args.path, args.picture, problems, title=f"{args.path}: {said}")
    print(f"{args.path}: {said}")
    return 1 if errors else 0


def cmd_export(args: argparse.Namespace) -> int:
    fmt = FORMATS[args.format]
    check_target(args.out, fmt.name)
    options = {o.kwarg: getattr(args, o.kwarg) for o in fmt.options if getattr(args, o.kwarg) is not None}
    if fmt.input == "suite":
        from .scenarios.scenario import load_suite

        suite = load_suite(args.map)
        written = fmt.face("write")(suite, args.out, **options)
        print(f"wrote {args.out} ({fmt.title}): {counted(len(written), 'scenario')}")
        return 0
    with warnings.catch_warnings(record=True) as caught:  # what reading skipped, shown once each
        warnings.simplefilter("always")
        m = read_map(args.map)
    for w in {str(w.message): w for w in caught}.values():
        warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    if not m.lanes:
        raise Feat2MapError("map has no lanes", str(args.map))
    # elements reading skipped (their warnings say so); load-time findings and repairs are no skip
    skipped = sum(1 for w in caught if w.filename.startswith(_our_dirs()) and "skip" in str(w.message).lower())
    if skipped:  # what is left of a broken input must validate whole (see formats/apollo/writer.refuse_invalid)
        m = dataclasses.replace(m, meta={**m.meta, "skipped_on_read": skipped})
    if "origin" in options:
        from .formats.geo import check_origin

        options["origin"] = check_origin(options["origin"], "--origin")
    try:
        write_map(m, args.out, fmt.name, **options)
    except OSError as exc:
        raise Feat2MapError(f"cannot write ({exc.strerror or exc})", str(args.out)) from None
    title = fmt.title  # the revision written, where an option chose one ("ASAM OpenDRIVE 1.7 (.xodr)")
    if fmt.name == "opendrive" and options.get("version"):
        title = title.replace(OPENDRIVE_VERSIONS[0], options["version"], 1)
    print(f"wrote {args.out} ({title}): {_summary(m)}")
    return 0


GENERATE_HELP = """Generate a map: sample one junction per feature combination (the paper's Algorithm 1)
from a feature space, lay the junctions out on a grid, join them with Bezier roads, and write
DIR/map.json, DIR/features.json (the map feature), DIR/map.png, DIR/junctions.png and
DIR/apollo/ (and DIR/map.xodr, DIR/lanelet2/, DIR/commonroad.xml with --opendrive, --lanelet2,
--commonroad). The feature space is the paper's San Francisco Table I unless --features or
--from-maps gives another; --spec adds hand-written junctions and road chains. The same seed and
options give the same bytes."""


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="feat2map", description=__doc__ + "\n\nRun `feat2map COMMAND --help` for a command's options.")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    lim = Limits()
    p.add_argument(LIMIT_FLAG, action="append", type=limit_arg, metavar="NAME=VALUE", default=[],
                   help="raise a size limit for this run (repeatable); limits and defaults: " + ", ".join(
                       f"{f.name}={plain_number(getattr(lim, f.name))}" for f in dataclasses.fields(lim)))
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser, title="commands", metavar="COMMAND")

    g = sub.add_parser("generate", help="generate a map from a feature space, input maps or a spec",
                       description=GENERATE_HELP)
    src = g.add_mutually_exclusive_group()
    src.add_argument("--features", metavar="FILE",
                     help="feature-space JSON, as `extract --out` writes (default: the paper's San Francisco Table I)")
    src.add_argument("--from-maps", nargs="+", metavar="MAP",
                     help="extract the feature space from these maps (Apollo .bin/.txt, OpenDRIVE .xodr, feat2map .json)")
    g.add_argument("--spec", metavar="FILE", help="hand-written junctions/road chains (YAML or JSON, see "
                   "docs/specs.md); with --features/--from-maps they are added to the sampled junctions")
    g.add_argument("--seed", type=seed_arg, default=0, metavar="N",
                   help="random seed, 0 to 2**63-1: the same seed and options give the same map")
    g.add_argument("--out", required=True, metavar="DIR", help="output folder, built whole and swapped in; an existing "
                   "folder is replaced as a whole if it is an earlier generate output (holds map.json), else refused")
    g.add_argument("--samples-per-combination", type=int, metavar="N",
                   help="junctions sampled per feature combination (default: 1, or the spec's)")
    g.add_argument("--grid-gap", type=float, metavar="M",
                   help=f"distance between neighbouring grid points in metres (default: {GRID_GAP_M:g}, or the spec's)")
    g.add_argument("--lane-width", type=float, metavar="M",
                   help=f"lane width in metres (default: {LANE_WIDTH_M:g}, or the spec's)")
    g.add_argument("--crosswalk-width", type=float, metavar="M",
                   help=f"crosswalk width in metres (default: {CROSSWALK_WIDTH_M:g}, or the spec's)")
    g.add_argument("--opendrive", action="store_true", help="also export DIR/map.xodr")
    g.add_argument("--lanelet2", action="store_true", help="also export DIR/lanelet2/: the Lanelet2 map and "
                   "map_projector_info.yaml (an Autoware map folder)")
    g.add_argument("--commonroad", action="store_true", help="also export DIR/commonroad.xml (CommonRoad scenario)")
    g.add_argument("--no-apollo", action="store_true", help="skip the Apollo export (DIR/apollo/)")
    g.add_argument("--no-picture", action="store_true", help="skip DIR/map.png and DIR/junctions.png")
    g.add_argument("--quiet", action="store_true", help="no progress bars")
    g.set_defaults(func=cmd_generate)

    e = sub.add_parser("extract", help="extract junction features and the map feature from maps",
                       description="Measure every junction's feature [road count, rotation, control, crosswalk] "
                                   "in maps and merge them into one map feature (a feature space for "
                                   "`generate --features`). Prints a table per map, or JSON with --json.")
    e.add_argument("maps", nargs="+", metavar="MAP", help="Apollo .bin/.txt, OpenDRIVE .xodr or feat2map .json maps")
    e.add_argument("--out", metavar="FILE", help="write the feature-space JSON here")
    e.add_argument("--json", action="store_true", help="print one JSON document instead of the tables")
    e.add_argument("--picture", metavar="FILE", help="bird's-eye PNG/SVG of the first map, junctions coloured by control")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    e.set_defaults(func=cmd_extract)

    ex = sub.add_parser("export", help="export a map to another format",
                        description="Write a map (any map feat2map reads) in another format; run "
                                    "`feat2map export FORMAT --help` for a format's options.")
    exsub = ex.add_subparsers(dest="format", required=True, parser_class=_Parser, title="formats", metavar="FORMAT")
    for fmt in FORMATS.values():
        if fmt.write is None:
            continue
        what = "a scenario suite" if fmt.input == "suite" else "a map"
        f = exsub.add_parser(fmt.name, help=f"export as {fmt.title}", description=f"Export {what} as {fmt.title}.")
        if fmt.input == "suite":
            f.add_argument("map", metavar="SUITE", help="scenario suite (.yaml or .json, see `feat2map suite`)")
        else:
            f.add_argument("map", help="feat2map .json map (or any map feat2map reads)")
        f.add_argument("--out", required=True, metavar="DIR" if fmt.output == "dir" else "FILE",
                       help=f"output folder, built whole and swapped in; an existing folder is replaced as a whole "
                       f"if it is an earlier export (holds {' or '.join(fmt.markers) or 'its files'}), else refused"
                       if fmt.output == "dir" else f"output file ({fmt.suffixes[0]})")
        for o in fmt.options:
            f.add_argument(o.flag, dest=o.kwarg, **o.argparse)
        f.set_defaults(func=cmd_export)

    v = sub.add_parser("validate", help="check a map with its format's rules (Apollo: what Apollo needs to load and route)",
                       description="Check a map with its format's rules and print one line per problem; exit 1 "
                                   "if there is any.")
    v.add_argument("path", help="an Apollo map folder (base_map, sim_map, routing_map as .bin/.txt) or one map file")
    v.add_argument("--format", choices=sorted(n for n, f in FORMATS.items() if f.validate),
                   help="the map's format (default: from the path)")
    v.add_argument("--picture", metavar="FILE", help="PNG/SVG of the map with the problems ringed in red")
    v.add_argument("--quiet", action="store_true", help="no progress bar")
    v.set_defaults(func=cmd_validate)

    from .cli_scenarios import add_scenario_commands

    add_scenario_commands(sub)
    return p


def _print_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Our warnings (a skipped road, junction or element) as one line, like errors: no source
    line; other libraries' warnings as Python prints them."""
    if filename.startswith(_our_dirs()):
        print(f"feat2map: warning: {one_line(message)}", file=sys.stderr)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


@functools.cache
def _our_dirs() -> tuple[str, ...]:
    """The folders of feat2map and its subpackages installed from elsewhere (envs, scenarios)."""
    specs = [importlib.util.find_spec(name) for name in ("feat2map", "feat2map.envs", "feat2map.scenarios")]
    return tuple(d for spec in specs if spec is not None for d in spec.submodule_search_locations or ())


def main(argv: Sequence[str] | None = None) -> int:
    for stream in (sys.stdout, sys.stderr):  # a non-UTF-8 file name is printed escaped, not a traceback
        reconfigure = getattr(stream, "reconfigure", None)  # a replaced stream may not have it
        if reconfigure is not None:
            with contextlib.suppress(ValueError):
                reconfigure(errors="backslashreplace")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with raised_limits(**dict(args.limit)), warnings.catch_warnings():
            warnings.simplefilter("default", UserWarning)  # each once per run (in-process runs start afresh)
            # numpy's and shapely's floating-point notes ("invalid value encountered in ...") on odd
            # input geometry: what matters is reported as problems or errors, these say nothing to a user
            warnings.filterwarnings("ignore", r"(invalid value|divide by zero|overflow|underflow) encountered",
                                    RuntimeWarning)
            warnings.showwarning = _print_warning
            return int(args.func(args) or 0)
    except Feat2MapError as exc:
        print(f"feat2map: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:  # the machine's, not the input's: a full disk, a permission, a folder given as a file
        where = one_line(exc.filename, WHERE_MAX_CHARS) if exc.filename else "output"
        print(f"feat2map: error: {where}: {exc.strerror or type(exc).__name__}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
