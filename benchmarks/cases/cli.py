"""The ``cli`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.bench import (
    PAIRED_NOTE,
    Sizes,
    _order,
    _row,
    _self_row,
)

HELP_TARGET_S = 0.5
"""The most seconds ``safe-bc --help`` may take, the target the ``cli`` case reports."""


def _cli_commands() -> dict[str, list[str]]:
    """The ``cli`` case's commands: an empty interpreter start (the baseline), then the
    installed ``safe-bc`` script beside this interpreter (or ``python -m safe_bc.cli.commands``
    where
    there is none) with the short help of the command list and of ``train``."""
    script = Path(sys.executable).with_name("safe-bc")
    cli = [str(script)] if script.exists() else [sys.executable, "-m", "safe_bc.cli.commands"]
    return {
        "python -c pass": [sys.executable, "-c", "pass"],
        "safe-bc --help": [*cli, "--help"],
        "safe-bc train --help": [*cli, "train", "--help"],
    }


def bench_cli(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """Wall-clock seconds from starting ``safe-bc --help`` (and ``safe-bc train --help``) in a
    fresh process to its exit, against starting an interpreter that does nothing in the same
    run: the value is the absolute time, the ratio what the command line adds to a bare
    start (paired per repetition, order alternating)."""
    commands = _cli_commands()
    runs: dict[str, list[float]] = {name: [] for name in commands}
    for rep in range(max(repeats, sizes.cli_min_repeats)):
        for name in _order(list(commands), rep):
            t0 = time.perf_counter()
            subprocess.run(commands[name], stdout=subprocess.DEVNULL, check=True)
            runs[name].append(time.perf_counter() - t0)
    base, *rest = list(commands)
    note = (
        f"wall-clock s, process start to exit, stdout discarded; target: at most "
        f"{HELP_TARGET_S:g} s; {PAIRED_NOTE}"
    )
    return [
        _self_row("cli", base, runs[base], "s", note),
        *(_row("cli", v, runs[v], "s", (base, runs[base]), note, paired=True) for v in rest),
    ]
