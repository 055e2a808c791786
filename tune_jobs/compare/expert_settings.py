"""Driving styles of the scripted CarRacing expert, on the same held-out tracks.

Rows: the expert recorded in the default demonstrations (``ExpertConfig()``, the cautious
style, the reference) and expert rows with their own ``ExpertConfig``
(``Method.expert_config``): less corner braking (``caution`` 0.8, and 0.65, which plans with
the full grip of the car) and a higher speed cap on straights. Every row is evaluated through
the one evaluation path (unperturbed, as agents are) on the same 20 held-out tracks (seed
block 0; the defaults were tuned on demonstration tracks only), with violations counted
against the default demonstrations' d_s; paired columns: each setting minus the default on
the same tracks. The expert under the collection's drift perturbation is measured by the
release sweep (``python -m safe_bc.tasks.carracing.release_sweep``).

Run: ``safe-bc compare tune_jobs/compare/expert_settings.py``. Writes
``results/expert/expert_settings*.parquet`` and ``expert_settings.md``.
"""

from pathlib import Path

from safe_bc.compare import Comparison, Method
from safe_bc.tasks.carracing.expert import ExpertConfig

COMPARISON = Comparison(
    name="expert_settings",
    methods=(
        Method("expert", expert=True, label="default (cautious) expert"),
        Method("caution=0.8", expert=True, expert_config=ExpertConfig(caution=0.8)),
        Method(
            "caution=0.65",
            expert=True,
            expert_config=ExpertConfig(caution=0.65),
            label="caution=0.65 (full grip)",
        ),
        Method("max_speed=80", expert=True, expert_config=ExpertConfig(max_speed=80.0)),
    ),
    task="carracing",
    out=Path("results/expert"),
    episodes=20,
    eval_seed=0,
    reference="expert",
    totals=("any_violation",),
    title="Scripted CarRacing expert: driving styles on the same held-out tracks",
    note="Every row is the scripted expert (privileged: it reads the track), one episode per "
    "track.",
)
