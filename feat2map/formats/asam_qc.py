"""Run an ASAM Quality Checker bundle (asam-qc-opendrive, asam-qc-openscenarioxml) on one file
and read its result, so each ASAM export is judged by ASAM's own checker.

A bundle is a command (`qc_opendrive -c CONFIG`) that reads a qc-framework configuration
(`<Config>` with the `InputFile` parameter and a `<CheckerBundle>` naming its `resultFile`) and
writes an `.xqar` result: per checker its status (completed / skipped / error) and its issues,
each with locations (file row, XPath, description). The bundles pin numpy<2 and lxml<6, so
scripts/setup.sh installs them in their own environment (.venv-qc) and links the commands into
.venv/bin, where `find_bundle` looks first.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..config import LIMIT_FLAG, limits, plain_number
from ..errors import Feat2MapError
from .base import Problem

# (command, bundle application name, pip package) per checked format
OPENDRIVE = ("qc_opendrive", "xodrBundle", "asam-qc-opendrive")
OPENSCENARIO = ("qc_openscenario", "xoscBundle", "asam-qc-openscenarioxml")


@dataclass(frozen=True)
class CheckerResult:
    """One checker of a bundle run: its id, status, summary and the issues it found."""

    checker_id: str
    status: str  # "completed", "skipped" or "error"
    summary: str
    issues: tuple[Problem, ...]

    @property
    def skipped_for_version(self) -> bool:
        """Skipped because the file's revision is outside the rule's applicable versions."""
        return self.status == "skipped" and "Version" in self.summary


def find_bundle(command: str) -> str | None:
    """The bundle's command beside this Python (.venv/bin), else on PATH; None when absent."""
    exe = Path(sys.executable).parent / command
    return str(exe) if exe.exists() else shutil.which(command)


def run_bundle(path: str | Path, bundle: tuple[str, str, str]) -> list[CheckerResult]:
    """Run `bundle` (OPENDRIVE or OPENSCENARIO) on the file `path`; one result per checker."""
    from lxml import etree

    command, application, package = bundle
    path = Path(path).resolve()
    if not path.is_file():
        raise Feat2MapError("no such file", str(path))
    exe = find_bundle(command)
    if exe is None:
        raise Feat2MapError(f"{command} not found: pip install {package} (scripts/setup.sh installs it in .venv-qc)",
                            str(path))
    with tempfile.TemporaryDirectory(prefix="feat2map-qc-") as tmp:
        config, result = Path(tmp) / "config.xml", Path(tmp) / "result.xqar"
        root = etree.Element("Config")
        etree.SubElement(root, "Param", name="InputFile", value=str(path))
        cb = etree.SubElement(root, "CheckerBundle", application=application)
        etree.SubElement(cb, "Param", name="resultFile", value=str(result))
        config.write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8"))
        seconds = limits().max_checker_s
        try:
            run = subprocess.run([exe, "-c", str(config)], cwd=tmp, capture_output=True, text=True, timeout=seconds)
        except subprocess.TimeoutExpired:
            raise Feat2MapError(f"{command} ran longer than {plain_number(seconds)} s, the limit max_checker_s "
                                f"(raise it with {LIMIT_FLAG} max_checker_s=N)", str(path)) from None
        if run.returncode != 0 or not result.is_file():
            last = (run.stderr.strip().splitlines() or ["no output"])[-1]
            raise Feat2MapError(f"{command} failed (exit {run.returncode}): {last}", str(path))
        doc = etree.parse(str(result)).getroot()
    return [_checker(c, path.name) for c in doc.iter("Checker")]


def _checker(el, name: str) -> CheckerResult:
    cid = el.get("checkerId", "?")
    short = cid.removeprefix("check_asam_xodr_").removeprefix("check_asam_xosc_")
    issues = []
    for issue in el.iter("Issue"):  # one problem per issue, at its first location
        loc = issue.find("Locations")
        loc = issue if loc is None else loc
        row = next((f.get("row") for f in loc.iter("FileLocation")), None)
        xpath = next((x.get("xpath") for x in loc.iter("XMLLocation")), None)
        where = name + (f":{row}" if row else "") + (f" {xpath}" if xpath else "")
        issues.append(Problem(where, f"{short}: {loc.get('description') or issue.get('description')}"))
    return CheckerResult(cid, el.get("status", ""), el.get("summary", ""), tuple(issues))


def problems(results: list[CheckerResult]) -> list[Problem]:
    """The issues of all checkers, plus a problem for each checker that failed internally."""
    out = [p for r in results for p in r.issues]
    out += [Problem(r.checker_id, f"checker error: {r.summary}") for r in results if r.status == "error"]
    return out
