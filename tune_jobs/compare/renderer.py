"""The raster renderer against the exact one, for agents and for the whole pipeline.

* ``renderer``: BC agents trained on exact frames (alpha 0.1, eps 2 px: the CarRacing
  improvement starts' settings; the default network and budget; training seeds 0-2), evaluated
  in the exact env and again (the same agents) in the raster env
  (:mod:`safe_bc.tasks.carracing.raster_render`), both against the exact demonstrations' d_s;
  paired raster - exact on the same (training seed, track) cells.
* ``pipeline``: the same settings with everything on one renderer: the exact pipeline (its
  demonstrations, d_s, training and evaluation exact) against the raster pipeline (the
  task's default collection drawn by the raster renderer, ``data/demos_raster``; the drift's
  release reads the frame's safety distance, so the trajectories may differ slightly).
  Each pipeline's violations count against its own demonstrations' d_s.
* ``pipeline_table1``, ``pipeline_table1_alpha0``: the two pipelines with a Table 1 row's
  settings (selection, network, budget), 8 training seeds and 20 tracks of Table 1's block 0.

``renderer`` and ``pipeline`` run on 20 held-out tracks of block 11. Row names are the keys of
the committed ``results/ablation/renderer/`` tables, which seed the bootstrap. The frames,
safety-cost errors and speeds of the renderers are ``python -m scripts.render_accuracy``.

Run: ``safe-bc compare tune_jobs/compare/renderer.py --name NAME``; writes
``results/ablation/renderer/NAME*``.
"""

from pathlib import Path
from typing import Any

from safe_bc.bc.config import BCConfig
from safe_bc.compare.reproduce import ReproduceConfig
from safe_bc.compare.spec import Agent, Comparison, View
from safe_bc.selection import SelectionConfig

EXACT_DEMOS = Path("data/demos_exact")
"""The default collection drawn by the exact renderer."""
RASTER_DEMOS = Path("data/demos_raster")
"""The default collection drawn by the raster renderer."""
OUT = Path("results/ablation/renderer")
START = SelectionConfig(eps=2.0, alpha=0.1)
"""The CarRacing improvement starts' selection."""
BLOCK11 = ("results/ablation/renderer/renderer", "results/ablation/renderer/pipeline")
"""The tables on block 11."""
BLOCK0 = (
    "results/table1",
    "results/expert/expert_settings",
    "results/ablation/renderer/pipeline_table1",
    "results/ablation/renderer/pipeline_table1_alpha0",
)
"""The tables on Table 1's block 0: the pipelines pair with Table 1's rows on its tracks."""
TABLE1 = ReproduceConfig(train_seeds=tuple(range(8)), episodes=20).comparison()
"""The 8 training seeds x 20 tracks design of Table 1 the pipelines pair with."""


def pipelines(
    name: str, selection: SelectionConfig, bc: BCConfig, title: str, **table: Any
) -> Comparison:
    """The exact and the raster pipeline with the same training settings, and ``table``'s
    fields."""
    return Comparison(
        name=name,
        methods=tuple(
            Agent(f"{r} pipeline", selection, bc=bc, renderer=r, demos=d)
            for r, d in (("exact", EXACT_DEMOS), ("raster", RASTER_DEMOS))
        ),
        task="carracing",
        demos=EXACT_DEMOS,
        out=OUT,
        episodes=20,
        reference="exact pipeline",
        paired_metrics=("reward", "violation_steps"),
        title=title,
        note="Each pipeline's violations count against its own demonstrations' d_s.",
        **table,
    )


def table1_row(row: str) -> tuple[SelectionConfig, BCConfig]:
    """Selection and BC settings of :data:`TABLE1`'s ``row``."""
    method = TABLE1.method(row)
    assert isinstance(method, Agent)
    return method.selection, method.bc or TABLE1.bc


COMPARISONS = (
    Comparison(
        name="renderer",
        methods=(
            Agent(
                "exact",
                START,
                label="exact frames (trained and evaluated)",
                renderer="exact",
                demos=EXACT_DEMOS,
            ),
            View(
                "raster",
                "exact",
                renderer="raster",
                label="same agents, evaluated on raster frames",
            ),
        ),
        task="carracing",
        demos=EXACT_DEMOS,
        out=OUT,
        train_seeds=(0, 1, 2),
        episodes=20,
        eval_seed=11,
        reference="exact",
        paired_metrics=("reward", "violation_steps"),
        title="Agents trained on exact frames, evaluated on exact and on raster frames",
        note="Both rows count violations against the default demonstrations' d_s.",
        shares_tracks_with=BLOCK11,
    ),
    pipelines(
        "pipeline",
        START,
        BCConfig(),
        "Exact pipeline vs raster pipeline (demonstrations, d_s, training, evaluation)",
        train_seeds=(0, 1, 2),
        eval_seed=11,
        shares_tracks_with=BLOCK11,
    ),
    *(
        pipelines(
            name,
            *table1_row(row),
            f"Exact pipeline vs raster pipeline, Table 1's {label} row",
            train_seeds=TABLE1.train_seeds,
            eval_seed=TABLE1.eval_seed,
            shares_tracks_with=BLOCK0,
        )
        for name, row, label in (
            ("pipeline_table1", "alpha=0.1 (rest=all)", "alpha=0.1"),
            ("pipeline_table1_alpha0", "alpha=0 (rest=all)", "alpha=0"),
        )
    ),
)
