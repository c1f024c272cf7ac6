"""Atomic outputs: a file or a whole folder appears complete or not at all.

Files are written to a hidden sibling and renamed into place. A folder output is built
complete in a hidden sibling staging folder (`staged_dir`) and then swapped in with one
rename (Linux: renameat2 RENAME_EXCHANGE, so the old folder stays whole until the new one
takes its place; elsewhere two renames, between which the folder is briefly absent). A run
killed at any moment therefore leaves the old folder, the new one, or (only without
RENAME_EXCHANGE) none; never a half-written or mixed one. Its hidden leftovers
(`.NAME.<kind>-<pid>-...`) are removed by the next run that writes NAME, once their process is gone.

An existing non-empty output folder is replaced as a whole only when it holds one of the
caller's marker files (a previous output of the same command); any other folder is refused
before any work is done (`check_dir_target`), so `--out ~` never deletes a home directory.
"""
from __future__ import annotations

import contextlib
import ctypes
import errno
import fnmatch
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
    """`out` as a Path when a folder may be written there: absent, empty, or holding one of
    `markers` (names or glob patterns of a previous output of the same kind, which is then
    replaced as a whole)."""
    out = output_path(out)
    if out.exists() and not out.is_dir():
        raise Feat2MapError("exists and is not a folder", str(out))
    if out.is_dir():
        names = [p.name for p in out.iterdir()]
        if names and not any(fnmatch.fnmatchcase(n, pat) for n in names for pat in markers):
            want = f" (a previous output holds {' or '.join(markers)})" if markers else ""
            raise Feat2MapError(f"folder exists, is not empty and is not an earlier output of this command{want}: "
                                "refusing to replace it; remove it or choose another --out", str(out))
    return out


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
