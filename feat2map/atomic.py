"""Atomic outputs: a file or a whole folder appears complete or not at all.

Files are written to a hidden sibling and renamed into place. A folder output is built
complete in a hidden sibling staging folder (`staged_dir`) and then swapped in with one
rename (Linux: renameat2 RENAME_EXCHANGE, so the old folder stays whole until the new one
takes its place; elsewhere two renames, between which the folder is briefly absent). A run
killed at any moment therefore leaves the old folder, the new one, or (only without
RENAME_EXCHANGE) none; never a half-written or mixed one. Its hidden leftovers
(`.NAME.<kind>-<pid>-...`) are removed by the next run that writes NAME, once their process is gone.

Every folder output carries a manifest, `MANIFEST` (a hidden JSON file listing each file and
folder the run wrote). An existing non-empty output folder is replaced as a whole only when its
manifest is a regular, well-formed one, every file and folder in it is listed (nothing the user
added since, an empty folder included: replacing would delete it) and one of the caller's marker
files is listed (a previous output of the same command); any other folder is refused before any
work is done (`check_dir_target`), so `--out ~` never deletes a home directory, and neither does a
folder that merely holds something named like our outputs. An `out` that is a symbolic link is
written through: its target becomes the output, the link stays. Errors raised while a folder is
staged name `out`, never the hidden staging folder.
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

from .config import OUTPUT_MANIFEST_MAX_BYTES
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
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        _name_out(exc, Path(tmp), path)  # the user's name, not the hidden temporary one
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
        manifest = out / MANIFEST
        if manifest.exists() or manifest.is_symlink():
            try:
                listed = read_manifest(out)
            except Feat2MapError as exc:
                raise Feat2MapError(f"{exc.message}: not an output feat2map wrote, so its folder is not replaced; "
                                    "remove the folder or choose another --out", exc.where) from None
            extra = unlisted(out, *listed)
            if extra:
                raise Feat2MapError(f"folder is an earlier output with {extra[0]!r} added since (not in its {MANIFEST})"
                                    ": refusing to replace it, which would delete that; move it out, remove the "
                                    "folder or choose another --out", str(out))
        want = f" (holding {' or '.join(markers)})" if markers else ""
        raise Feat2MapError(f"folder exists, is not empty and is not an earlier output of this command{want} "
                            f"with nothing added since (its {MANIFEST} lists what feat2map wrote): "
                            "refusing to replace it; remove it or choose another --out", str(out))
    return out


def _listing(root: Path) -> tuple[list[str], list[str]] | None:
    """(every entry under `root` that is not a folder, every folder), relative, '/'-separated,
    links not followed (a link to a folder counts as a file); None when a folder cannot be read."""
    files: list[str] = []
    folders: list[str] = []
    try:
        for top, dirs, names in os.walk(root, onerror=_raise):
            rel = Path(top).relative_to(root)
            files += [(rel / n).as_posix() for n in names]
            for d in dirs:
                (files if (Path(top) / d).is_symlink() else folders).append((rel / d).as_posix())
    except OSError:
        return None
    return sorted(files), sorted(folders)


def _raise(err: OSError) -> None:
    raise err


def _names(value: object) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def read_manifest(folder: Path) -> tuple[frozenset[str], frozenset[str]]:
    """(files, folders) that `folder`'s MANIFEST lists; a Feat2MapError naming the manifest when
    it is not a regular file, is larger than OUTPUT_MANIFEST_MAX_BYTES or is not what
    `staged_dir` writes ({"files": [names], "folders": [names]}; older ones lack "folders")."""
    manifest = folder / MANIFEST
    where = str(manifest)
    if manifest.is_symlink() or not manifest.is_file():
        raise Feat2MapError("missing or not a regular file", where)
    try:
        with manifest.open("rb") as fh:
            raw = fh.read(OUTPUT_MANIFEST_MAX_BYTES + 1)
    except OSError as exc:
        raise Feat2MapError(f"cannot be read ({exc.strerror or type(exc).__name__})", where) from None
    if len(raw) > OUTPUT_MANIFEST_MAX_BYTES:
        raise Feat2MapError(f"malformed: larger than {OUTPUT_MANIFEST_MAX_BYTES:,} bytes", where)
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise Feat2MapError("malformed: not JSON", where) from None
    if not isinstance(doc, dict) or not _names(doc.get("files")) or not _names(doc.get("folders", [])):
        raise Feat2MapError('malformed: expected {"files": [names], "folders": [names]}', where)
    return frozenset(doc["files"]), frozenset(doc.get("folders", []))


def unlisted(folder: Path, files: frozenset[str], folders: frozenset[str]) -> list[str]:
    """What is in `folder` but not listed (files, then folders, each sorted; a folder holding a
    listed file counts as listed, as older manifests list files only); ['?'] when unreadable."""
    listing = _listing(folder)
    if listing is None:
        return ["?"]
    present, dirs = listing
    held = {p.as_posix() for n in present if n in files for p in Path(n).parents if p != Path(".")}
    return [n for n in present if n not in files and n != MANIFEST] + [d + "/" for d in dirs
                                                                      if d not in folders and d not in held]


def ours(folder: Path, markers: Sequence[str] = ()) -> bool:
    """Whether `folder` is an output feat2map wrote: its MANIFEST (a regular file, well-formed)
    lists every file and folder in it, and (when `markers` are given) one listed regular file
    matches a marker."""
    try:
        files, folders = read_manifest(folder)
    except Feat2MapError:
        return False
    if unlisted(folder, files, folders):
        return False
    return not markers or any(fnmatch.fnmatchcase(n, pat) and (folder / n).is_file() and not (folder / n).is_symlink()
                              for n in files if "/" not in n for pat in markers)


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


def through_links(out: Path) -> Path:
    """`out`, or the path a symbolic link `out` points to (through a chain of them): a folder
    output written through a link replaces its target and leaves the link."""
    return Path(os.path.realpath(out)) if out.is_symlink() else out


def _name_out(exc: BaseException, tmp: Path, out: Path) -> None:
    """Say `out` where `exc` says the staging folder `tmp` (a hidden name the user never gave)."""
    if isinstance(exc, Feat2MapError):
        exc.rename_path(str(tmp), str(out))
    elif isinstance(exc, OSError):
        for attr in ("filename", "filename2"):
            value = getattr(exc, attr)
            if isinstance(value, str):
                setattr(exc, attr, value.replace(str(tmp), str(out)))


def _remove(path: Path) -> None:
    if path.is_symlink():
        with contextlib.suppress(OSError):
            path.unlink()
    else:
        shutil.rmtree(path, ignore_errors=True)


@contextlib.contextmanager
def staged_dir(out: str | Path, markers: Sequence[str] = ()) -> Iterator[Path]:
    """Yield an empty staging folder beside `out`; when the block succeeds its content
    becomes `out` whole (an old `out` is swapped out and removed), on error it is dropped.
    See `check_dir_target` for when an existing `out` may be replaced; a link `out` is
    written through (`through_links`); an error names `out`, not the staging folder."""
    out = through_links(output_path(out))
    out = check_dir_target(out, markers)
    out.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(out)
    tmp = Path(tempfile.mkdtemp(prefix=_prefix(out, "stage"), dir=out.parent))
    try:
        yield tmp
        listing = _listing(tmp)
        if listing is None:
            raise Feat2MapError("cannot list the folder just written", str(out))
        files, folders = listing
        write_text(tmp / MANIFEST, json.dumps({"files": files, "folders": folders}, indent=1) + "\n")
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
    except (Feat2MapError, OSError) as exc:
        _name_out(exc, tmp, out)
        raise
    finally:
        _remove(tmp)
