"""Batch size for the chosen observation (``bar-nosteer_rgb_k1``): plain BC with 2,000
batches of 64 (the default, ``results/ablation/budget/``) and of 32, 3 training seeds, the
observation ablation's 20 selection tracks (block 10), raster frames.

Why: a training step at batch 32 costs about 0.6x one at batch 64
(``results/checks/make_tune/floor.md``), and the default study searches both; `make tune` can
reach half its old wall-clock within the study's requirements only if its trials train
cheaper. This table says what the cheaper batch costs in outcomes before the study drops the
other.

Run: ``safe-bc compare tune_jobs/compare/observation_batch.py``, then ``python -m
scripts.observation_choice --episodes results/ablation/batch/batch_episodes.parquet --out
results/ablation/batch --name batch --title "Batch size (CarRacing, plain BC)"``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import sibling

obs = sibling(__file__, "observation")

CELL = "bar-nosteer_rgb_k1"
SIZES = (64, 32)
"""``TrainConfig.batch_size`` of each row (64: the default)."""


def name(size: int) -> str:
    return CELL if size == 64 else f"{CELL}@bs{size}"


def _rows(size: int) -> list:
    rows = obs.rows(name(size), obs.all_cells()[CELL])
    bc = rows[0].bc
    return [replace(rows[0], bc=replace(bc, train=replace(bc.train, batch_size=size))), *rows[1:]]


COMPARISON = replace(
    obs.COMPARISON,
    name="batch",
    methods=(*(r for size in SIZES for r in _rows(size)), obs.COMPARISON.method("expert")),
    out=Path("results/ablation/batch"),
    reference=CELL,
    title="Batch size (CarRacing, plain BC)",
)
