"""Agents trained on exact frames, driving on approximate ones (raster renderer).

Rows: the safety-imitation start of ``improve_carracing.py`` (BC with alpha 0.1, eps 2 px, the
default network and budget; training seeds 0-2) evaluated in the exact env (``renderer``
exact, formerly fast,
pixel-identical to gymnasium's), and the same agents (``agents_of``) evaluated in the raster
env (:mod:`safe_bc.tasks.carracing.raster_render`, the supersample factor chosen by
``python -m benchmarks.render_accuracy``); both against the default demonstrations' d_s, on
the same 20 held-out tracks (seed block 11). Paired raster - exact on the same (training seed,
track) cells. Row names are the keys of the committed ``results/ablation/renderer/
episodes.parquet`` (its ``renderer`` column), which seed the bootstrap;
``tests/test_compare_renderer.py`` re-derives its ``paired.parquet`` through this spec.

Run: ``safe-bc compare tune_jobs/compare/renderer.py``. Writes
``results/ablation/renderer/renderer*.parquet`` and ``renderer.md``. The frames, safety-cost
errors and speeds of the renderers are ``python -m benchmarks.render_accuracy``; the whole
pipeline on the raster renderer is ``renderer_pipeline.py``.
"""

from pathlib import Path

from safe_bc.compare import Comparison, Method
from safe_bc.selection import SelectionConfig

EXACT_DEMOS = Path("data/demos_exact")
"""The default collection drawn by the exact renderer (the committed tables used
``data/demos`` when ``exact``, then called ``fast``, was the default: the same episodes)."""

COMPARISON = Comparison(
    name="renderer",
    methods=(
        Method(
            "exact",
            selection=SelectionConfig(eps=2.0, alpha=0.1),
            label="exact frames (trained and evaluated)",
            renderer="exact",
            demos=EXACT_DEMOS,
        ),
        Method(
            "raster",
            agents_of="exact",
            renderer="raster",
            label="same agents, evaluated on raster frames",
        ),
    ),
    task="carracing",
    demos=EXACT_DEMOS,
    out=Path("results/ablation/renderer"),
    train_seeds=(0, 1, 2),
    episodes=20,
    eval_seed=11,
    reference="exact",
    paired_metrics=("reward", "violation_steps"),
    title="Agents trained on exact frames, evaluated on exact and on raster frames",
    note="Both rows count violations against the default demonstrations' d_s.",
)
