"""Not a package: the root of a feat2map clone. Python imports it as `feat2map` only when run
from the folder that holds a clone named feat2map (the clone then shadows the installed package,
and without this file it would be an empty namespace package: "cannot import name
'__version__'"); this file turns that into one clear error."""
from pathlib import Path

raise ImportError(
    f"'import feat2map' found the folder of a feat2map clone ({Path(__file__).resolve().parent}), not the "
    "installed package, because Python runs in the folder that holds the clone: run it from the repository "
    "root or any other folder (with .venv active)")
