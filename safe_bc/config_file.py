"""Running a plain-config Python file (a study file, a comparison family) by path.

A config file is data written as Python: it builds frozen records and names them (``STUDY``,
``COMPARISONS``). Running it is the one step that can fail in the user's own code, so every
failure comes back as one ``ValueError`` line naming the file and, where the problem is in it,
the line.
"""

from __future__ import annotations

import importlib.util
import sys
import traceback
from pathlib import Path
from types import ModuleType


def run_config_file(path: str | Path, what: str, where: str, prefix: str) -> ModuleType:
    """Import the Python file at ``path`` as the module ``<prefix><stem>`` (kept in
    ``sys.modules`` so that what it defines pickles by reference) and return it.

    ``what`` names the kind of file and ``where`` its usual place, for the messages
    (``"study file"``, ``"tune_jobs/<name>.py"``).

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a Python file, or running it failed (a syntax error, a failing
            import, a bad value): one line naming the file, the line and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no {what} {path}")
    if path.suffix != ".py":
        raise ValueError(f"{path}: a {what} is a Python file ({where})")
    module_name = f"{prefix}{path.stem}"
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise ValueError(f"{path}: cannot be imported")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    try:
        spec.loader.exec_module(module)
    except SyntaxError as e:  # also raised for a syntax error in a module the file imports
        sys.modules.pop(module_name, None)
        inside = Path(e.filename or path).resolve() == path.resolve()
        at = f"{path}:{e.lineno}" if inside else f"{path}: {e.filename}:{e.lineno}"
        raise ValueError(f"{at}: {type(e).__name__}: {e.msg}") from None
    except Exception as e:
        sys.modules.pop(module_name, None)
        here = [
            f
            for f in traceback.extract_tb(e.__traceback__)
            if Path(f.filename).resolve() == path.resolve()
        ]
        line = f":{here[-1].lineno}" if here else ""
        problem = " ".join(str(e).split()) or "(no message)"
        raise ValueError(f"{path}{line}: {type(e).__name__}: {problem}") from None
    return module
