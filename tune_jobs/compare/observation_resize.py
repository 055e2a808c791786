"""Frame size for the chosen observation (``bar-nosteer_rgb_k1``): plain BC on the full 96x96
frame (the default), resized to 64x64 and to 48x48 (area interpolation), 3 training seeds, the
observation ablation's 20 selection tracks (block 10). A smaller frame is the lever for
training cost (a single-thread training step on 64x64 frames took about half
the time of 96x96 in an indicative measurement); this table says what it costs in outcomes.

Run: ``safe-bc compare tune_jobs/compare/observation_resize.py``, then ``python -m
scripts.observation_choice --episodes results/ablation/resize/resize_episodes.parquet --out
results/ablation/resize --name resize --title "Frame size (CarRacing, plain BC)"``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import sibling

obs = sibling(__file__, "observation")

CELL = "bar-nosteer_rgb_k1"
SIZES = (None, 64, 48)
"""``PreprocessConfig.resize`` of each row (``None``: the full frame)."""


def name(size: int | None) -> str:
    return CELL if size is None else f"{CELL}@r{size}"


COMPARISON = replace(
    obs.COMPARISON,
    name="resize",
    methods=(
        *(
            r
            for size in SIZES
            for r in obs.rows(name(size), replace(obs.all_cells()[CELL], resize=size))
        ),
        obs.COMPARISON.method("expert"),
    ),
    out=Path("results/ablation/resize"),
    reference=CELL,
    title="Frame size (CarRacing, plain BC)",
)
