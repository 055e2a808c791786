"""Who made a result: package version, git revision, time, and the machine (CPU model, vendor,
instruction set, torch version and the SIMD kernels torch picks). Recorded with every output.

The CPU matters: torch picks its kernels by the instruction set (``AVX2``, ``AVX512``, ...),
their rounding differs, and a study's trials drift apart from the first one on, so a result
says which CPU made it (:func:`machine_info`). ``ATEN_CPU_CAPABILITY=avx2`` makes torch use its
AVX2 kernels on an AVX-512 CPU (``torch_cpu_capability`` then records ``AVX2``).
"""

from __future__ import annotations

import datetime as _dt
import functools
import hashlib
import os
import platform
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from safe_bc.version import __version__

_REPO = Path(__file__).resolve().parents[2]


CODE_PATHSPEC = (".", ":(exclude)results")
"""What a revision covers: every tracked file but the outputs under ``results/`` (a rerun
rewrites committed tables one by one; its own earlier outputs do not make the code
uncommitted)."""


def git_revision() -> str:
    """The checkout's commit, with ``-dirty`` when there are uncommitted changes to tracked
    files outside ``results/`` (:data:`CODE_PATHSPEC`).

    Returns ``"unknown"`` outside a git checkout (e.g. an installed wheel).
    """
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=_REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHSPEC],
            cwd=_REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{rev}-dirty" if dirty else rev


RESULTS = _REPO / "results"
"""The checkout's committed result folder: tables written here must come from a clean tree."""
ALLOW_DIRTY = "SAFE_BC_ALLOW_DIRTY"
"""Environment variable that lets a result table be written from a dirty tree: its value (a
reason, e.g. ``"draft rerun"``; ``0`` or empty does not count) is recorded in the table."""


class DirtyTreeError(RuntimeError):
    """A result table under ``results/`` was about to be written from uncommitted code."""


def _changed_files() -> list[str]:
    try:
        out = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHSPEC],
            cwd=_REPO, capture_output=True, text=True, check=True,
        ).stdout  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return []
    return [line[3:] for line in out.splitlines() if line.strip()]


def committed_unchanged(folder: str | Path) -> bool:
    """Whether ``folder`` holds files git tracks, none of them changed or deleted since the
    checkout's last commit: a published result (e.g. a study's committed tables on a fresh
    clone), not the records of a run that went on here. ``False`` outside a git checkout."""
    folder = Path(folder)
    if not folder.is_dir():
        return False
    try:

        def git(*args: str) -> str:
            return subprocess.run(
                ["git", *args, "--", "."], cwd=folder, capture_output=True, text=True, check=True
            ).stdout

        return (
            bool(git("ls-files").strip())
            and not git("status", "--porcelain", "--untracked-files=no").strip()
        )
    except (OSError, subprocess.CalledProcessError):
        return False


def check_result_write(path: str | Path) -> dict[str, Any] | None:
    """Refuse to write a result table under the checkout's ``results/`` from a dirty git tree
    (uncommitted changes to tracked files outside ``results/``: the table could not be
    re-derived from any commit; the command's own earlier tables do not count), unless
    ``$SAFE_BC_ALLOW_DIRTY`` says why; then return the record to embed in the table's metadata
    (``{"allowed_by": ..., "reason": ..., "changed_files": [...]}``).
    ``None``: nothing to record (a clean tree, a path elsewhere, e.g. a test's temporary
    folder, or no git checkout).

    Raises:
        DirtyTreeError: dirty tree, path under ``results/``, no ``$SAFE_BC_ALLOW_DIRTY``.
    """
    target = Path(path).resolve()
    if not target.is_relative_to(RESULTS.resolve()):
        return None
    changed = _changed_files()
    if not changed:
        return None
    reason = os.environ.get(ALLOW_DIRTY, "").strip()
    if reason in ("", "0"):
        shown = ", ".join(changed[:8]) + (
            f" (+{len(changed) - 8} more)" if len(changed) > 8 else ""
        )
        raise DirtyTreeError(
            f"refusing to write {path}: the git tree has uncommitted changes ({shown}), so the "
            f"table could not be re-derived from a commit; commit first, or set "
            f"{ALLOW_DIRTY}=<reason> to write it anyway (the reason and the changed files are "
            "recorded in the table)"
        )
    return {"allowed_by": ALLOW_DIRTY, "reason": reason, "changed_files": changed}


SIMD_FLAGS = (
    "sse4_2", "avx", "avx2", "fma", "f16c", "avx512f", "avx512dq", "avx512bw", "avx512vl",
    "avx512_vnni", "avx512_bf16", "avx512_fp16", "amx_tile", "amx_bf16", "amx_int8",
    "asimd", "asimdhp", "sve", "sve2", "sme",
)  # fmt: skip
"""The vector extensions :func:`machine_info` lists from ``/proc/cpuinfo``'s flags (x86
``flags``, ARM ``Features``), in this order: the ones that decide torch's and numpy's kernels."""

ARM_IMPLEMENTERS = {"0x41": "ARM", "0x42": "Broadcom", "0x43": "Cavium", "0x46": "Fujitsu",
                    "0x48": "HiSilicon", "0x4e": "NVIDIA", "0x50": "Ampere (APM)",
                    "0x51": "Qualcomm", "0x61": "Apple", "0xc0": "Ampere"}  # fmt: skip
"""``CPU implementer`` codes of ARM's ``/proc/cpuinfo`` -> vendor."""


def file_digest(path: str | Path) -> str:
    """``"sha256:<hex>"`` of a file's bytes: how a table names another table it read."""
    return "sha256:" + hashlib.sha256(Path(path).read_bytes()).hexdigest()


def parse_cpuinfo(text: str) -> dict[str, str]:
    r"""``cpu_model``, ``cpu_vendor`` and ``cpu_simd`` (the :data:`SIMD_FLAGS` present, space
    separated) from the text of Linux's ``/proc/cpuinfo`` (its first processor); ``""``
    where the text does not say.

    >>> info = parse_cpuinfo("vendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 9B14\n"
    ...                      "flags\t\t: fpu sse4_2 avx avx2 avx512f avx512_vnni\n\n"
    ...                      "vendor_id\t: other\n")
    >>> info["cpu_model"], info["cpu_vendor"]
    ('AMD EPYC 9B14', 'AuthenticAMD')
    >>> info["cpu_simd"]
    'sse4_2 avx avx2 avx512f avx512_vnni'
    >>> parse_cpuinfo("CPU implementer\t: 0x41\nFeatures\t: fp asimd sve\n")["cpu_vendor"]
    'ARM'
    """
    fields: dict[str, str] = {}
    for line in text.split("\n\n", 1)[0].splitlines():
        key, sep, value = line.partition(":")
        if sep:
            fields.setdefault(key.strip().lower(), value.strip())
    model = fields.get("model name") or fields.get("model") or fields.get("hardware") or ""
    if not model and "cpu part" in fields:
        model = f"part {fields['cpu part']}"
    vendor = fields.get("vendor_id") or ARM_IMPLEMENTERS.get(
        fields.get("cpu implementer", "").lower(), fields.get("cpu implementer", "")
    )
    flags = set((fields.get("flags") or fields.get("features") or "").split())
    simd = " ".join(f for f in SIMD_FLAGS if f in flags)
    return {"cpu_model": model, "cpu_vendor": vendor, "cpu_simd": simd}


def _sysctl(name: str) -> str:
    try:
        return subprocess.run(
            ["sysctl", "-n", name], capture_output=True, text=True, check=True, timeout=5
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def _cpu() -> dict[str, str]:
    """The CPU as the system describes it: ``/proc/cpuinfo`` on Linux, ``sysctl`` on macOS,
    else ``platform.processor()``."""
    try:
        info = parse_cpuinfo(Path("/proc/cpuinfo").read_text(errors="replace"))
    except OSError:
        info = {"cpu_model": "", "cpu_vendor": "", "cpu_simd": ""}
    if not info["cpu_model"] and platform.system() == "Darwin":
        info["cpu_model"] = _sysctl("machdep.cpu.brand_string")
        info["cpu_vendor"] = _sysctl("machdep.cpu.vendor") or (
            "Apple" if platform.machine() == "arm64" else ""
        )
        if not info["cpu_simd"]:  # Intel Macs list their features; Apple silicon has NEON
            feats = set(_sysctl("machdep.cpu.features").lower().split())
            feats |= set(_sysctl("machdep.cpu.leaf7_features").lower().split())
            feats = {f.replace(".", "_").replace("avx1_0", "avx") for f in feats}
            info["cpu_simd"] = " ".join(f for f in SIMD_FLAGS if f in feats) or (
                "asimd" if platform.machine() == "arm64" else ""
            )
    if not info["cpu_model"]:
        info["cpu_model"] = platform.processor()
    return {k: v or "unknown" for k, v in info.items()}


def _torch() -> dict[str, str]:
    """torch's version and the kernels it dispatches to here (``AVX512``, ``AVX2``, ``DEFAULT``,
    ...; ``ATEN_CPU_CAPABILITY`` lowers it), or ``"unavailable"``."""
    try:
        import torch

        capability = str(torch.backends.cpu.get_cpu_capability())
        version = str(torch.__version__)
    except (ImportError, AttributeError, RuntimeError):
        return {"torch_version": "unavailable", "torch_cpu_capability": "unavailable"}
    return {"torch_version": version, "torch_cpu_capability": capability}


@functools.cache
def machine_info() -> dict[str, str]:
    """What computed a result, beyond the code: ``cpu_model``, ``cpu_vendor``, ``cpu_simd``
    (the vector extensions the CPU reports, :data:`SIMD_FLAGS`), ``torch_version``,
    ``torch_cpu_capability`` (the SIMD level of torch's kernels,
    ``torch.backends.cpu.get_cpu_capability()``) and ``numpy_version``; ``"unknown"`` where the
    system does not say. Read once per process."""
    import numpy

    return {**_cpu(), **_torch(), "numpy_version": numpy.__version__}


def provenance() -> dict[str, str]:
    """Version, revision, UTC creation time and machine of the current run (with
    :func:`machine_info`: CPU model, vendor, instruction set, torch's kernels)."""
    return {
        "package_version": __version__,
        "git_revision": git_revision(),
        "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "machine": f"{platform.machine()} {platform.node()}",
        "cpus": str(os.cpu_count()),
        **machine_info(),
    }


def with_provenance(metadata: dict[str, Any] | None) -> dict[str, Any]:
    """``metadata`` with this run's :func:`provenance` under ``"provenance"`` when it records
    none (neither a ``"provenance"`` entry nor :func:`run_metadata`'s top-level
    ``"git_revision"``); a recorded one is kept (it may describe the run that computed the
    rows, e.g. a table rewritten from a cache).

    >>> with_provenance({"git_revision": "abc"})
    {'git_revision': 'abc'}
    >>> "cpu_model" in with_provenance(None)["provenance"]
    True
    """
    metadata = dict(metadata or {})
    if "provenance" not in metadata and "git_revision" not in metadata:
        metadata["provenance"] = provenance()
    return metadata


def result_metadata(path: str | Path, metadata: dict[str, Any] | None) -> dict[str, Any]:
    """The metadata a result table at ``path`` is written with: ``metadata``
    :func:`with_provenance`, and the dirty tree's record where :func:`check_result_write`
    allows one (``"dirty_tree"``).

    Raises:
        DirtyTreeError: as :func:`check_result_write`.
    """
    dirty = check_result_write(path)
    metadata = with_provenance(metadata)
    return metadata if dirty is None else {**metadata, "dirty_tree": dirty}


def run_metadata(**fields: Any) -> dict[str, Any]:
    """What a result table records: the command line (:func:`command_line`), ``fields`` (seeds,
    configs) and :func:`provenance`."""
    return {"command": command_line(), **fields, **provenance()}


def repo_relative(path: str | Path, root: str | Path = _REPO) -> str:
    """``path`` relative to the repository ``root`` (POSIX) when it is an absolute path inside
    it, else unchanged: what a committed record says, the same on every machine.

    >>> repo_relative("/r/results/ray/x", "/r"), repo_relative("/tmp/x", "/r")
    ('results/ray/x', '/tmp/x')
    >>> repo_relative("data/demos", "/r"), repo_relative("/r", "/r")
    ('data/demos', '.')
    """
    text = str(path)
    if not os.path.isabs(text):
        return text
    relative = os.path.relpath(os.path.normpath(text), os.path.normpath(str(root)))
    return text if relative.startswith("..") else Path(relative).as_posix()


ENTRY_PROGRAMS = (
    "/safe-bc",
    "safe_bc/cli/__main__.py",
    "safe_bc/cli/commands.py",
    "safe_bc/cli/commands.py",  # the module's path before the cli package
)
"""How ``argv[0]`` ends when the command line's entry point runs (recorded as ``safe-bc``)."""


def command_line(argv: Sequence[str] | None = None, root: str | Path = _REPO) -> str:
    """The command line ``argv`` (default ``sys.argv``) as a result records it: the program as
    ``safe-bc`` when it is the command line's entry point (``.../bin/safe-bc``,
    ``python -m`` of ``safe_bc/cli/``), else by its path in the repository ``root`` or, outside
    it, its name; and every absolute path inside ``root`` (a word, or the value of ``--flag=value``)
    relative to it.

    >>> command_line(["/r/.venv/bin/safe-bc", "describe", "--out", "/r/res", "--x=/r/a"], "/r")
    'safe-bc describe --out res --x=a'
    >>> command_line(["/r/safe_bc/cli/__main__.py", "compare", "--out", "/tmp/o"], "/r")
    'safe-bc compare --out /tmp/o'
    >>> command_line(["/usr/bin/pytest", "-q"], "/r"), command_line(["/r/scripts/s.py"], "/r")
    ('pytest -q', 'scripts/s.py')
    """
    words = list(sys.argv if argv is None else argv)
    if not words:
        return ""
    program = words[0].replace(os.sep, "/")
    if program.endswith(ENTRY_PROGRAMS) or program == "safe-bc":
        program = "safe-bc"
    else:
        program = repo_relative(words[0], root)
        program = Path(program).name if os.path.isabs(program) else program

    def word(w: str) -> str:
        flag, eq, value = w.partition("=")
        if eq and flag.startswith("-"):
            return f"{flag}={repo_relative(value, root)}"
        return repo_relative(w, root)

    return " ".join([program, *(word(w) for w in words[1:])])
