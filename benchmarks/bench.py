"""`make bench`: env stepping, Ray collection, BC training and evaluation speed, as ratios.

This file is the harness (sizes, repeats, paired ratios, memory, the table and its
provenance); each case is one file under ``benchmarks/cases/`` holding its function
``bench_<case>(sizes, repeats, seed) -> rows`` (:data:`CASES`, in the order they run).

The machine is shared and noisy, so every figure is the median of several repetitions and
every comparison is a *ratio* against a baseline measured in the same process, with the
variants interleaved (their order alternates between repetitions) so that load from other
processes hits both alike. Compare ratios, not absolute numbers.

Each case runs in its own subprocess (``python -m benchmarks.bench --case X --json``) so that
its peak memory can be read with ``getrusage``; the driver collects the rows, prints a table
and writes ``results/bench.parquet`` with machine information and provenance in the table
metadata.

    python -m benchmarks.bench                       # all cases, ~4-5 minutes on 2 busy cores
    python -m benchmarks.bench --quick --cases env,train --repeats 2
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["CASES", "FULL", "QUICK", "Sizes", "main", "run_case", "run_case_subprocess"]

CASES: tuple[str, ...] = (
    "env",
    "collect",
    "train",
    "stream",
    "eval",
    "study",
    "final",
    "improve",
    "selfimprove",
    "cli",
)
"""Benchmark cases, in the order they run."""

DEFAULT_OUT = Path("results/bench.parquet")
COLUMNS: tuple[str, ...] = (
    "case",
    "variant",
    "value",
    "unit",
    "baseline",
    "ratio",
    "runs",
    "repeats",
    "note",
    "peak_mb",
    "peak_children_mb",
    "peak_actor_mb",
    "peak_tree_mb",
)
"""Columns of the result table (one row per measured figure)."""

MEMORY_NOTES = {
    "peak_mb": "getrusage(RUSAGE_SELF).ru_maxrss of the case's own process (the driver of "
    "its Ray actors); includes the imports (torch, gymnasium, ray) of that process.",
    "peak_children_mb": "getrusage(RUSAGE_CHILDREN).ru_maxrss after the case (ray.shutdown() "
    "first): the largest single reaped descendant, not a sum. Caveat (Linux): a child keeps "
    "the RSS high-water mark of the process it was forked from across exec, so this is at "
    "least the driver's RSS when it last spawned a helper (git in provenance(), Ray's "
    "GCS/raylet); Ray actors are children of the raylet and are usually not reaped into it. "
    "Use peak_actor_mb / peak_tree_mb for Ray. 0 when the case starts no processes.",
    "peak_actor_mb": "largest RSS of a single Ray actor process (a descendant named "
    "'ray::<ActorClass>'), sampled every 0.25 s with psutil; NaN when the case starts no "
    "actors (or without psutil).",
    "peak_tree_mb": "largest sum of RSS over the case's process and all its descendants "
    "(Ray GCS, raylet, dashboard/runtime-env agents, idle workers, actors), sampled every "
    "0.25 s with psutil: can miss short peaks and double-counts pages shared between "
    "processes (shared libraries, the plasma store). NaN without psutil.",
}


@dataclass(frozen=True)
class Sizes:
    """How much work one repetition of each case does."""

    env_steps: int
    """Env steps per variant per repetition (the ``env`` case)."""
    collect_episodes: int
    """Episodes per collection run (both worker counts)."""
    collect_steps: int
    """``max_steps`` of each collected episode."""
    train_frames: int
    """Synthetic ``96x96x3`` demonstration frames."""
    train_batches: int
    """Gradient steps per training run (batch size 64)."""
    eval_episodes: int
    """Held-out episodes per ``evaluate_policies`` call."""
    eval_steps: int
    """``max_steps`` of each evaluation episode."""
    act_steps: int
    """Steps of the per-step env vs inference timing, per repetition."""
    study_trials: int = 4
    """Trials of the tiny study timed at 1 and at 2 concurrent trials."""
    study_batches: int = 100
    """Training batches per trial of the tiny study."""
    final_episodes: int = 4
    """Episodes per policy of the final-phase evaluation (2 policies)."""
    improve_steps: int = 150
    """Lockstep steps of the improvement rollout's 4 CarRacing envs, per variant and
    repetition."""
    selfimprove_tracks: int = 2
    """Training tracks of the ``selfimprove`` case's round (each run unperturbed and once per
    CarRacing push: 6 runs a track)."""
    selfimprove_steps: int = 200
    """``max_steps`` of every run of the ``selfimprove`` case."""
    selfimprove_kept: int = 1500
    """Car frames each round of the ``selfimprove`` case's kept-frame timing keeps (a full run's
    rounds keep ~80k; the demonstrations are as many)."""
    selfimprove_rounds: int = 4
    """Rounds (all accepted) of the ``selfimprove`` case's kept-frame timing."""
    stream_episodes: tuple[int, ...] = (5, 100)
    """Dataset sizes (episodes) of the ``stream`` case: the source's episodes recoded (new
    episode ids and env seeds) into a temporary store, as many as each entry says."""
    stream_batches: int = 200
    """Training batches (batch size 64) of each ``stream`` case run."""
    stream_source: str = "data/demos"
    """The ``stream`` case's source dataset; when absent (or ``""``), 5 synthetic episodes of
    ``stream_synthetic_steps`` random frames."""
    stream_synthetic_steps: int = 200
    """Steps of each synthetic source episode of the ``stream`` case."""
    train_min_repeats: int = 1
    """At least this many repetitions of the train case, whatever ``--repeats`` says: its
    ratio sits near the 0.95x target and one run's moved by +-10% (0.84x-1.03x in six runs
    of 3 repetitions), so it is timed in more back-to-back pairs."""
    cli_min_repeats: int = 1
    """At least this many repetitions of the ``cli`` case (a process start takes under a
    second, so more starts cost little and steady the median)."""


FULL = Sizes(
    env_steps=300,
    collect_episodes=2,
    collect_steps=300,
    train_frames=1000,
    train_batches=200,
    eval_episodes=2,
    eval_steps=200,
    act_steps=200,
    train_min_repeats=7,
    cli_min_repeats=9,
)
QUICK = Sizes(
    env_steps=40,
    collect_episodes=2,
    collect_steps=60,
    train_frames=200,
    train_batches=16,
    eval_episodes=1,
    eval_steps=60,
    act_steps=40,
    study_trials=2,
    study_batches=10,
    final_episodes=1,
    improve_steps=20,
    selfimprove_tracks=1,
    selfimprove_steps=20,
    selfimprove_kept=30,
    selfimprove_rounds=2,
    stream_episodes=(1, 3),
    stream_batches=3,
    stream_source="",
    stream_synthetic_steps=20,
)

# --------------------------------------------------------------------------------- helpers


def _median(values: Sequence[float]) -> float:
    return float(statistics.median(values))


PAIRED_NOTE = (
    "ratio: median of the per-repetition ratios (each repetition times the variants back to "
    "back, in alternating order)"
)
"""Note of a row whose ratio is :func:`_paired_ratio`."""


def _paired_ratio(runs: Sequence[float], base_runs: Sequence[float]) -> float:
    """Median of the per-repetition ratios ``runs[i] / base_runs[i]``: each repetition times
    both variants back to back, so a slow spell of the machine cancels."""
    if len(base_runs) != len(runs):
        raise ValueError(f"paired ratio needs equal repetitions: {len(runs)}, {len(base_runs)}")
    return _median([v / b for v, b in zip(runs, base_runs, strict=True)])


def _order(names: Sequence[str], rep: int) -> list[str]:
    """Variants in the given order on even repetitions, reversed on odd ones."""
    return list(names) if rep % 2 == 0 else list(names)[::-1]


def _row(
    case: str,
    variant: str,
    runs: Sequence[float],
    unit: str,
    baseline: tuple[str, Sequence[float]] | None = None,
    note: str = "",
    paired: bool = False,
) -> dict[str, Any]:
    """One result row: the median of ``runs`` and its ratio to the baseline's median.

    ``baseline`` is ``(variant name, runs)``; a row that is its own baseline has ratio 1, a
    row without one has ratio NaN and an empty ``baseline``. ``paired``: the ratio is
    :func:`_paired_ratio` instead.
    """
    value = _median(runs)
    if baseline is None:
        base_name, ratio = "", math.nan
    else:
        base_name, base_runs = baseline
        ratio = _paired_ratio(runs, base_runs) if paired else value / _median(base_runs)
    return {
        "case": case,
        "variant": variant,
        "value": value,
        "unit": unit,
        "baseline": base_name,
        "ratio": ratio,
        "runs": [float(v) for v in runs],
        "repeats": len(runs),
        "note": note,
    }


def _self_row(
    case: str, variant: str, runs: Sequence[float], unit: str, note: str = ""
) -> dict[str, Any]:
    """A baseline row (ratio 1 against itself)."""
    return _row(case, variant, runs, unit, (variant, runs), note)


_RAY_SYSTEM_PROCS = frozenset({"ray::IDLE", "ray::DashboardAgent", "ray::RuntimeEnvAgent"})


class _TreeRSS:
    """Samples, in a daemon thread, the summed RSS of this process and its descendants and
    the largest RSS of one Ray actor process (named ``ray::<ActorClass>`` by Ray)."""

    def __init__(self, interval: float = 0.25) -> None:
        self.interval = interval
        self.peak_bytes = 0
        self.peak_actor_bytes = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        try:
            import psutil
        except ImportError:  # psutil is a dev dependency
            self._proc = None
        else:
            self._proc = psutil.Process()

    def _sample(self) -> None:
        import psutil

        assert self._proc is not None
        total = 0
        for proc in [self._proc, *self._proc.children(recursive=True)]:
            with contextlib.suppress(psutil.Error):
                rss = proc.memory_info().rss
                total += rss
                name = proc.name()
                if name.startswith("ray::") and name not in _RAY_SYSTEM_PROCS:
                    self.peak_actor_bytes = max(self.peak_actor_bytes, rss)
        self.peak_bytes = max(self.peak_bytes, total)

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            self._sample()

    def __enter__(self) -> _TreeRSS:
        if self._proc is not None:
            self._sample()
            self._thread = threading.Thread(target=self._loop, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()

    @property
    def peak_mb(self) -> float:
        """Peak summed RSS of the process tree, MiB (NaN without psutil)."""
        return self.peak_bytes / 2**20 if self._proc is not None else math.nan

    @property
    def peak_actor_mb(self) -> float:
        """Peak RSS of one Ray actor process, MiB (NaN when none was seen)."""
        return self.peak_actor_bytes / 2**20 if self.peak_actor_bytes else math.nan


def _maxrss_mb(who: int) -> float:
    """``ru_maxrss`` in MiB (Linux reports KiB, macOS bytes)."""
    raw = resource.getrusage(who).ru_maxrss
    return raw / 2**20 if sys.platform == "darwin" else raw / 1024


# ---------------------------------------------------------------------------- running cases

_BENCHES: dict[str, str] = {case: f"benchmarks.cases.{case}:bench_{case}" for case in CASES}
"""Each case's function, ``module:function`` (imported when it runs): one file per case under
``benchmarks/cases/``, each a function ``(sizes, repeats, seed) -> rows``."""


def case_module(case: str) -> ModuleType:
    """The file of ``case``, imported."""
    import importlib

    return importlib.import_module(_BENCHES[case].partition(":")[0])


def case_function(case: str) -> Callable[[Sizes, int, int], Any]:
    """The function of ``case`` (imports its file)."""
    return getattr(case_module(case), _BENCHES[case].partition(":")[2])


def run_case(case: str, sizes: Sizes, repeats: int, seed: int = 0) -> dict[str, Any]:
    """Run one case in this process: ``{"case", "rows", "seconds", "memory": {...},
    "inputs"}`` (``inputs``: the identity of the inputs the case made, where it names them).

    The memory figures are this process's (see ``MEMORY_NOTES``); run it in a fresh process
    (``run_case_subprocess``) for them to describe the case alone.
    """
    if case not in _BENCHES:
        raise ValueError(f"unknown case {case!r}; choose from {', '.join(CASES)}")
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    start = time.perf_counter()
    with _TreeRSS() as tree:
        got = case_function(case)(sizes, repeats, seed)
    # a case that makes its own inputs may name them: {"rows": [...], "inputs": {...}}
    rows, inputs = (got["rows"], got.get("inputs")) if isinstance(got, dict) else (got, None)
    memory = {
        "peak_mb": _maxrss_mb(resource.RUSAGE_SELF),
        "peak_children_mb": _maxrss_mb(resource.RUSAGE_CHILDREN),
        "peak_actor_mb": tree.peak_actor_mb,
        "peak_tree_mb": tree.peak_mb,
    }
    return {
        "case": case,
        "rows": rows,
        "seconds": time.perf_counter() - start,
        "memory": memory,
        "inputs": inputs,
    }


def run_case_subprocess(
    case: str, quick: bool, repeats: int, seed: int = 0, timeout: float = 900.0
) -> dict[str, Any]:
    """``run_case`` in a fresh ``python -m benchmarks.bench --case ... --json`` process.

    The child's stderr (Ray and progress messages) passes through; its stdout is one JSON
    document.
    """
    cmd = [sys.executable, "-m", "benchmarks.bench", "--case", case, "--json"]
    cmd += ["--repeats", str(repeats), "--seed", str(seed)] + (["--quick"] if quick else [])
    env = {**os.environ, "RAY_AUTH_MODE": os.environ.get("RAY_AUTH_MODE", "disabled")}
    repo = Path(__file__).resolve().parents[1]  # ``benchmarks`` is importable from the root
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(repo), env.get("PYTHONPATH", "")) if p)
    proc = subprocess.run(
        cmd, stdout=subprocess.PIPE, text=True, timeout=timeout, env=env, check=False, cwd=repo
    )
    if proc.returncode != 0:
        raise RuntimeError(f"bench case {case!r} failed with exit status {proc.returncode}")
    return json.loads(proc.stdout)


def _rows_with_memory(result: dict[str, Any]) -> list[dict[str, Any]]:
    """The case's rows, each carrying the case's peak memory figures."""
    return [{**row, **result["memory"]} for row in result["rows"]]


# ------------------------------------------------------------------------------ reporting


def machine_info() -> dict[str, Any]:
    """CPU model and count, library versions, load average: what the numbers depend on."""
    import gymnasium
    import ray
    import torch

    model = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count() or 0
    return {
        "cpu_model": model,
        "cpu_count": os.cpu_count(),
        "cpu_usable": usable,
        "load_avg_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "torch": torch.__version__,
        "torch_threads_default": torch.get_num_threads(),
        "ray": ray.__version__,
        "gymnasium": gymnasium.__version__,
    }


def _fmt(value: float) -> str:
    if not math.isfinite(value):
        return "-"
    if abs(value) >= 100:
        return f"{value:,.0f}"
    if abs(value) >= 10:
        return f"{value:.1f}"
    return f"{value:.2f}"


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """Aligned text table: case, variant, value, unit, ratio vs baseline, peak MB."""
    header = ("case", "variant", "value", "unit", "ratio", "vs", "peak MB", "actor MB", "tree MB")
    lines = [
        (
            row["case"],
            row["variant"],
            _fmt(row["value"]),
            row["unit"],
            "-" if not math.isfinite(row["ratio"]) else f"{row['ratio']:.2f}x",
            row["baseline"] if row["baseline"] != row["variant"] else "(baseline)",
            _fmt(row.get("peak_mb", math.nan)),
            _fmt(row.get("peak_actor_mb", math.nan)),
            _fmt(row.get("peak_tree_mb", math.nan)),
        )
        for row in rows
    ]
    widths = [max(len(str(x)) for x in col) for col in zip(header, *lines, strict=True)]
    right = {2, 4, 6, 7, 8}

    def fmt_line(cells: Sequence[str]) -> str:
        return "  ".join(
            c.rjust(w) if i in right else c.ljust(w)
            for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ).rstrip()

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([fmt_line(header), rule, *(fmt_line(line) for line in lines)])


def bench_inputs(
    cases: Sequence[str], sizes: Sizes, made: dict[str, Any] | None = None
) -> dict[str, Any]:
    """What the run read: the record (path, digest, episodes) of the demonstration set a case
    read, from the case file's ``dataset_read(sizes)`` where it has one (the ``stream`` case's
    source set); the other cases make their own inputs (synthetic frames, untrained nets
    seeded by ``--seed``, seeded tracks), so ``demos`` is ``None`` when no case read a set, and
    ``made`` holds, per case that names them, the digests of the inputs it made."""
    for case in cases:
        read = getattr(case_module(case), "dataset_read", None)
        record = read(sizes) if read is not None else None
        if record is not None:
            return {"demos": record}
    out: dict[str, Any] = {"demos": None}
    out["made"] = "synthetic frames, seeded untrained nets, seeded tracks"
    if made:
        out["made_digests"] = made
    return out


def write_results(
    rows: Sequence[dict[str, Any]], out: Path, settings: dict[str, Any]
) -> pd.DataFrame:
    """Write the table to ``out`` (Parquet) with machine info and provenance as metadata."""
    import pandas as pd

    from safe_bc.data.provenance import provenance
    from safe_bc.data.store import write_table_atomic

    frame = pd.DataFrame(list(rows), columns=list(COLUMNS))
    metadata = {
        "benchmark": "benchmarks.bench",
        "settings": settings,
        "machine": machine_info(),
        "provenance": provenance(),
        "memory_notes": MEMORY_NOTES,
        "ratio": "median(variant runs) / median(baseline runs), same process, interleaved",
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    write_table_atomic(out, frame, metadata)
    return frame


# ----------------------------------------------------------------------------------- CLI


def _parse_cases(text: str) -> list[str]:
    cases = [c.strip() for c in text.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown or not cases:
        raise argparse.ArgumentTypeError(
            f"unknown case(s) {unknown or text!r}; choose from {', '.join(CASES)}"
        )
    return cases


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.bench", description=(__doc__ or "").splitlines()[0]
    )
    parser.add_argument("--quick", action="store_true", help="small sizes (used by the tests)")
    parser.add_argument("--repeats", type=int, default=None, help="repetitions (3; quick: 2)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="Parquet output path")
    parser.add_argument(
        "--cases", type=_parse_cases, default=list(CASES), help=f"subset of {','.join(CASES)}"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--case", choices=CASES, help="run one case in this process")
    parser.add_argument("--json", action="store_true", help="with --case: print JSON only")
    return parser


def _run_one(args: argparse.Namespace, sizes: Sizes, repeats: int) -> int:
    """``--case X``: run it here; JSON on stdout with ``--json`` (everything else to stderr)."""
    with contextlib.redirect_stdout(sys.stderr):
        result = run_case(args.case, sizes, repeats, args.seed)
    if args.json:
        print(json.dumps(result))
    else:
        print(format_table(_rows_with_memory(result)))
    return 0


def _run_all(args: argparse.Namespace, sizes: Sizes, repeats: int) -> int:
    """Every selected case in its own subprocess; print and write the table."""
    rows: list[dict[str, Any]] = []
    seconds: dict[str, float] = {}
    made: dict[str, Any] = {}
    failed: list[str] = []
    start = time.perf_counter()
    for case in args.cases:
        print(f"bench: {case} ...", file=sys.stderr, flush=True)
        try:
            result = run_case_subprocess(case, args.quick, repeats, args.seed)
        except (RuntimeError, subprocess.TimeoutExpired, json.JSONDecodeError) as e:
            print(f"bench: {case} failed: {e}", file=sys.stderr)
            failed.append(case)
            continue
        rows += _rows_with_memory(result)
        seconds[case] = result["seconds"]
        if result.get("inputs"):
            made[case] = result["inputs"]
    settings = {
        "quick": args.quick,
        "repeats": repeats,
        "seed": args.seed,
        "cases": args.cases,
        "failed_cases": failed,
        "sizes": asdict(sizes),
        "case_seconds": seconds,
        "total_seconds": time.perf_counter() - start,
        "argv": sys.argv[1:],
        "inputs": bench_inputs(args.cases, sizes, made),
    }
    if rows:
        from safe_bc.data.provenance import DirtyTreeError

        print(format_table(rows))
        try:
            write_results(rows, args.out, settings)
        except DirtyTreeError as e:  # the tree changed during the run: keep the rows elsewhere
            kept = Path(tempfile.mkdtemp(prefix="safe-bc-bench-")) / args.out.name
            write_results(rows, kept, settings)
            print(f"bench: {e}\nbench: the measurements are kept in {kept}", file=sys.stderr)
            return 2
        print(f"\nwrote {args.out} ({settings['total_seconds']:.0f} s)")
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; the exit status is 1 when a case failed."""
    args = _parser().parse_args(argv)
    sizes = QUICK if args.quick else FULL
    repeats = args.repeats if args.repeats is not None else (2 if args.quick else 3)
    if repeats < 1:
        _parser().error(f"--repeats must be >= 1, got {repeats}")
    if args.case is not None:
        return _run_one(args, sizes, repeats)
    from safe_bc.data.provenance import DirtyTreeError, check_result_write

    try:  # a dirty tree fails now, not after minutes of measuring
        check_result_write(args.out)
    except DirtyTreeError as e:
        print(f"bench: {e}", file=sys.stderr)
        return 2
    return _run_all(args, sizes, repeats)


if __name__ == "__main__":
    sys.exit(main())
