"""Driving styles of the scripted CarRacing expert, on the same held-out tracks.

``expert_settings``: the expert of the default demonstrations (``ExpertConfig()``, the cautious
style, the reference) and expert rows with their own ``ExpertConfig``: less corner braking
(``caution`` 0.8, and 0.65, which plans with the full grip of the car) and a higher speed cap
on straights. Every row runs through the one evaluation path (unperturbed, as agents are) on
the same 20 held-out tracks of block 0 (the defaults were tuned on demonstration tracks
only), violations counted against the default demonstrations' d_s; paired columns: each
setting minus the default on the same tracks. The expert under the collection's drift
perturbation is the release sweep's (``python -m safe_bc.rollout.release_sweep``).

Run: ``safe-bc compare tune_jobs/compare/expert.py``. Writes
``results/expert/expert_settings*.parquet`` and ``expert_settings.md``.
"""

from pathlib import Path

from safe_bc.compare.spec import Comparison, Expert
from safe_bc.tasks.carracing.expert import ExpertConfig

COMPARISONS = (
    Comparison(
        name="expert_settings",
        methods=(
            Expert("expert", label="default (cautious) expert"),
            Expert("caution=0.8", ExpertConfig(caution=0.8)),
            Expert("caution=0.65", ExpertConfig(caution=0.65), label="caution=0.65 (full grip)"),
            Expert("max_speed=80", ExpertConfig(max_speed=80.0)),
        ),
        task="carracing",
        out=Path("results/expert"),
        episodes=20,
        eval_seed=0,
        reference="expert",
        totals=("any_violation",),
        title="Scripted CarRacing expert: driving styles on the same held-out tracks",
        note="Every row is the scripted expert (privileged: it reads the track), one episode "
        "per track.",
        shares_tracks_with=("results/table1",),
    ),
)
