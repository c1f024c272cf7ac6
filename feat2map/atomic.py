"""Atomic outputs: a file or a whole folder appears complete or not at all.

Files are written to a hidden sibling and renamed into place. A folder output is built
complete in a hidden sibling staging folder (`staged_dir`) and then swapped in with one
rename (Linux: renameat2 RENAME_EXCHANGE, so the old folder stays whole until the new one
takes its place; elsewhere two renames, between which the folder is briefly absent). A run
killed at any moment therefore leaves the old folder, the new one, or (only without
RENAME_EXCHANGE) none; never a half-written or mixed one. Its hidden leftovers
(`.NAME.<kind>-<pid>-...`) are removed by the next run that writes NAME, once their process is gone.

Every folder output carries a manifest, `MANIFEST` (a hidden file listing each file the run
wrote). An existing non-empty output folder is replaced as a whole only when its manifest is
a regular file, every file in the folder is listed in it (nothing the user added since) and
one of the caller's marker files is listed (a previous output of the same command); any other
folder is refused before any work is done (`check_dir_target`), so `--out ~` never deletes a
home directory, and neither does a folder that merely holds something named like our outputs.
"""
from __future__ import annotations

import contextlib
import ctypes
import errno
import fnmatch
import json
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Iterator, Sequence

from .errors import Feat2MapError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_FILE_MODE = 0o666 & ~_umask()
_DIR_MODE = 0o777 & ~_umask()
_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?:tmp|stage|old)-(?P<pid>\d+)-[^.]+$")
_RENAME_EXCHANGE = 2
MANIFEST = ".feat2map-output.json"  # in every folder staged_dir writes: the files it holds
_AT_FDCWD = -100


def _prefix(path: Path, kind: str) -> str:
    return f".{path.name}.{kind}-{os.getpid()}-"


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_leftovers(path: str | Path) -> list[Path]:
    """Remove the hidden staging siblings of `path` left by killed runs (their process is gone)."""
    path = Path(path)
    removed: list[Path] = []
    try:
        entries = list(path.parent.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = _LEFTOVER.match(p.name)
        if m is None or m["name"] != path.name or _alive(int(m["pid"])):
            continue
        with contextlib.suppress(OSError):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p)
    return removed


def output_path(path: str | Path, what: str = "--out") -> Path:
    """A named output path (an empty string or '.' is an error, not the current folder)."""
    p = Path(path)
    if not str(path).strip() or p.name in ("", ".", ".."):
        raise Feat2MapError(f"needs a file or folder name, got {str(path)!r}", what)
    return p


def check_file_target(path: str | Path, what: str = "--out") -> Path:
    """`path` as a Path when a file may be written there (named, not an existing folder)."""
    path = output_path(path, what)
    if path.is_dir():
        raise Feat2MapError("is a folder; give a file name", str(path))
    return path


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write `data` to a temporary file beside `path`, then rename it into place."""
    path = check_file_target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(path)
    fd, tmp = tempfile.mkstemp(prefix=_prefix(path, "tmp"), dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text(path: str | Path, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def check_dir_target(out: str | Path, markers: Sequence[str] = ()) -> Path:
    """`out` as a Path when a folder may be written there: absent, empty, or an earlier output
    of ours (see `ours`) listing one of `markers` (names or glob patterns of a previous output
    of the same kind, which is then replaced as a whole)."""
    out = output_path(out)
    if out.exists() and not out.is_dir():
        raise Feat2MapError("exists and is not a folder", str(out))
    if out.is_dir() and any(out.iterdir()) and not ours(out, markers):
        want = f" (holding {' or '.join(markers)})" if markers else ""
        raise Feat2MapError(f"folder exists, is not empty and is not an earlier output of this command{want} "
                            f"with nothing added since (its {MANIFEST} lists what feat2map wrote): "
                            "refusing to replace it; remove it or choose another --out", str(out))
    return out


def _files(root: Path) -> list[str] | None:
    """Every entry under `root` that is not a folder, relative, '/'-separated (links not followed);
    None when a folder cannot be read."""
    found = []
    try:
        for top, dirs, names in os.walk(root, onerror=_raise):
            rel = Path(top).relative_to(root)
            found += [(rel / n).as_posix() for n in names]
            found += [(rel / d).as_posix() for d in dirs if (Path(top) / d).is_symlink()]
    except OSError:
        return None
    return sorted(found)


def _raise(err: OSError) -> None:
    raise err


def ours(folder: Path, markers: Sequence[str] = ()) -> bool:
    """Whether `folder` is an output feat2map wrote: its MANIFEST (a regular file) lists every
    file in it, and (when `markers` are given) one listed regular file matches a marker."""
    manifest = folder / MANIFEST
    if manifest.is_symlink() or not manifest.is_file():
        return False
    try:
        listed = json.loads(manifest.read_text(encoding="utf-8"))["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    present = _files(folder)
    if present is None or not isinstance(listed, list) or not set(present) <= set(listed) | {MANIFEST}:
        return False
    return not markers or any(fnmatch.fnmatchcase(n, pat) and (folder / n).is_file() and not (folder / n).is_symlink()
                              for n in present if "/" not in n for pat in markers)


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two existing paths (Linux renameat2 RENAME_EXCHANGE); False if unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EPERM):
        return False
    raise OSError(err, os.strerror(err), str(b))


@contextlib.contextmanager
def staged_dir(out: str | Path, markers: Sequence[str] = ()) -> Iterator[Path]:
    """Yield an empty staging folder beside `out`; when the block succeeds its content
    becomes `out` whole (an old `out` is swapped out and removed), on error it is dropped.
    See `check_dir_target` for when an existing `out` may be replaced."""
    out = check_dir_target(out, markers)
    out.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(out)
    tmp = Path(tempfile.mkdtemp(prefix=_prefix(out, "stage"), dir=out.parent))
    try:
        yield tmp
        write_text(tmp / MANIFEST, json.dumps({"files": _files(tmp)}, indent=1) + "\n")
        os.chmod(tmp, _DIR_MODE)
        check_dir_target(out, markers)  # still ours to replace after the work
        if not out.exists():
            os.rename(tmp, out)
        elif _exchange(tmp, out):
            pass  # `tmp` now holds the old folder: removed below
        else:
            old = Path(tempfile.mkdtemp(prefix=_prefix(out, "old"), dir=out.parent))
            os.rename(out, old / "d")
            os.rename(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
