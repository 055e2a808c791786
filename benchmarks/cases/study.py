"""The ``study`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from benchmarks.bench import (
    Sizes,
    _order,
    _row,
    _self_row,
)


class _TrialClock:
    """Tune callback: wall time from the first trial's start to the last trial's end."""

    def __init__(self) -> None:
        self.first: float | None = None
        self.last = 0.0
        self.done = 0

    def setup(self, **info: Any) -> None:
        """Tune calls this before the experiment starts (nothing to do)."""

    def __getattr__(self, name: str) -> Any:  # every other Tune callback hook: a no-op
        if name.startswith("on_") or name in ("get_state", "set_state"):
            return lambda *args, **kwargs: None
        raise AttributeError(name)

    def on_trial_start(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        if self.first is None:
            self.first = time.perf_counter()

    def on_trial_complete(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        self.last = time.perf_counter()
        self.done += 1


def _bench_collect(seed: int) -> Any:
    """The study cases' collection: two short real CarRacing episodes."""
    from safe_bc.rollout.collect import CollectConfig

    return CollectConfig(episodes=2, workers=2, max_steps=150, seed=seed)


def _bench_demos(root: Path, seed: int) -> Path:
    """:func:`_bench_collect`'s demonstrations under ``root``."""
    from safe_bc.distributed.collect import collect

    out = root / "demos"
    collect(_bench_collect(seed), out, progress=False)
    return out


def _tiny_study(root: Path, demos: Path, sizes: Sizes, concurrent: int, seed: int) -> Any:

    from safe_bc.study.spec import load_study

    repo = Path(__file__).resolve().parents[1]
    smoke = load_study(repo / "tune_jobs" / "smoke.py")
    return replace(
        smoke,
        name=f"bench_c{concurrent}",
        demos=demos,
        collect=_bench_collect(seed),
        storage=str(root / "ray"),
        results=root / "results",
        trials=sizes.study_trials,
        batches=sizes.study_batches,
        max_concurrent=concurrent,
        screen_episodes=0,
        eval_episodes=1,
        max_steps=sizes.eval_steps,
        final_candidates=1,
        final_train_seeds=1,
        final_episodes=1,
        final_workers=0,
        sampler_seed=seed,
    )


def bench_study(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """Trials/min of the study's tuning loop (a tiny study) at 1 vs 2 concurrent trials."""
    from safe_bc.distributed.runtime import ensure_ray
    from safe_bc.study.run import run_study

    ensure_ray()
    rates: dict[int, list[float]] = {1: [], 2: []}
    with tempfile.TemporaryDirectory(prefix="bench-study-") as tmp:
        demos = _bench_demos(Path(tmp), seed)
        for rep in range(repeats):
            for concurrent in _order([1, 2], rep):
                clock = _TrialClock()
                spec = _tiny_study(Path(tmp) / f"r{rep}", demos, sizes, concurrent, seed)
                run_study(spec, fresh=True, progress=False, callbacks=[clock])
                assert clock.first is not None and clock.done == spec.trials
                rates[concurrent].append(60.0 * clock.done / (clock.last - clock.first))
    note = (
        f"tune_jobs/smoke.py shrunk: {sizes.study_trials} trials x {sizes.study_batches} "
        f"batches, 1 eval episode of <= {sizes.eval_steps} steps, 1 CPU per trial; first trial "
        "start to last trial end (the final phase excluded)"
    )
    return [
        _self_row("study", "1 concurrent trial", rates[1], "trials/min", note),
        _row(
            "study",
            "2 concurrent trials",
            rates[2],
            "trials/min",
            ("1 concurrent trial", rates[1]),
            note,
        ),
    ]
