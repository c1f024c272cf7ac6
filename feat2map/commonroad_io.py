"""commonroad-io next to feat2map in one venv: commonroad-io's generated protobuf modules need
protobuf 3.20, feat2map (the Apollo format) needs protobuf >= 5.26, so that
`from commonroad.common.file_reader import CommonRoadFileReader` fails with "Descriptors cannot
be created directly". `install()` (run by `import feat2map`) puts a finder on `sys.meta_path`
that, only while the protobuf runtime cannot load commonroad-io's generated code, answers the
two commonroad-io modules that import it (`common.reader.file_reader_protobuf`,
`common.writer.file_writer_protobuf`) with stand-ins whose classes raise a clear ImportError.
Everything XML (CommonRoadFileReader/-Writer on .xml files, the scenario model) then works;
reading or writing CommonRoad's protobuf files (.pb) needs commonroad-io in its own venv, or
PROTOCOL_BUFFERS_PYTHON_IMPLEMENTATION=python set before anything imports protobuf (pure-Python
protobuf: correct, and much slower for Apollo maps). Standard library only: no import cost.
"""
from __future__ import annotations

import importlib.abc
import importlib.util
import sys
import types
from pathlib import Path

STUBBED = {
    "commonroad.common.reader.file_reader_protobuf": ("ProtobufFileReaderDynamic", "ProtobufFileReaderMap",
                                                      "ProtobufFileReaderScenario", "TrajectoryPredictionFactory"),
    "commonroad.common.writer.file_writer_protobuf": ("ProtobufFileWriter",),
}
MESSAGE = ("CommonRoad protobuf (.pb) files need commonroad-io's protobuf 3.20 code, which the protobuf "
           "runtime feat2map needs cannot load: use commonroad-io in its own venv for .pb files, or set "
           "PROTOCOL_BUFFERS_PYTHON_IMPLEMENTATION=python before importing protobuf (XML files work as they are)")


def protobuf_loads_commonroad() -> bool:
    """Can the installed protobuf runtime load commonroad-io's generated (protobuf 3.20) modules?"""
    try:
        from google.protobuf import __version__ as version
        from google.protobuf.internal import api_implementation
    except ImportError:
        return True  # no protobuf: commonroad-io's own import error is the right one
    return version.startswith("3.") or api_implementation.Type() == "python"


def _unavailable(name: str) -> type:
    def __init__(self, *args, **kwargs):
        raise ImportError(MESSAGE)

    return type(name, (), {"__init__": __init__, "__doc__": MESSAGE})


class _Loader(importlib.abc.Loader):
    def create_module(self, spec):
        return types.ModuleType(spec.name)

    def exec_module(self, module) -> None:
        module.__doc__ = MESSAGE
        for cls in STUBBED[module.__name__]:
            setattr(module, cls, _unavailable(cls))


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name not in STUBBED or protobuf_loads_commonroad():
            return None
        return importlib.util.spec_from_loader(name, _Loader())


ISOLATED_DIR = "commonroad-io"  # scripts/setup.sh installs commonroad-io here, in the venv, off site-packages


def install() -> None:
    """Put the finder first on sys.meta_path (once), and the venv's isolated commonroad-io folder
    (scripts/setup.sh: outside site-packages, so `pip check` holds) on sys.path, last."""
    isolated = str(Path(sys.prefix) / ISOLATED_DIR)
    if Path(isolated).is_dir() and isolated not in sys.path:
        sys.path.append(isolated)
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())
