"""Kill a `feat2map` command at a chosen moment: right before its k-th filesystem change
(rename, replace, unlink, rmdir, mkdir, rmtree, folder swap). Used by test_atomic and by
scripts/harden_harness.py to check that outputs are never half-written or mixed."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

RUNNER = """
import os, shutil, sys
at = int(os.environ.get("FEAT2MAP_KILL_AT", "0"))
count = [0]
def hook(fn):
    def wrapped(*a, **k):
        count[0] += 1
        if count[0] == at:
            os.kill(os.getpid(), 9)
        return fn(*a, **k)
    return wrapped
for name in ("rename", "replace", "unlink", "rmdir", "mkdir"):
    setattr(os, name, hook(getattr(os, name)))
shutil.rmtree = hook(shutil.rmtree)
import feat2map.atomic as atomic
if hasattr(atomic, "_exchange"):
    atomic._exchange = hook(atomic._exchange)
from feat2map.cli import main
rc = main(sys.argv[1:])
sys.stderr.write(f"FEAT2MAP_CHANGES {count[0]}\\n")
sys.exit(rc)
"""
_DATE = re.compile(rb"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d")


def run(argv: list[str], kill_at: int = 0, cwd: Path | None = None, timeout: float = 600) -> tuple[int, int]:
    """Run `feat2map ARGV` in a subprocess killed before its `kill_at`-th filesystem change
    (0: never); returns (exit code, changes made: counted only when it ran to the end)."""
    env = dict(os.environ, FEAT2MAP_KILL_AT=str(kill_at), SDL_VIDEODRIVER="offscreen", MPLBACKEND="Agg")
    r = subprocess.run([sys.executable, "-c", RUNNER, *argv], env=env, cwd=cwd, timeout=timeout,
                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    m = re.search(r"FEAT2MAP_CHANGES (\d+)", r.stderr)
    return r.returncode, int(m.group(1)) if m else 0


def fingerprint(folder: Path) -> dict[str, bytes] | None:
    """Relative path -> content (export dates blanked) of every file under `folder`; None if absent."""
    if not folder.is_dir():
        return None
    return {str(f.relative_to(folder)): _DATE.sub(b"0000-00-00T00:00:00", f.read_bytes())
            for f in sorted(folder.rglob("*")) if f.is_file()}
