"""Training budget of the chosen observation (``bar-nosteer_rgb_k1``): plain BC with 1000,
2000 and 4000 batches, 3 training seeds, the observation ablation's 20 selection tracks.

Run: ``safe-bc compare tune_jobs/compare/observation_budget.py``, then ``python -m
scripts.observation_choice --episodes results/ablation/budget/budget_episodes.parquet --out
results/ablation/budget --name budget --title "Training budget (CarRacing, plain BC)"``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import sibling

obs = sibling(__file__, "observation")

CELL = "bar-nosteer_rgb_k1"
COMPARISON = replace(
    obs.COMPARISON,
    name="budget",
    methods=(
        *(
            r
            for b in (1000, 2000, 4000)
            for r in obs.rows(f"{CELL}@b{b}", obs.all_cells()[CELL], batches=b)
        ),
        obs.COMPARISON.method("expert"),
    ),
    out=Path("results/ablation/budget"),
    reference=f"{CELL}@b2000",
    title="Training budget (CarRacing, plain BC)",
)
