"""Hardening harness (issue 14): counts what a careless user or an attacker gets out of feat2map.

Not part of the test suite (it runs for minutes); run it with the interpreter whose feat2map
you want to measure, e.g. `.venv/bin/python scripts/harden_harness.py --quick`. Sections:

1. corrupt inputs: truncations, bit flips and value mutations (NaN, inf, 1e308, 1e9 lengths,
   negative / string widths, self-successors, 1-point Béziers, 5,000-deep nesting ...) of a
   generated map in every format (and of the small shared maps, when ../shared/maps exists),
   run through `extract`, `generate --from-maps`, `validate` and `export`; plus bad command
   lines and special inputs (a non-map .txt, damaged output manifests, a user's
   map_projector_info.yaml). Counted: tracebacks (an exception escaping the CLI, or a crash/timeout of the
   worker), non-finite values written with exit 0, over-long or leaking error lines.
2. SIGKILL: `generate` / `export apollo` killed at random moments, over nothing, over a
   complete run of another seed, over a killed run; the output folder must be absent, the old
   one or the new one, whole (never half-written or mixed); hidden staging leftovers must be
   gone after the next run.
3. invariants: >= N random 3-8-leg maps (random feature spaces through `generate`, random
   specs through `build_spec`, random features through `generate_from_features`): check_map
   violations, and whether the Apollo validator reports problems on the violating maps.
4. huge requests: time and peak memory of a YAML alias bomb, a 100,000-junction spec,
   --samples-per-combination 125000, a chain of 10,000 km roads, OpenDRIVE length 1e9.
5. rough edges (issues 25 and 35): exports of broken maps (junction-lane cycle, self-link,
   zero-length lane, .xodr links to a missing road) must be refused or validate clean; messages
   name the file/option/command, never a staging folder or a file's content; no traceback on a
   non-UTF-8 name; a folder named map.json is not ours; a user's empty folder in an earlier
   output, a user's map_projector_info.yaml are kept; --out LINK leaves no stray link; the envs
   refuse bad (batch) actions and non-dict options/actions with a ValueError before any state
   changes; a non-terminal stderr stays clean; `pip check` passes. Pass/fail per case.
6. planner bridge (issue 33): abusive planners (BRIDGE_CASES: forked children holding stdout,
   daemons, never reading stdin, floods, deep JSON, huge numbers, NaN, 50 MB lines, stale,
   doubled and future step ids, crashes, 100 MB of stderr ...), each driving a rollout: its
   outcome, report, wall time, peak RSS and surviving processes (--bridge-module: another
   bridge.py, for a before/after).
7. report injection (issue 35): each attack (a script tag, an event handler, a javascript: link, a
   raw HTML block, a Markdown image or link of a local secret file by absolute or `../` path) in a
   suite name, a scenario name, a stage name and a planner's stderr, and raw Markdown given to
   report_html with a symlink out of the folder: report.html must hold no script, no handler, no
   javascript: URL, no byte of the secret, only data: pictures of files the rollout wrote, and
   a strict Content-Security-Policy; report.md no markup outside its code blocks. Pass/fail per case.

Prints one table per section and a summary (also as JSON with --json FILE).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import multiprocessing as mp
import os
import random
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("FEAT2MAP_SHARED_MAPS", REPO.parent / "shared" / "maps"))
SMALL_SHARED = ["apollo/cube_town/base_map.bin", "apollo/borregas_ave/base_map.bin",
                "opendrive/esmini_fabriksgatan/fabriksgatan_traffic_lights.xodr",
                "opendrive/commonroad_four_way_crossing/four_way_crossing.xodr"]
MEM_LIMIT = 6 << 30  # bytes of address space per worker: a 149 GiB allocation fails fast
CASE_TIMEOUT_S = 60.0
ERROR_LINE_CAP = 500  # an error line longer than this counts as over-long
_NONFINITE_TEXT = re.compile(rb"(?<![\w.])[-+]?(nan|inf|infinity)(?![\w.])", re.I)


# ------------------------------------------------------------------------------ corpus

def _mutate_numbers(text: str, rng: random.Random, value: str, k: int, pattern: str) -> str:
    """Replace k random matches of `pattern` (a number in group 1) with `value`."""
    spans = [m.span(1) for m in re.finditer(pattern, text)]
    if not spans:
        return text
    for a, b in sorted(rng.sample(spans, min(k, len(spans))), reverse=True):
        text = text[:a] + value + text[b:]
    return text


def _json_mutations(doc: dict, rng: random.Random) -> list[tuple[str, str]]:
    """Semantic mutations of a native map document: (name, text)."""
    out = []

    def dump(d):
        return json.dumps(d, allow_nan=True)

    def lane(d):
        return rng.choice(d["lanes"])

    for name, fn in [
        ("centerline-nan", lambda d: lane(d)["centerline"][0].__setitem__(0, float("nan"))),
        ("centerline-inf", lambda d: lane(d)["centerline"][1].__setitem__(1, float("inf"))),
        ("centerline-1e308", lambda d: lane(d)["centerline"][0].__setitem__(0, 1e308)),
        ("centerline-1pt", lambda d: lane(d).__setitem__("centerline", lane(d)["centerline"][:1])),
        ("boundary-nan", lambda d: lane(d)["left_boundary"][0].__setitem__(1, float("nan"))),
        ("width-negative", lambda d: lane(d).__setitem__("width", -3.5)),
        ("width-string", lambda d: lane(d).__setitem__("width", "wide")),
        ("width-nan", lambda d: lane(d).__setitem__("width", float("nan"))),
        ("speed-inf", lambda d: lane(d).__setitem__("speed_limit", float("inf"))),
        ("self-successor", lambda d: (lambda ln: ln.__setitem__("successors", [ln["id"]]))(lane(d))),
        ("bezier-1pt", lambda d: lane(d).__setitem__("bezier", [[0, 0]])),
        ("bezier-nan", lambda d: lane(d).__setitem__("bezier", [[0, 0], [1, float("nan")], [2, 0], [3, 0]])),
        ("reference-string", lambda d: rng.choice(d["roads"]).__setitem__("reference", "x")),
        ("stopline-nan", lambda d: (d["signals"] or d["stop_signs"])[0]["stop_line"][0].__setitem__(0, float("nan"))),
        ("heading-inf", lambda d: (d["signals"] or d["stop_signs"])[0].__setitem__("heading", float("inf"))),
        ("junction-polygon-nan", lambda d: d["junctions"][0]["polygon"][0].__setitem__(0, float("nan"))),
        ("origin-inf", lambda d: d.__setitem__("origin", [float("inf"), 0])),
        ("feature-9-legs", lambda d: d["junctions"][0].__setitem__("feature", {
            "rotation": [i * 40.0 for i in range(9)], "control": "bare", "crosswalk": False})),
        ("lanes-not-list", lambda d: d.__setitem__("lanes", {"a": 1})),
        ("predecessors-int", lambda d: lane(d).__setitem__("predecessors", 5)),
        ("crosswalk-2pt", lambda d: d["crosswalks"][0].__setitem__("polygon", d["crosswalks"][0]["polygon"][:2])
         if d["crosswalks"] else None),
    ]:
        d = json.loads(json.dumps(doc))
        try:
            fn(d)
        except (IndexError, KeyError):
            continue
        out.append((name, dump(d)))
    out.append(("nested-5000", '{"format": "feat2map-map", "version": 1, "meta": ' + "[" * 5000 + "]" * 5000 + "}"))
    return out


def _xodr_mutations(text: str, rng: random.Random) -> list[tuple[str, str]]:
    out = []
    for name, attr, value in [("length-1e9", "length", "1e9"), ("length-1e308", "length", "1e308"),
                              ("length-nan", "length", "nan"), ("length-negative", "length", "-5"),
                              ("hdg-inf", "hdg", "inf"), ("x-1e308", "x", "1e308"), ("s-nan", "s", "NaN")]:
        out.append((name, _mutate_numbers(text, rng, value, 3, rf'\b{attr}="([^"]*)"')))
    for name, value in [("width-1e6", "1e6"), ("width-1e300", "1e300"), ("width-negative", "-3.5"),
                        ("width-string", "wide"), ("width-nan", "nan")]:
        out.append((name, _mutate_numbers(text, rng, value, 3, r'<width [^>]*\ba="([^"]*)"')))
    out.append(("curvature-1e300", _mutate_numbers(text, rng, "1e300", 2, r'\b[abcd][UV]="([^"]*)"')))
    out.append(("geometry-length-1e9-all", re.sub(r'(<geometry [^>]*length=")[^"]*"', r'\g<1>1e9"', text)))
    out.append(("nested-5000", '<?xml version="1.0"?><OpenDRIVE>' + "<a>" * 5000 + "</a>" * 5000 + "</OpenDRIVE>"))
    return out


def _apollo_txt_mutations(text: str, rng: random.Random) -> list[tuple[str, str]]:
    out = []
    num = r"\b(?:x|y|z|width|length|s|speed_limit|heading): (-?[0-9.e+-]+)"
    for name, value in [("coord-nan", "nan"), ("coord-inf", "inf"), ("coord-1e308", "1e308"),
                        ("coord-neg-inf", "-inf")]:
        out.append((name, _mutate_numbers(text, rng, value, 3, r"\b(?:x|y): (-?[0-9.e+-]+)")))
    out.append(("width-negative", _mutate_numbers(text, rng, "-3.5", 5, r"\bwidth: (-?[0-9.e+-]+)")))
    out.append(("length-1e308", _mutate_numbers(text, rng, "1e308", 3, r"\blength: (-?[0-9.e+-]+)")))
    out.append(("any-number-nan", _mutate_numbers(text, rng, "nan", 20, num)))
    m = re.search(r'lane \{\n  id \{\n    id: "([^"]+)"', text)
    if m:
        lid = m.group(1)
        out.append(("self-successor", text.replace(f'lane {{\n  id {{\n    id: "{lid}"\n  }}',
                                                   f'lane {{\n  id {{\n    id: "{lid}"\n  }}\n  successor_id {{\n'
                                                   f'    id: "{lid}"\n  }}', 1)))
    out.append(("nested-5000", "lane { " * 5000 + "}" * 5000))
    return out


def _byte_mutations(data: bytes, rng: random.Random, n_trunc: int, n_flip: int) -> list[tuple[str, bytes]]:
    out = []
    for _ in range(n_trunc):
        k = rng.randrange(1, max(2, len(data)))
        out.append((f"trunc-{k}", data[:k]))
    for i in range(n_flip):
        b = bytearray(data)
        for _ in range(rng.randint(1, 8)):
            p = rng.randrange(len(b))
            b[p] ^= 1 << rng.randrange(8)
        out.append((f"flip-{i}", bytes(b)))
    return out


def build_corpus(work: Path, rng: random.Random, n_trunc: int, n_flip: int) -> list[tuple[str, Path]]:
    """Write every corrupt input file; returns (label, path)."""
    import feat2map
    from feat2map.formats import write_map
    from feat2map.formats.native import save

    m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1)
    src = work / "src"
    src.mkdir()
    save(m, src / "map.json")
    write_map(m, src / "map.xodr", "opendrive")
    write_map(m, src / "apollo", "apollo")
    seeds = [("gen.json", src / "map.json"), ("gen.xodr", src / "map.xodr"),
             ("gen.base_map.txt", src / "apollo" / "base_map.txt"), ("gen.base_map.bin", src / "apollo" / "base_map.bin")]
    seeds += [(rel.replace("/", "_"), SHARED / rel) for rel in SMALL_SHARED if (SHARED / rel).is_file()]
    corpus: list[tuple[str, Path]] = []
    cdir = work / "corpus"
    cdir.mkdir()

    def put(label: str, suffix: str, data: bytes | str) -> None:
        p = cdir / f"{len(corpus):04d}{suffix}"
        p.write_bytes(data.encode() if isinstance(data, str) else data)
        corpus.append((label, p))

    for label, path in seeds:
        data = path.read_bytes()
        suffix = "".join(path.suffixes[-1:])
        for name, b in _byte_mutations(data, rng, n_trunc, n_flip):
            put(f"{label}:{name}", suffix, b)
        values: list[tuple[str, str]] = []
        if label == "gen.json":
            values = _json_mutations(json.loads(data), rng)
        elif suffix == ".xodr":
            values = _xodr_mutations(data.decode("utf-8", "replace"), rng)
        elif label == "gen.base_map.txt":
            values = _apollo_txt_mutations(data.decode(), rng)
        for name, t in values:
            if t.encode() != data:  # a mutation that found nothing to change is no invalid input
                put(f"{label}:{name}", suffix, t)
    return corpus


def commands_for(path: Path, out: Path) -> list[list[str]]:
    return [["extract", str(path)],
            ["generate", "--from-maps", str(path), "--out", str(out / "gen"), "--no-picture", "--quiet"],
            ["validate", str(path)],
            ["export", "apollo", str(path), "--out", str(out / "apollo")],
            ["export", "opendrive", str(path), "--out", str(out / "map.xodr")]]


def special_cases(work: Path) -> list[tuple[str, list[str], str | None]]:
    """Bad command lines and special inputs: (label, argv, cwd)."""
    sp = work / "special"
    sp.mkdir()
    (sp / "dir_out").mkdir()
    (sp / "dir_out" / "keep.txt").write_text("x")
    import feat2map
    from feat2map.formats.native import save

    m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=2)
    save(m, sp / "m.json")
    (sp / "deep.json").write_text("[" * 5000 + "]" * 5000)
    (sp / "deep.yaml").write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    (sp / "bomb.yaml").write_text(_alias_bomb())
    (sp / "nine.json").write_text(json.dumps({"road_counts": [9], "controls": ["bare"], "crosswalks": [False],
                                              "rotation_ranges": {"9": [[i * 40, i * 40] for i in range(9)]}}))
    (sp / "spec_bad_width.yaml").write_text("config: {lane_width: .nan}\njunctions:\n- sockets: [0, 90, 180]\n")
    (sp / "suite_passwd.yaml").write_text("version: 1\nname: s\nscenarios:\n- name: a\n  map: /etc/passwd\n"
                                          "  route: [[J0, R0, R1]]\n")
    passwd = Path("/etc/passwd")  # its first line, as a .txt: an error that quotes content counts as a leak
    (sp / "passwd.txt").write_text(passwd.read_text().splitlines()[0] + "\n" if passwd.is_file() else "root:x:0:0\n")
    manifests = {"nested list": b'{"files": [["map.json"]]}', "not JSON": b"map.json", "a list": b'["map.json"]',
                 "null": b"null", "not UTF-8": b"\xff\xfe{", "deep": b"[" * 100_000 + b"]" * 100_000,
                 "huge": b'{"files": [' + b'"x", ' * 4_000_000 + b'"map.json"]}'}
    for name, data in manifests.items():  # an earlier output whose manifest is damaged (issue 35)
        d = sp / f"manifest_{name.replace(' ', '_')}"
        d.mkdir()
        save(m, d / "map.json")
        (d / ".feat2map-output.json").write_bytes(data)
    (sp / "ll2").mkdir()
    (sp / "ll2" / "map_projector_info.yaml").write_text("projector_type: MGRS\nmgrs_grid: 54SUE\n")
    out = sp / "o"
    g = ["generate", "--no-picture", "--quiet", "--no-apollo"]
    cases = [
        ("extract /etc/passwd", ["extract", "/etc/passwd"], None),
        ("generate --grid-gap nan", g + ["--grid-gap", "nan", "--out", str(out / "a")], None),
        ("generate --grid-gap inf", g + ["--grid-gap", "inf", "--out", str(out / "b")], None),
        ("generate --grid-gap 1e308", g + ["--grid-gap", "1e308", "--out", str(out / "c")], None),
        ("generate --lane-width nan", g + ["--lane-width", "nan", "--out", str(out / "d")], None),
        ("generate --crosswalk-width -inf", g + ["--crosswalk-width", "-inf", "--out", str(out / "e")], None),
        ("generate --seed -1", g + ["--seed", "-1", "--out", str(out / "f")], None),
        ("generate --out ''", g + ["--out", ""], str(sp)),
        ("generate --features 9 legs", g + ["--features", str(sp / "nine.json"), "--out", str(out / "g")], None),
        ("generate --features deep.json", g + ["--features", str(sp / "deep.json"), "--out", str(out / "h")], None),
        ("generate --spec deep.yaml", g + ["--spec", str(sp / "deep.yaml"), "--out", str(out / "i")], None),
        ("generate --spec nan lane width", g + ["--spec", str(sp / "spec_bad_width.yaml"), "--out", str(out / "j")],
         None),
        ("extract --out existing dir", ["extract", str(sp / "m.json"), "--out", str(sp / "dir_out")], None),
        ("extract --out f.json --picture p.xyz", ["extract", str(sp / "m.json"), "--out", str(sp / "f.json"),
                                                  "--picture", str(sp / "p.xyz")], None),
        ("export opendrive --out existing dir", ["export", "opendrive", str(sp / "m.json"), "--out",
                                                 str(sp / "dir_out")], None),
        ("suite --out existing dir", ["suite", str(sp / "m.json"), "--out", str(sp / "dir_out")], None),
        ("suite --duration nan", ["suite", str(sp / "m.json"), "--out", str(sp / "s.yaml"), "--duration", "nan"],
         None),
        ("suite --traffic -5", ["suite", str(sp / "m.json"), "--out", str(sp / "s2.yaml"), "--traffic", "-5"], None),
        ("rollout suite with map /etc/passwd", ["rollout", str(sp / "suite_passwd.yaml"), "--out", str(out / "r"),
                                                "--quiet"], None),
        ("extract a non-map .txt", ["extract", str(sp / "passwd.txt")], None),
        ("validate a non-map .txt", ["validate", str(sp / "passwd.txt")], None),
        ("export lanelet2 over a user's map_projector_info.yaml", ["export", "lanelet2", str(sp / "m.json"), "--out",
                                                                   str(sp / "ll2" / "x.osm")], None),
    ]
    cases += [(f"generate --out an earlier output with a manifest {name}",
               g + ["--out", str(sp / f"manifest_{name.replace(' ', '_')}")], None) for name in manifests]
    return cases


def _alias_bomb() -> str:
    """A YAML billion-laughs document of about 400 bytes."""
    lines = ['a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(1, 9):
        lines.append(f"a{i}: &a{i} [{','.join([f'*a{i - 1}'] * 9)}]")
    lines.append("junctions: *a8")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ workers

def _worker(conn, mem_limit: int) -> None:
    """Run CLI invocations in-process; report (rc, escaped exception, stderr, stdout size)."""
    resource.setrlimit(resource.RLIMIT_AS, (mem_limit, mem_limit))
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    os.environ.setdefault("MPLBACKEND", "Agg")
    from feat2map.cli import main

    while True:
        job = conn.recv()
        if job is None:
            return
        argv, cwd = job
        err, out = io.StringIO(), io.StringIO()
        old = os.getcwd()
        exc_text = None
        rc = None
        try:
            if cwd:
                os.chdir(cwd)
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                rc = main(argv)
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else 2
        except BaseException as exc:  # what a user would see as a traceback
            exc_text = f"{type(exc).__name__}: {str(exc)[:300]}\n" + "".join(traceback.format_tb(exc.__traceback__)[-3:])
        finally:
            os.chdir(old)
        conn.send((rc, exc_text, err.getvalue()[-20000:]))


class Pool:
    """Worker processes with a hard per-job deadline (a hung worker is killed and replaced)."""

    def __init__(self, n: int, mem_limit: int) -> None:
        self.ctx = mp.get_context("fork")
        self.mem_limit = mem_limit
        self.workers = [self._start() for _ in range(n)]

    def _start(self):
        a, b = self.ctx.Pipe()
        p = self.ctx.Process(target=_worker, args=(b, self.mem_limit))  # not daemonic: rollout spawns workers
        p.start()
        return [p, a]

    def run(self, jobs: list, timeout: float) -> list:
        results = [None] * len(jobs)
        todo = list(enumerate(jobs))
        busy: dict[int, tuple[int, float]] = {}
        while todo or busy:
            for w, (_p, conn) in enumerate(self.workers):
                if w not in busy and todo:
                    i, job = todo.pop(0)
                    conn.send(job)
                    busy[w] = (i, time.monotonic())
            time.sleep(0.005)
            for w in list(busy):
                p, conn = self.workers[w]
                i, t0 = busy[w]
                if conn.poll():
                    try:
                        results[i] = conn.recv() + (time.monotonic() - t0,)
                    except EOFError:
                        results[i] = (None, "worker died", "", time.monotonic() - t0)
                        self._replace(w)
                    del busy[w]
                elif not p.is_alive():
                    results[i] = (None, f"worker died (exit {p.exitcode})", "", time.monotonic() - t0)
                    self._replace(w)
                    del busy[w]
                elif time.monotonic() - t0 > timeout:
                    results[i] = (None, f"timeout after {timeout:.0f} s", "", timeout)
                    p.kill()
                    p.join()
                    self._replace(w)
                    del busy[w]
        return results

    def _replace(self, w: int) -> None:
        p, conn = self.workers[w]
        if p.is_alive():
            p.kill()
        p.join()
        self.workers[w] = self._start()

    def close(self) -> None:
        for p, conn in self.workers:
            with contextlib.suppress(Exception):
                conn.send(None)
            p.join(5)
            if p.is_alive():
                p.kill()


def nonfinite_written(root: Path) -> list[str]:
    """Files under `root` (or `root` itself) holding NaN/inf values."""
    files = [root] if root.is_file() else [p for p in root.rglob("*") if p.is_file()] if root.exists() else []
    bad = []
    for f in files:
        data = f.read_bytes()
        if f.suffix == ".bin":
            try:
                from feat2map.formats.apollo import schema as aps

                msg = aps.parse_map(data, str(f)) if "routing" not in f.name else aps.parse_graph(data, str(f))
                data = str(msg).encode()
            except Exception:
                continue
        elif f.suffix in (".png", ".gif"):
            continue
        if _NONFINITE_TEXT.search(data):
            bad.append(str(f))
    return bad


def section_corpus(work: Path, args) -> dict:
    rng = random.Random(args.seed)
    corpus = build_corpus(work, rng, args.trunc, args.flips)
    jobs, meta = [], []
    for label, path in corpus:
        for argv in commands_for(path, work / "out" / path.stem):
            jobs.append((argv, None))
            meta.append((label, " ".join(argv[:2]) if argv[0] == "export" else argv[0], argv))
    for label, argv, cwd in special_cases(work):
        jobs.append((argv, cwd))
        meta.append((label, "special", argv))
    t0 = time.time()
    pool = Pool(args.workers, MEM_LIMIT)
    try:
        results = pool.run(jobs, CASE_TIMEOUT_S)
    finally:
        pool.close()
    counts = {"inputs": len(corpus), "runs": len(jobs), "tracebacks": 0, "timeouts": 0, "exit0_nonfinite": 0,
              "long_error_lines": 0, "leaks": 0, "accepted_bad_cli": 0, "wall_s": round(time.time() - t0, 1)}
    examples: dict[str, list[str]] = {}
    passwd_first = Path("/etc/passwd").read_text().splitlines()[0] if Path("/etc/passwd").is_file() else "root:x:0:0"
    for (label, cmd, argv), (rc, exc, err, _dt), (_, cwd) in zip(meta, results, jobs):
        key = None
        if exc is not None:
            key = "timeouts" if exc.startswith("timeout") else "tracebacks"
        elif "Traceback" in err:
            key = "tracebacks"
        if key:
            counts[key] += 1
            examples.setdefault(key, []).append(f"{label} | {cmd} | {(exc or err).splitlines()[0][:200]}")
        lines = [ln for ln in err.splitlines() if "error" in ln]
        if any(len(ln) > ERROR_LINE_CAP for ln in lines):
            counts["long_error_lines"] += 1
            examples.setdefault("long_error_lines", []).append(f"{label} | {cmd} | {max(map(len, lines))} chars")
        if passwd_first[:12] in err:
            counts["leaks"] += 1
            examples.setdefault("leaks", []).append(f"{label} | {cmd}")
        if rc == 0:
            outs = [Path(cwd or ".") / a for i, a in enumerate(argv)  # --out '' is the job's folder
                    if i and argv[i - 1] in ("--out", "--picture") and (a or cwd)]
            bad = [b for o in outs for b in nonfinite_written(o)]
            if bad:
                counts["exit0_nonfinite"] += 1
                examples.setdefault("exit0_nonfinite", []).append(f"{label} | {cmd} | {bad[0]}")
            if cmd == "special":
                counts["accepted_bad_cli"] += 1
                examples.setdefault("accepted_bad_cli", []).append(label)
    # a value mutation (not a truncation or bit flip, which may leave a valid file) is an invalid
    # input: accepted when a command exits 0 on it, silently when it also warns of nothing
    accepted: dict[str, dict[str, list[str]]] = {}
    for (label, cmd, _argv), (rc, _exc, err, _dt) in zip(meta, results):
        name = label.rsplit(":", 1)[-1]
        if cmd != "special" and not name.startswith(("trunc-", "flip-")) and rc == 0:
            kind = "exit0_invalid_warned" if "warning" in err else "exit0_invalid"
            accepted.setdefault(label, {}).setdefault(kind, []).append(cmd)
    for label, kinds in accepted.items():
        kind = min(kinds)  # silent acceptance by any command counts first
        examples.setdefault(kind, []).append(f"{label} | {', '.join(kinds[kind])}")
    counts["value_mutations"] = sum(1 for label, _ in corpus if not label.rsplit(":", 1)[-1].startswith(("trunc-",
                                                                                                        "flip-")))
    for kind in ("exit0_invalid", "exit0_invalid_warned"):
        counts[kind] = len(examples.get(kind, []))
    counts["examples"] = {k: v[:6] for k, v in examples.items()}
    counts["all_examples"] = examples
    return counts


# ------------------------------------------------------------------------------ SIGKILL

def section_kill(work: Path, args) -> dict:
    """Kill runs (a) right before their k-th filesystem change (rename, replace, unlink, rmdir,
    mkdir, rmtree, swap), for every k or a sample of them, and (b) at random moments; the output
    folder must then be absent, the old output or the new one, whole; the next complete run must
    leave exactly its own output and no hidden leftovers."""
    sys.path.insert(0, str(REPO / "tests"))
    from killpoints import RUNNER, fingerprint

    rng = random.Random(args.seed + 1)
    env = dict(os.environ, SDL_VIDEODRIVER="offscreen", MPLBACKEND="Agg")
    base = work / "kill"
    base.mkdir()
    py = [sys.executable, "-c", RUNNER]

    def run(argv, kill_at=0, timeout=600):
        return subprocess.run(py + argv, env=dict(env, FEAT2MAP_KILL_AT=str(kill_at)), cwd=base, timeout=timeout,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    for s in (1, 2):
        run(["generate", "--seed", str(s), "--out", str(base / f"g{s}"), "--quiet", "--no-apollo", "--no-picture"])
        shutil.copy(base / f"g{s}" / "map.json", base / f"m{s}.json")
    cmds = {
        "generate": lambda s, out: ["generate", "--seed", str(s), "--out", str(out), "--quiet", "--opendrive"],
        "generate-no-apollo": lambda s, out: ["generate", "--seed", str(s), "--out", str(out), "--quiet",
                                              "--no-apollo", "--no-picture"],
        "export-apollo": lambda s, out: ["export", "apollo", str(base / f"m{s}.json"), "--out", str(out)],
    }
    # (case, command before (seed 1) or None, command under test (seed 2))
    cases = [("generate over nothing", None, "generate"), ("generate over another seed", "generate", "generate"),
             ("generate --no-apollo over a full output", "generate", "generate-no-apollo"),
             ("export apollo over another seed", "export-apollo", "export-apollo")]
    refs, mutations, durations = {}, {}, {}
    for name, cmd in cmds.items():
        for s in (1, 2):
            out = base / f"ref-{name}-{s}"
            t0 = time.time()
            r = run(cmd(s, out))
            durations[name] = max(durations.get(name, 0.0), time.time() - t0)
            refs[(name, s)] = fingerprint(out)
            m = re.search(r"FEAT2MAP_CHANGES (\d+)", r.stderr)
            mutations[name] = int(m.group(1)) if m else 0
    counts = {"runs": 0, "half_written": 0, "mixed": 0, "orphans_after_next_run": 0, "stale_after_rerun": 0,
              "swept_points": 0, "random_time_runs": 0}
    examples: list[str] = []

    def trial(case: str, before: str | None, cmd: str, kill_at: int = 0, after_s: float | None = None) -> None:
        out = base / "out"
        shutil.rmtree(out, ignore_errors=True)
        prev = None
        if before is not None:
            run(cmds[before](1, out))
            prev = fingerprint(out)
        if after_s is None:
            run(cmds[cmd](2, out), kill_at=kill_at)
        else:
            proc = subprocess.Popen(py + cmds[cmd](2, out), env=env, cwd=base, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL)
            time.sleep(after_s)
            proc.kill()
            proc.wait()
        counts["runs"] += 1
        state = fingerprint(out)
        new = refs[(cmd, 2)]
        if state is not None and state != new and state != prev:
            if set(state) in (set(new), set(prev or {})):
                counts["mixed"] += 1
                kind = "mixed"
            else:
                counts["half_written"] += 1
                kind = "half-written"
            examples.append(f"{case}, killed at change {kill_at or f'{after_s:.2f} s'}: {kind}: "
                            f"{sorted(set(state) ^ set(new))[:5]}")
        run(cmds[cmd](2, out))  # the next complete run
        if fingerprint(out) != new:
            counts["stale_after_rerun"] += 1
            examples.append(f"{case}: the next run left {sorted(set(fingerprint(out)) ^ set(new))[:4]}")
        if any(p.name.startswith(".out.") for p in base.iterdir()):
            counts["orphans_after_next_run"] += 1
            examples.append(f"{case}: hidden leftovers {[p.name for p in base.iterdir() if p.name.startswith('.out.')][:3]}")
            for p in base.iterdir():
                if p.name.startswith(".out."):
                    shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink()

    for case, before, cmd in cases:
        total = mutations[cmd]
        points = list(range(1, total + 1))
        if args.kill_points and len(points) > args.kill_points:
            points = sorted(rng.sample(points, args.kill_points))
        for k in points:
            trial(case, before, cmd, kill_at=k)
            counts["swept_points"] += 1
    for _ in range(args.kills):
        case, before, cmd = rng.choice(cases)
        trial(case, before, cmd, after_s=rng.uniform(0.3, durations[cmd] * 1.05))
        counts["random_time_runs"] += 1
    counts["mutations_per_run"] = mutations
    counts["examples"] = examples[:10]
    return counts


# ------------------------------------------------------------------------------ invariants

def random_feature(rng, legs=(3, 8), min_sep=None, one_way=True, max_lanes=2):
    """(angles, control, crosswalk, road types, lanes) of a random junction."""
    import numpy as np

    from feat2map.config import GenerationConfig

    sep = min_sep if min_sep is not None else GenerationConfig().min_socket_separation_deg
    n = int(rng.integers(legs[0], legs[1] + 1))
    while True:
        a = np.sort(rng.uniform(-180, 180, n))
        if np.diff(np.append(a, a[0] + 360)).min() >= sep:
            break
    types = [str(rng.choice(["in-out", "in-out", "in", "out"])) if one_way else "in-out" for _ in range(n)]
    if "in-out" not in types and not ("in" in types and "out" in types):
        types[0] = "in-out"
    lanes = [int(rng.integers(1, max_lanes + 1)) for _ in range(n)]
    return ([float(x) for x in a], str(rng.choice(["bare", "signal", "stop"])), bool(rng.integers(2)), types, lanes)


def _invariant_job(kind: str, seed: int) -> tuple:
    """Build one random map; returns (kind, status, problems, validate_problems)."""
    import numpy as np

    import feat2map
    from feat2map.config import GenerationConfig
    from feat2map.errors import Feat2MapError
    from feat2map.invariants import check_map

    rng = np.random.default_rng([seed, 14])
    try:
        if kind == "space":
            counts = sorted(set(int(x) for x in rng.integers(3, 9, int(rng.integers(1, 4)))))
            ranges = {}
            for n in counts:
                step = 360.0 / n
                ranges[n] = tuple((i * step + c - s, i * step + c + s) for i, (c, s) in
                                  enumerate(zip(rng.uniform(-8, 8, n), rng.uniform(0, 10, n))))
            controls = tuple(rng.choice(["bare", "signal", "stop"], int(rng.integers(1, 4)), replace=False))
            space = feat2map.FeatureSpace(tuple(counts), controls, (True, False) if rng.integers(2) else (False,),
                                          ranges)
            m = feat2map.generate(space, seed=int(seed))
        elif kind == "features":
            feats = []
            for _ in range(int(rng.integers(1, 5))):
                a, c, x, t, ln = random_feature(rng)
                feats.append(feat2map.JunctionFeature.make(a, c, x, road_types=t, lanes=ln))
            m = feat2map.generate_from_features(feats, seed=int(seed), config=GenerationConfig(grid_gap=160.0))
        else:  # spec
            from feat2map.spec import build_spec, parse_spec

            junctions = []
            for _ in range(int(rng.integers(1, 4))):
                a, c, x, t, ln = random_feature(rng)
                junctions.append({"control": c, "crosswalk": x,
                                  "sockets": [{"angle": ang, "type": tt, "lanes": ll} for ang, tt, ll in zip(a, t, ln)]})
            spec = parse_spec({"version": 1, "config": {"grid_gap": 160.0}, "junctions": junctions}, f"spec{seed}")
            m = build_spec(spec, seed=int(seed))
    except Feat2MapError as exc:
        return kind, "refused", [str(exc)[:200]], None
    except Exception as exc:
        return kind, "traceback", [f"{type(exc).__name__}: {str(exc)[:200]}"], None
    problems = check_map(m)
    vp = None
    if problems:
        try:
            from feat2map.formats import write_map
            from feat2map.formats.apollo import validate_apollo

            with tempfile.TemporaryDirectory() as tmp:
                write_map(m, Path(tmp) / "a", "apollo")
                vp = len(validate_apollo(Path(tmp) / "a"))
        except Exception as exc:
            vp = f"{type(exc).__name__}"
    return kind, "built", problems[:5], vp


def section_invariants(args) -> dict:
    jobs = [(k, s) for s in range(args.seed * 100000, args.seed * 100000 + args.maps) for k in
            ("space", "features", "spec")][: args.maps]
    t0 = time.time()
    with mp.get_context("fork").Pool(args.workers) as pool:
        res = pool.starmap(_invariant_job, jobs, chunksize=4)
    counts: dict = {"maps_tried": len(res), "wall_s": 0.0}
    examples: dict[str, list] = {}
    for kind, status, problems, vp in res:
        c = counts.setdefault(kind, {"built": 0, "refused": 0, "traceback": 0, "violating": 0,
                                     "validate_missed": 0})
        c[status] += 1
        if status == "built" and problems:
            c["violating"] += 1
            examples.setdefault(kind, []).append(problems[0])
            if vp == 0:
                c["validate_missed"] += 1
        if status == "traceback":
            examples.setdefault(kind + " traceback", []).append(problems[0])
        if status == "refused":
            examples.setdefault(kind + " refused", []).append(problems[0])
    counts["violations"] = sum(counts[k]["violating"] for k in ("space", "features", "spec") if k in counts)
    counts["built"] = sum(counts[k]["built"] for k in ("space", "features", "spec") if k in counts)
    counts["wall_s"] = round(time.time() - t0, 1)
    counts["examples"] = {k: v[:4] for k, v in examples.items()}
    return counts


# ------------------------------------------------------------------------------ huge requests

def section_huge(work: Path, args) -> dict:
    h = work / "huge"
    h.mkdir()
    (h / "bomb.yaml").write_text(_alias_bomb())
    junctions = [{"sockets": [0, 90, 180]} for _ in range(100_000)]
    (h / "many.json").write_text(json.dumps({"version": 1, "junctions": junctions}))
    (h / "chain.yaml").write_text("chains:\n- start: {point: [0, 0], heading: 0}\n  roads:\n" + "".join(
        f"  - {{end: [{(k + 1) * 1e7}, 0], heading: 0}}\n" for k in range(20)))
    src = work / "src" / "map.xodr"
    if src.is_file():
        (h / "long.xodr").write_text(re.sub(r'(<road [^>]*length=")[^"]*"', r'\g<1>1e9"',
                                            re.sub(r'(<geometry [^>]*length=")[^"]*"', r'\g<1>1e9"',
                                                   src.read_text())))
    g = ["generate", "--no-picture", "--quiet", "--no-apollo"]
    cases = [("YAML alias bomb spec (419 B)", g + ["--spec", str(h / "bomb.yaml"), "--out", str(h / "o1")]),
             ("100,000-junction spec", g + ["--spec", str(h / "many.json"), "--out", str(h / "o2")]),
             ("--samples-per-combination 125000", g + ["--samples-per-combination", "125000", "--out", str(h / "o3")]),
             ("chain of 20 roads of 10,000 km", g + ["--spec", str(h / "chain.yaml"), "--out", str(h / "o4")]),
             ("OpenDRIVE length 1e9", ["extract", str(h / "long.xodr")]),
             ("--grid-gap 1e308", g + ["--grid-gap", "1e308", "--out", str(h / "o5")])]
    rows = []
    for label, argv in cases:
        t0 = time.time()
        proc = subprocess.Popen([sys.executable, "-m", "feat2map.cli", *argv], stdout=subprocess.DEVNULL, cwd=h,
                                stderr=subprocess.PIPE, preexec_fn=lambda: resource.setrlimit(
                                    resource.RLIMIT_AS, (MEM_LIMIT, MEM_LIMIT)))
        try:
            _, err = proc.communicate(timeout=args.huge_timeout)
            rc = proc.returncode
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
            rc = "timeout"
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        line = err.decode("utf-8", "replace").strip().splitlines()
        rows.append({"case": label, "rc": rc, "s": round(time.time() - t0, 1), "maxrss_mb_all_children":
                     round(ru.ru_maxrss / 1024), "error_chars": len(line[-1]) if line else 0,
                     "error": (line[-1][:160] if line else ""), "traceback": "Traceback" in err.decode("utf-8", "replace")})
    return {"cases": rows, "unbounded": sum(r["rc"] == "timeout" for r in rows),
            "tracebacks": sum(bool(r["traceback"]) for r in rows)}


# ------------------------------------------------------------------------------ planner bridge

BRIDGE_STEP_TIMEOUT_S = 2.0  # --planner-timeout of the bridge section's rollouts
BRIDGE_DURATION_S = 4.0  # simulated seconds of its scenario: a well-behaved planner's rollout ends soon
BRIDGE_CASE_TIMEOUT_S = 60.0  # a rollout running longer counts as a hang (and is killed)
BRIDGE_RSS_TARGET_MB = 300
HARNESS_TAG_VAR = "FEAT2MAP_HARNESS_TAG"  # in each rollout's environment, inherited by every planner process

# The planners' common part: speaks protocol min(the bridge's, 2), echoing "step" when sent.
PLANNER_PRELUDE = """\
import json, os, signal, sys, time
def send(m):
    sys.stdout.write(json.dumps(m) + "\\n"); sys.stdout.flush()
def recv():
    line = sys.stdin.readline()
    return json.loads(line) if line.strip() else {"type": "eof"}
def answer(req, m):
    if "step" in req:
        m = dict(m, step=req["step"])
    send(m)
def hello(req):
    answer(req, {"type": "hello", "protocol": min(req.get("protocol", 1), 2), "map_format": "native",
                 "output": "control"})
def start():
    hello(recv()); i = recv(); answer(i, {"type": "ready"})
STAND = {"type": "control", "acceleration": -8.0, "steering": 0.0}
def drive():
    while True:
        m = recv()
        if m["type"] in ("close", "eof"):
            answer(m, {"type": "bye"}); return
        answer(m, STAND)
"""

# (name, what the planner does, its code after PLANNER_PRELUDE, the outcome, text its message holds)
BRIDGE_CASES: list[tuple[str, str, str, str, str]] = [
    ("fork_keeps_stdout", "forks a child holding stdout, exits", """
start(); recv()
if os.fork() == 0:
    time.sleep(600); os._exit(0)
os._exit(0)
""", "error", "exited (code 0) before its step reply; a process it started holds its stdout"),
    ("setsid_keeps_stdout", "a setsid() child holds stdout, exits", """
start(); recv()
if os.fork() == 0:
    os.setsid(); time.sleep(600); os._exit(0)
os._exit(0)
""", "error", "exited (code 0) before its step reply; a process it started holds its stdout"),
    ("fork_at_init", "forks at init, drives, says bye, exits", """
hello(recv()); i = recv()
if os.fork() == 0:
    time.sleep(600); os._exit(0)
answer(i, {"type": "ready"}); drive()
""", "timeout", ""),
    ("double_fork_daemon", "a daemon (setsid, double fork, fds closed), then hangs", """
start(); recv()
if os.fork() == 0:
    os.setsid()
    if os.fork() == 0:
        os.closerange(0, 3); time.sleep(600)
    os._exit(0)
time.sleep(600)
""", "error", "no step reply within"),
    ("fork_bomb_lite", "12 sleeping processes, then hangs", """
start(); recv()
for _ in range(4):
    if os.fork() == 0:
        for _ in range(2):
            if os.fork() == 0:
                time.sleep(600); os._exit(0)
        time.sleep(600); os._exit(0)
time.sleep(600)
""", "error", "no step reply within"),
    ("never_reads_stdin", "answers each message without reading it (4 KiB pipe)", """
import fcntl, struct, termios
h = recv(); hello(h); answer(recv(), {"type": "ready"})
fcntl.fcntl(0, fcntl.F_SETPIPE_SZ, 4096)
seen, k = 0, 0
while True:
    n = struct.unpack("i", fcntl.ioctl(0, termios.FIONREAD, b"\\0" * 4))[0]
    if n > seen:
        seen = n; answer({"step": k} if "step" in h else {}, STAND); k += 1
    time.sleep(0.002)
""", "error", "does not read its stdin"),
    ("floods_replies", "valid replies in bursts of 50 (protocol 1: no step to tell them apart)", """
h = recv(); send({"type": "hello", "protocol": 1, "map_format": "native", "output": "control"})
recv(); send({"type": "ready"}); recv()
while True:  # bursts: a starved planner writing one line at a time keeps pace with the steps it is asked
    sys.stdout.write((json.dumps(STAND) + "\\n") * 50); sys.stdout.flush()
""", "error", "replies without being asked"),
    ("closes_stdout", "closes stdout, keeps running", """
start(); recv(); os.close(1); time.sleep(600)
""", "error", "closed its stdout while still running"),
    ("closes_stdin", "closes stdin, answers once, keeps running", """
start(); m = recv(); os.close(0); answer(m, STAND); time.sleep(600)
""", "error", "closed its stdin before its step reply"),
    ("deep_json", "JSON nested 100,000 deep", """
start(); recv(); sys.stdout.write("[" * 100000 + "]" * 100000 + "\\n"); sys.stdout.flush(); recv()
""", "error", "nested too deep"),
    ("int_400_digits", "a 400-digit acceleration", """
start(); answer(recv(), dict(STAND, acceleration=10 ** 400)); recv()
""", "error", "an integer of 401 digits"),
    ("float_1e308", "a trajectory at +-1e308", """
start(); answer(recv(), {"type": "trajectory", "points": [{"t": 0, "x": 1e308, "y": -1e308, "heading": 0,
                                                         "speed": 1e308}]}); recv()
""", "error", "a number out of range"),
    ("nan_points", "a trajectory of NaN", """
start(); answer(recv(), {"type": "trajectory", "points": [{"t": 0, "x": float("nan"), "y": 0, "heading": 0,
                                                         "speed": 0}]}); recv()
""", "error", "a non-finite number: NaN"),
    ("line_50mb", "a 50 MB line", """
start(); recv(); sys.stdout.write("x" * 50_000_000 + "\\n"); sys.stdout.flush(); recv()
""", "error", "a line over"),
    ("binary_garbage", "a line of binary bytes", """
start(); recv(); sys.stdout.buffer.write(bytes(range(256)).replace(b"\\n", b"") * 20 + b"\\n"); sys.stdout.flush()
recv()
""", "error", "garbage step reply"),
    ("empty_lines_only", "blank lines in a loop", """
start(); recv()
while True:
    sys.stdout.write("\\n" * 1000); sys.stdout.flush()
""", "error", "no step reply within"),
    ("stale_step", "answers step k as step k-1 (protocol 2)", """
start()
while True:
    m = recv()
    if m["type"] in ("close", "eof"):
        answer(m, {"type": "bye"}); break
    answer(dict(m, step=m["step"] - 1) if m.get("step", 0) > 0 else m, STAND)
""", "error", "step reply for step 0 at step 1"),
    ("duplicates_replies", "answers every step twice", """
start()
while True:
    m = recv()
    if m["type"] in ("close", "eof"):
        answer(m, {"type": "bye"}); break
    answer(m, STAND); answer(m, STAND)
""", "error", "step reply for step 0 at step 1"),
    ("future_step", "answers step k as step k+1 (protocol 2)", """
start()
while True:
    m = recv()
    if m["type"] in ("close", "eof"):
        answer(m, {"type": "bye"}); break
    answer(dict(m, step=m["step"] + 1) if "step" in m else m, STAND)
""", "error", "step reply for step 1 at step 0"),
    ("drops_step_v2", "speaks protocol 2 without echoing step", """
start(); send(STAND); recv()
""", "error", "step reply without its 'step'"),
    ("replies_before_hello", "a control before the hello", """
send(STAND); start(); drive()
""", "error", "bad hello: expected a hello"),
    ("late_replies", "answers each step after the deadline", """
start()
while True:
    m = recv(); time.sleep(3.0); answer(m, STAND)
""", "error", "no step reply within"),
    ("sleeps_after_ready", "ready, then sleeps forever", """
start(); time.sleep(600)
""", "error", "no step reply within"),
    ("exits_at_once", "exits before its hello", """
sys.exit(0)
""", "error", "exited (code 0) before its hello reply"),
    ("crashes_mid_run", "SIGSEGV at its 4th step", """
import resource
resource.setrlimit(resource.RLIMIT_CORE, (0, 0)); start()
for _ in range(3):
    answer(recv(), STAND)
recv(); os.kill(os.getpid(), signal.SIGSEGV)
""", "error", "was killed by SIGSEGV before its step reply"),
    ("stderr_100mb", "100 MB of stderr lines, then exit 1", """
start(); recv()
for _ in range(1000):
    sys.stderr.write("e" * 99_999 + "\\n")
sys.stderr.flush(); sys.exit(1)
""", "error", "exited (code 1) before its step reply; planner stderr: eeee"),
    ("stderr_no_newline", "10 MB of stderr in one line, then hangs", """
start(); recv(); sys.stderr.write("x" * 10_000_000); sys.stderr.flush(); time.sleep(600)
""", "error", "no step reply within 2 s; planner stderr: xxxx"),
    ("ignores_sigterm", "ignores SIGTERM, lingers after its bye", """
signal.signal(signal.SIGTERM, signal.SIG_IGN); start(); drive(); time.sleep(600)
""", "timeout", ""),
]


def tagged_processes(tag: str, var: str = HARNESS_TAG_VAR) -> list[int]:
    """Live processes whose environment holds `var`=`tag` (Linux /proc)."""
    marker = f"{var}={tag}".encode()
    found = []
    for name in os.listdir("/proc"):
        if not name.isdigit() or int(name) == os.getpid():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as f:
                if f.read().rsplit(b")", 1)[1].split()[0] in (b"Z", b"X"):
                    continue
            with open(f"/proc/{name}/environ", "rb") as f:
                if marker in f.read().split(b"\0"):
                    found.append(int(name))
        except (OSError, IndexError):
            continue
    return found


def bridge_suite(work: Path) -> Path:
    """A one-scenario suite (a signalled T junction, no traffic) of BRIDGE_DURATION_S."""
    import feat2map
    from feat2map import cli
    from feat2map.formats import native
    from feat2map.scenarios.scenario import Suite, load_suite, save_suite

    work.mkdir(parents=True, exist_ok=True)
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180], "signal", False)], seed=0)
    native.save(m, work / "t.json")
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli.main(["suite", str(work / "t.json"), "--out", str(work / "all.yaml"),
                         "--duration", str(BRIDGE_DURATION_S)]) == 0
    suite = load_suite(work / "all.yaml")
    save_suite(Suite("abuse", suite.scenarios[:1], suite.base_dir), work / "one.yaml")
    return work / "one.yaml"


_ROLLOUT = """\
import importlib.util, json, resource, sys
argv, result, bridge = json.loads(sys.argv[1]), sys.argv[2], sys.argv[3]
if bridge:  # another bridge.py in place of feat2map.scenarios.bridge (e.g. main's, for a before/after)
    spec = importlib.util.spec_from_file_location("feat2map.scenarios.bridge", bridge)
    mod = importlib.util.module_from_spec(spec); sys.modules[spec.name] = mod; spec.loader.exec_module(mod)
from feat2map import cli
rc = cli.main(argv)
with open(result, "w") as f:
    json.dump({"rc": rc, "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}, f)
"""


def section_bridge(work: Path, args) -> dict:
    """Issue 33: abusive planners through the planner bridge, each in a rollout of its own
    (`feat2map rollout --planner-cmd`, --planner-timeout BRIDGE_STEP_TIMEOUT_S): its outcome and
    message, whether the report was written, wall time, the rollout's peak RSS, and the planner's
    processes alive after the rollout (found by an environment tag, then killed). Targets: no
    hang, a report each time, RSS under BRIDGE_RSS_TARGET_MB, no survivor."""
    from feat2map.scenarios.rollout import HASH_SEED

    bw = work / "bridge"
    suite = bridge_suite(bw)
    names = set(args.bridge_cases.split(",")) if args.bridge_cases else None
    rows = []
    for name, what, body, want_outcome, want_text in BRIDGE_CASES:
        if names is not None and name not in names:
            continue
        script = bw / f"{name}.py"
        script.write_text(PLANNER_PRELUDE + body)
        out, result = bw / f"out-{name}", bw / f"{name}.json"
        tag = f"{name}-{os.getpid()}-{time.time_ns()}"
        argv = ["rollout", str(suite), "--planner-cmd", f"{sys.executable} {script}", "--planner-timeout",
                str(BRIDGE_STEP_TIMEOUT_S), "--out", str(out), "--quiet", "--no-gif", "--no-coverage"]
        t0 = time.time()
        proc = subprocess.Popen([sys.executable, "-c", _ROLLOUT, json.dumps(argv), str(result), args.bridge_module or ""],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True,
                                env=dict(os.environ, SDL_VIDEODRIVER="offscreen", MPLBACKEND="Agg",
                                         PYTHONHASHSEED=HASH_SEED,  # the rollout drives in its own process
                                         **{HARNESS_TAG_VAR: tag}))
        try:
            _, err = proc.communicate(timeout=args.bridge_timeout)
            hang = False
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            _, err = proc.communicate()
            hang = True
        wall = time.time() - t0
        time.sleep(0.5)  # let killed processes finish dying
        survivors = tagged_processes(tag)
        for pid in survivors:
            with contextlib.suppress(OSError):
                os.kill(pid, 9)
        res = json.loads(result.read_text()) if result.is_file() else {}
        summary = out / "summary.json"
        o = json.loads(summary.read_text())["outcomes"][0] if summary.is_file() else {}
        outcome, message = o.get("outcome", "hang" if hang else "none"), o.get("message", "")
        rows.append({"case": name, "planner": what, "outcome": outcome, "message": message[:200],
                     "as_expected": outcome == want_outcome and want_text in message, "report": summary.is_file(),
                     "s": round(wall, 1), "rss_mb": round(res["maxrss_mb"], 1) if res else None,
                     "survivors": len(survivors), "hang": hang,
                     "traceback": "Traceback" in err.decode("utf-8", "replace")})
        print(f"   {name:<22} {outcome:<8} report={summary.is_file()!s:<5} {wall:5.1f} s "
              f"rss={rows[-1]['rss_mb']} MB survivors={len(survivors)} {message[:90]}", flush=True)
    rss = [r["rss_mb"] for r in rows if r["rss_mb"] is not None]
    return {"cases": rows, "hangs": sum(r["hang"] for r in rows), "no_report": sum(not r["report"] for r in rows),
            "max_rss_mb": max(rss, default=None), "over_rss_target": sum(x > BRIDGE_RSS_TARGET_MB for x in rss),
            "survivors": sum(r["survivors"] for r in rows), "unexpected": [r["case"] for r in rows
                                                                          if not r["as_expected"]],
            "max_s": max((r["s"] for r in rows), default=0.0)}


# ------------------------------------------------------------------------------ main

def _cli(argv: list[str], cwd: Path | None = None, timeout: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "feat2map.cli", *argv], capture_output=True, text=True, errors="replace",
                          cwd=cwd, timeout=timeout, env=dict(os.environ, SDL_VIDEODRIVER="offscreen", MPLBACKEND="Agg"))


def section_rough(work: Path, args) -> dict:
    """Issue 25's rough edges, each a pass/fail case: exports must not write what validate
    rejects; messages name the culprit (file, option, command); no traceback on a non-UTF-8
    file name; output folders recognised by our manifest, not by a name; a non-terminal stderr
    gets no progress frames or numpy notes; suites by suffix; `pip check` clean."""
    rw = work / "rough"
    rw.mkdir()
    m = rw / "g"
    assert _cli(["generate", "--seed", "3", "--out", str(m), "--no-picture", "--opendrive"]).returncode == 0
    doc = json.loads((m / "map.json").read_text())
    cases: dict[str, tuple[bool, str]] = {}

    def native(name: str, edit) -> Path:
        d = json.loads(json.dumps(doc))
        edit(d)
        path = rw / f"{name}.json"
        path.write_text(json.dumps(d))
        return path

    def junction_cycle(d):
        a, b = [ln for ln in d["lanes"] if ln.get("junction_id")][:2]
        a["successors"], b["predecessors"], b["successors"], a["predecessors"] = [b["id"]], [a["id"]], [a["id"]], [b["id"]]

    def self_link(d):
        ln = d["lanes"][0]
        ln["successors"] = ln["successors"] + [ln["id"]]

    def zero_length(d):
        ln = [x for x in d["lanes"] if not x.get("junction_id")][3]
        for key in ("centerline", "left_boundary", "right_boundary"):
            ln[key] = [ln[key][0]] * 2
        d["meta"].pop("generator", None)

    xodr = (m / "map.xodr").read_text()
    k = iter(range(10**6))
    missing = rw / "missing.xodr"
    missing.write_text(re.sub(r'(elementType="road" elementId=")[^"]*(")',
                              lambda mm: mm.group(1) + "9999" + mm.group(2) if next(k) < 24 else mm.group(0), xodr))
    connections = rw / "connections.xodr"
    connections.write_text(re.sub(r'(incomingRoad=")[^"]*(")', r"\g<1>8888\2", xodr, count=24))
    for name, src in [("junction-lane cycle", native("cycle", junction_cycle)),
                      ("self-link", native("self", self_link)),
                      ("zero-length lane", native("zero", zero_length)),
                      (".xodr links to a missing road", missing),
                      (".xodr connections of a missing road", connections)]:
        out = rw / f"apollo-{name.replace(' ', '_')}"
        r = _cli(["export", "apollo", str(src), "--out", str(out)])
        if r.returncode != 0:
            errors = [ln for ln in r.stderr.splitlines() if ln.startswith("feat2map: error:")]  # after any warnings
            ok = len(errors) == 1 and not out.exists()
            cases[f"export {name}"] = (ok, f"refused: {(errors or [r.stderr])[0][:160]}")
        else:
            v = _cli(["validate", str(out), "--quiet"])
            cases[f"export {name}"] = (v.returncode == 0, f"written; validate: {v.stdout.strip().splitlines()[-1]}")

    def err_has(argv, *texts, code=2, cwd=None):
        r = _cli(argv, cwd=cwd)
        line = r.stderr.strip()
        return (r.returncode == code and len(line.splitlines()) == 1 and all(t in line for t in texts), line[:200])

    (rw / "big.yaml").write_text("config: {samples_per_combination: 1000000}\njunctions:\n"
                                 "  - sockets: [{angle: 0}, {angle: 90}, {angle: 180}]\n")
    (rw / "notes.txt").write_text("hello, these are my notes\n")
    (rw / "bad.xodr").write_text('<OpenDRIVE><header/><road id="1"\n')
    o = str(rw / "o")
    cases["spec config over a limit names the file"] = err_has(["generate", "--spec", str(rw / "big.yaml"), "--out", o],
                                                               f"{rw / 'big.yaml'}: config")
    cases["--origin 1e300 names the option"] = err_has(["export", "apollo", str(m / "map.json"), "--origin", "1e300",
                                                        "1e300", "--out", o], "--origin:")
    cases["--grid-gap -5 names the option"] = err_has(["generate", "--grid-gap", "-5", "--out", o], "--grid-gap must")
    cases["--sed: command and did you mean"] = err_has(["generate", "--sed", "2", "--out", o],
                                                       "feat2map generate: error", "did you mean --seed?")
    cases["plain text to extract not blamed on Apollo"] = err_has(["extract", str(rw / "notes.txt")],
                                                                  "not a map feat2map reads")
    r = _cli(["extract", str(rw / "bad.xodr")])
    cases[".xodr parse error gives its position once"] = (r.stderr.count("line 2") == 1, r.stderr.strip()[:200])
    from feat2map.envs.config import SCHEMA, unknown_key_message

    hint = unknown_key_message("lanes_cont", SCHEMA)
    cases["env key lanes_cont gets a hint"] = ("lanes_count" in hint, hint[:200])
    odd = rw / b"ma\xffp".decode("utf-8", "surrogateescape")
    _cli(["export", "apollo", str(m / "map.json"), "--out", str(odd)])
    r = _cli(["validate", str(odd), "--picture", str(rw / "p.png"), "--quiet"])
    cases["non-UTF-8 name with validate --picture"] = (r.returncode == 0 and "Traceback" not in r.stderr,
                                                       r.stderr.strip()[-200:])
    d = rw / "mine"
    d.mkdir()
    (d / "map.json").mkdir()
    (d / "thesis.tex").write_text("precious")
    r = _cli(["generate", "--out", str(d), "--no-picture", "--no-apollo"])
    cases["folder named map.json inside a user's folder"] = (r.returncode == 2 and (d / "thesis.tex").exists(),
                                                            r.stderr.strip()[:200])
    r1 = _cli(["generate", "--seed", "4", "--out", str(rw / "g4")])
    r2 = _cli(["validate", str(rw / "g4" / "apollo")])
    cases["non-terminal stderr: no bars or numpy notes"] = (r1.stderr == "" and r2.stderr == "",
                                                             (r1.stderr + r2.stderr)[:200])
    r = _cli(["extract", str(m / "map.json"), "--out", str(rw / "f.json")])
    cases["extract --out prints no JSON"] = ("{" not in r.stdout, r.stdout[-200:])
    cases["suite --out s.txt refused"] = err_has(["suite", str(m / "map.json"), "--out", str(rw / "s.txt")],
                                                 ".yaml, .yml) or JSON")
    r = _cli(["export", "opendrive", str(m / "map.json"), "--odr-version", "1.7", "--out", str(rw / "m17.xodr")])
    cases["--odr-version 1.7 reported as 1.7"] = ("OpenDRIVE 1.7" in r.stdout, r.stdout.strip()[:200])
    r = _cli(["--help"])
    cases["--help limits as integers"] = ("e+0" not in r.stdout, "")
    cases.update(_rough_outputs(rw, m))
    cases.update(_rough_envs())
    r = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True, timeout=120)
    cases["pip check"] = (r.returncode == 0, r.stdout.strip()[:200])
    failed = [name for name, (ok, _) in cases.items() if not ok]
    return {"cases": len(cases), "failed": len(failed),
            "results": {name: ("ok" if ok else "FAIL") + (f": {detail}" if detail else "")
                        for name, (ok, detail) in cases.items()}}


def _rough_outputs(rw: Path, m: Path) -> dict[str, tuple[bool, str]]:
    """Issue 35's output-folder and error-place cases, each pass/fail: errors name --out, never
    the staging folder nor the file's content; a user's empty folder in an earlier output is
    kept (refused); --out LINK leaves no stray link; a user's map_projector_info.yaml is kept."""
    cases: dict[str, tuple[bool, str]] = {}
    ring = rw / "ring.yaml"  # a two-way closed ring: two loops, Apollo's routing graph is refused
    pts = [(0, 40, 180), (-40, 0, 270), (0, -40, 0), (40, 0, 90)]
    ring.write_text("version: 1\nchains:\n  - name: ring\n    lanes_forward: 1\n    lanes_backward: 1\n"
                    "    start: {point: [40, 0], heading: 90}\n    roads:\n"
                    + "".join(f"      - {{end: [{x}, {y}], heading: {h}}}\n" for x, y, h in pts))
    r = _cli(["generate", "--spec", str(ring), "--out", str(rw / "ring"), "--no-picture", "--quiet"])
    cases["refused Apollo export in generate names --out, not staging"] = (
        r.returncode == 2 and f"{rw / 'ring' / 'apollo'}: refusing" in r.stderr and ".stage-" not in r.stderr,
        r.stderr.strip()[:200])
    notes = rw / "secret.txt"
    notes.write_text("my password is hunter2\n")
    r = _cli(["extract", str(notes)])
    cases["non-map .txt: named, content not quoted"] = (r.returncode == 2 and str(notes) in r.stderr
                                                        and "hunter2" not in r.stderr, r.stderr.strip()[:200])
    out = rw / "g_empty"
    g = ["generate", "--no-picture", "--quiet", "--out", str(out)]
    _cli(g)
    (out / "apollo" / "mine").mkdir()
    r = _cli(g + ["--seed", "2"])
    cases["user's empty folder in an earlier output kept (refused)"] = (
        r.returncode == 2 and (out / "apollo" / "mine").is_dir() and "apollo/mine/" in r.stderr, r.stderr.strip()[:200])
    (rw / "target").mkdir()
    (rw / "link").symlink_to(rw / "target")
    r1 = _cli(["generate", "--no-picture", "--quiet", "--no-apollo", "--out", str(rw / "link")])
    stray = [p.name for p in rw.iterdir() if p.name.startswith(".link.")]
    cases["--out LINK: written through, no stray staging link"] = (
        r1.returncode == 0 and (rw / "link").is_symlink() and (rw / "target" / "map.json").is_file() and not stray,
        (r1.stderr.strip() or ", ".join(stray))[:200])
    (rw / "ll2").mkdir()
    info = rw / "ll2" / "map_projector_info.yaml"
    info.write_text("projector_type: MGRS\nmgrs_grid: 54SUE\n")
    r = _cli(["export", "lanelet2", str(m / "map.json"), "--out", str(rw / "ll2" / "x.osm")])
    cases["export lanelet2 keeps a user's map_projector_info.yaml"] = (
        r.returncode == 2 and "MGRS" in info.read_text() and not (rw / "ll2" / "x.osm").exists(), r.stderr.strip()[:200])
    return cases


def _rough_envs() -> dict[str, tuple[bool, str]]:
    """Issue 35's env cases, each pass/fail: a bad batch action (short, long, out of the space)
    and a PettingZoo agent's NaN action are ValueErrors raised before any state changes (the
    next step equals a twin's that never saw them); non-dict options and actions are ValueErrors."""
    import gymnasium as gym
    import numpy as np
    from gymnasium.utils.env_checker import data_equivalence

    import feat2map
    from feat2map.envs import parallel_env

    cases: dict[str, tuple[bool, str]] = {}
    J = feat2map.JunctionFeature.make
    cfg = {"features": [J([0, 90, 180], "signal", True).to_dict()], "traffic_vehicles": 3, "route_junctions": 1,
           "duration": 2.5, "policy_frequency": 2}

    def refused(call) -> str:
        try:
            call()
        except ValueError as exc:
            return str(exc)
        except Exception as exc:  # noqa: BLE001 - the wrong type is what this counts
            return f"WRONG TYPE {type(exc).__name__}: {exc}"
        return "ACCEPTED"

    def same(a, b) -> bool:
        return all(np.array_equal(x, y) for x, y in zip(a[:4], b[:4]))

    for label, bad in [("one short", [0, 1, 2]), ("one long", [0, 1, 2, 1, 1]), ("out of space", [0, 1, 2, 99])]:
        envs, twin = (gym.make_vec("feat2map/JunctionGrid-v0", num_envs=4, config=cfg) for _ in range(2))
        envs.reset(seed=3)
        twin.reset(seed=3)
        msg = refused(lambda envs=envs, bad=bad: envs.step(np.array(bad)))
        good = np.array([1, 2, 0, 1])
        ok = not msg.startswith(("WRONG", "ACCEPTED")) and all(same(envs.step(good), twin.step(good)) for _ in range(6))
        cases[f"vector env: batch action {label} refused, no sub-env changed"] = (ok, msg[:200])
    env, twin = (parallel_env({"features": cfg["features"], "agents": 3, "traffic_vehicles": 0,
                               "action": {"type": "ContinuousAction"}}) for _ in range(2))
    env.reset(seed=0)
    twin.reset(seed=0)
    a0, a1 = env.agents[:2]
    msg = refused(lambda: env.step({a0: np.array([1.0], np.float32), a1: np.array([np.nan], np.float32)}))
    ok = not msg.startswith(("WRONG", "ACCEPTED"))
    for _ in range(4):  # a0 holds its decision: the refused step's must not have been taken
        acts = {a: np.array([0.2], np.float32) for a in env.agents if a != a0}
        ok = ok and data_equivalence(env.step(acts), twin.step(acts))
    cases["PettingZoo: a NaN action refused before any agent's decision"] = (ok, msg[:200])
    msg = refused(lambda: env.step([0, 1]))
    cases["PettingZoo: actions not a dict -> ValueError"] = (not msg.startswith(("WRONG", "ACCEPTED")), msg[:200])
    single = gym.make("feat2map/JunctionGrid-v0", config=cfg)
    vec = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, config=cfg)
    for name, e in (("single", single), ("vector", vec), ("PettingZoo", env)):
        msg = refused(lambda e=e: e.reset(seed=0, options="config"))
        cases[f"{name} env: reset(options='config') -> ValueError"] = (not msg.startswith(("WRONG", "ACCEPTED")),
                                                                       msg[:200])
    return cases


REPORT_ATTACKS = {
    "script tag": "<script>alert(1)</script>",
    "event handler": '<img src=x onerror="alert(1)"><b onmouseover=alert(1)>b</b>',
    "javascript: link": "[go](javascript:alert(1)) <javascript:alert(1)>",
    "raw HTML block": '\n<div onclick="alert(1)">\n<iframe src="javascript:alert(1)"></iframe>\n</div>\n',
    "image of a local file": "![x]({secret})",
    "image of ../": "![x](../secret.txt)",
    "link to a local file": "[x]({secret})",
    "fence breakout": "\n```\n</pre><script>alert(1)</script>\n```\n",
}


def _report_problems(page: str, secret: bytes) -> list[str]:
    """What in a report.html could run, load or leak: [] for a clean page."""
    import base64

    import lxml.html

    problems = [p for p, bad in (("<script", "<script" in page.lower()), ("secret bytes", secret.decode() in page),
                                 ("secret base64", base64.b64encode(secret).decode() in page)) if bad]
    doc = lxml.html.document_fromstring(page)
    csp = doc.xpath("//head/meta[@http-equiv='Content-Security-Policy']/@content")
    if not csp or not csp[0].startswith("default-src 'none'; img-src data:;") or "script-src" in csp[0]:
        problems.append(f"CSP {csp}")
    problems += [f"<{el.tag}>" for el in doc.xpath("//script|//iframe|//object|//embed|//base|//form|//body//style")]
    for el in doc.iter():
        for name, value in (el.attrib.items() if isinstance(el.tag, str) else ()):
            if name.lower().startswith("on") or "javascript:" in value.lower():
                problems.append(f"<{el.tag} {name}={value[:40]!r}>")
            elif name == "src" and not value.startswith(("data:image/png;base64,", "data:image/gif;base64,")):
                problems.append(f"<{el.tag} src={value[:60]!r}>")
            elif name == "href":
                problems.append(f"<{el.tag} href={value[:60]!r}>")
    return problems


def section_report(work: Path, args) -> dict:
    """Issue 35: attacks planted in a rollout's names, stage names and planner stderr reach
    neither report.html (parsed, every element and attribute) nor report.md as markup."""
    from feat2map.scenarios.report import report_html, report_markdown, write_report
    from feat2map.scenarios.rollout import Outcome, SuiteResult

    rw = work / "report"
    rw.mkdir()
    secret = b"HARNESS-SECRET-35 token=hunter2"
    (rw / "secret.txt").write_bytes(secret)
    cases: dict[str, tuple[bool, str]] = {}
    for label, attack in REPORT_ATTACKS.items():
        a = attack.format(secret=rw / "secret.txt")
        for where in ("suite name", "scenario name", "stage name", "planner stderr"):
            o = Outcome(f"sc {a}" if where == "scenario name" else "sc", "error", {}, 1.0, 5,
                        ("LF", a) if where == "stage name" else ("LF",), (), ("J0",), 0.5,
                        message=f"planner stderr:\n{a}" if where == "planner stderr" else "raised")
            result = SuiteResult(f"s {a}" if where == "suite name" else "s", "baseline", (o,))
            out = write_report(result, rw / f"r-{len(cases)}")
            problems = _report_problems((out / "report.html").read_text(), secret)
            md = re.sub(r"(?ms)^(`{3,})$.*?^\1$", "", report_markdown(result, "any", {}))  # outside code blocks
            problems += [f"report.md {t}" for t in ("<script", "<img", "<div", "](javascript", f"]({rw}", "](../")
                         if t in md.replace("\\]", "")]
            cases[f"{label} in the {where}"] = (not problems, "; ".join(problems)[:200])
    folder = rw / "raw"
    folder.mkdir()
    (folder / "link.png").symlink_to(rw / "secret.txt")
    md = "\n\n".join(v.format(secret=rw / "secret.txt") for v in REPORT_ATTACKS.values()) + "\n\n![l](link.png)"
    page = report_html(md, folder, "t", {"link.png", str(rw / "secret.txt"), "../secret.txt"})
    problems = _report_problems(page, secret)
    cases["raw Markdown attacks and a symlink out, given to report_html"] = (not problems, "; ".join(problems)[:200])
    failed = [name for name, (ok, _) in cases.items() if not ok]
    return {"cases": len(cases), "failed": len(failed),
            "results": {name: ("ok" if ok else "FAIL") + (f": {detail}" if detail else "")
                        for name, (ok, detail) in cases.items()}}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="small numbers everywhere (a smoke run)")
    p.add_argument("--sections", default="corpus,kill,invariants,huge,rough,bridge,report")
    p.add_argument("--seed", type=int, default=14)
    p.add_argument("--trunc", type=int, default=12, help="truncations per seed file")
    p.add_argument("--flips", type=int, default=12, help="bit-flip variants per seed file")
    p.add_argument("--kills", type=int, default=20, help="SIGKILL runs at random moments")
    p.add_argument("--kill-points", type=int, default=40,
                   help="filesystem changes to kill at per case (0: every one)")
    p.add_argument("--maps", type=int, default=1050, help="random maps for the invariant section")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--huge-timeout", type=float, default=120.0, help="seconds before a huge request counts unbounded")
    p.add_argument("--bridge-cases", help="bridge section: only these cases (comma-separated names)")
    p.add_argument("--bridge-module", help="bridge section: drive through this bridge.py instead of feat2map's "
                   "(e.g. an older one, for a before/after)")
    p.add_argument("--bridge-timeout", type=float, default=BRIDGE_CASE_TIMEOUT_S,
                   help="bridge section: seconds before a rollout counts as a hang")
    p.add_argument("--json", help="write the counts here too")
    args = p.parse_args()
    if args.quick:
        args.trunc, args.flips, args.kills, args.kill_points, args.maps, args.huge_timeout = 2, 2, 2, 4, 30, 30.0
    sections = args.sections.split(",")
    report: dict = {"python": sys.executable}
    import feat2map

    report["feat2map"] = str(Path(feat2map.__file__).parent)
    with tempfile.TemporaryDirectory(prefix="harden-") as tmp:
        work = Path(tmp)
        for name in ("corpus", "kill", "invariants", "huge", "rough", "bridge", "report"):
            if name not in sections:
                continue
            t0 = time.time()
            print(f"== {name}", flush=True)
            if name == "corpus":
                report[name] = section_corpus(work, args)
            elif name == "kill":
                report[name] = section_kill(work, args)
            elif name == "invariants":
                report[name] = section_invariants(args)
            elif name == "rough":
                report[name] = section_rough(work, args)
            elif name == "bridge":
                report[name] = section_bridge(work, args)
            elif name == "report":
                report[name] = section_report(work, args)
            else:
                if "corpus" not in sections:
                    (work / "src").mkdir(exist_ok=True)
                    import feat2map as f2m
                    from feat2map.formats import write_map

                    write_map(f2m.generate(f2m.PAPER_SF_FEATURE_SPACE, seed=1), work / "src" / "map.xodr", "opendrive")
                report[name] = section_huge(work, args)
            print(json.dumps({k: v for k, v in report[name].items() if k != "all_examples"}, indent=1), flush=True)
            print(f"   ({time.time() - t0:.0f} s)", flush=True)
    summary = {}
    if "corpus" in report:
        c = report["corpus"]
        summary.update({"corrupt inputs": c["inputs"], "CLI runs": c["runs"], "tracebacks": c["tracebacks"],
                        "timeouts": c["timeouts"], "non-finite written (exit 0)": c["exit0_nonfinite"],
                        "bad command lines accepted": c["accepted_bad_cli"],
                        "invalid values accepted (exit 0, no warning)": f"{c['exit0_invalid']} of {c['value_mutations']}",
                        "invalid values accepted with a warning": c["exit0_invalid_warned"],
                        "error lines > cap": c["long_error_lines"],
                        "leaks": c["leaks"]})
    if "kill" in report:
        k = report["kill"]
        summary.update({"SIGKILL runs": k["runs"], "half-written folders": k["half_written"],
                        "mixed folders": k["mixed"], "orphaned staging after next run": k["orphans_after_next_run"],
                        "stale files after rerun": k["stale_after_rerun"]})
    if "invariants" in report:
        i = report["invariants"]
        summary.update({"random maps tried": i["maps_tried"], "maps built": i["built"],
                        "maps violating check_map": i["violations"],
                        "invariant-run tracebacks": sum(i[k]["traceback"] for k in ("space", "features", "spec")
                                                        if k in i)})
    if "huge" in report:
        summary.update({"huge requests unbounded": report["huge"]["unbounded"],
                        "huge requests max s": max(r["s"] for r in report["huge"]["cases"])})
    if "rough" in report:
        summary["rough edges (issues 25, 35) failing"] = f"{report['rough']['failed']} of {report['rough']['cases']}"
    if "bridge" in report:
        b = report["bridge"]
        summary.update({"abusive planners": len(b["cases"]), "bridge hangs": b["hangs"],
                        "bridge rollouts without a report": b["no_report"],
                        f"bridge peak RSS MB (target < {BRIDGE_RSS_TARGET_MB})": b["max_rss_mb"],
                        "bridge surviving processes": b["survivors"],
                        "bridge outcomes not as expected": ", ".join(b["unexpected"]) or 0})
    if "report" in report:
        summary["report injection (issue 35) failing"] = f"{report['report']['failed']} of {report['report']['cases']}"
    report["summary"] = summary
    print("\n== summary")
    for k, v in summary.items():
        print(f"{k:<40} {v}")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
