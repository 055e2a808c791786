"""Network width for the chosen observation (``bar-nosteer_rgb_k1``): plain BC with conv
channels 8-16-16, 16-32-32 (the default) and 32-64-64, 3 training seeds, the observation
ablation's 20 selection tracks.

Run: ``safe-bc compare tune_jobs/compare/observation_network.py``, then ``python -m
scripts.observation_choice --episodes results/ablation/network/network_episodes.parquet --out
results/ablation/network --name network --title "Network width (CarRacing, plain BC)"``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import sibling

obs = sibling(__file__, "observation")

CELL = "bar-nosteer_rgb_k1"
WIDTHS = ((8, 16, 16), (16, 32, 32), (32, 64, 64))
COMPARISON = replace(
    obs.COMPARISON,
    name="network",
    methods=(
        *(
            r
            for c in WIDTHS
            for r in obs.rows(f"{CELL}@c{'-'.join(map(str, c))}", obs.all_cells()[CELL], channels=c)
        ),
        obs.COMPARISON.method("expert"),
    ),
    out=Path("results/ablation/network"),
    reference=f"{CELL}@c16-32-32",
    title="Network width (CarRacing, plain BC)",
)
