"""Beyond the expert on the rehabilitation pathway: 3 seeds x 3 modes, 200 held-out patients.

Rows: the guideline clinician (the expert; the paired columns' reference, standing in for
every training seed on the same patients); the safety-imitation start (BC with alpha 0.5);
one :func:`safe_bc.improve.improve` run per mode from each seed's start (``shield``,
``lagrangian``, ``both``) with the rehab defaults and a shield zone of :data:`SHIELD_EPS`.
Every policy on the same 200 fresh held-out patients (seed block 5). The evaluation path
counts the sessions whose outcome went beyond d_s, the last session included
(``violating_sessions``, ``any_violating_session``, ``last_session_violation``); its
``violation_steps`` scores the state before each session and misses the last outcome.
Row names are the keys of the committed tables (``results/improve/rehab/episodes.parquet``),
which seed the bootstrap; ``tests/test_compare_improve.py`` re-derives their summary through
this spec.

Run: ``safe-bc compare tune_jobs/compare/improve_rehab.py`` (about an hour on 2 cores;
resumes per method and seed). Writes ``results/improve/rehab/improve*.parquet``,
``improve.md`` and ``learning_curves.png``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare import Comparison, Method
from safe_bc.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig

SHIELD_EPS = 0.1
"""Width of the shield's critical zone on the rehab pathway (``ImproveConfig.eps``; the
start's selection eps, 0.05, when unset): the margin sweep's choice, shield + Lagrangian with
``cost_margin`` 0.05 and this zone (``results/improve/rehab/sweep/margin_sweep.md``)."""
BASE = ImproveConfig(eps=SHIELD_EPS)
MODES = {  # name: (label, shield, lagrangian)
    "shield": ("shield only", True, False),
    "lagrangian": ("Lagrangian only", False, True),
    "both": ("shield + Lagrangian", True, True),
}

COMPARISON = Comparison(
    name="improve",
    methods=(
        Method("expert", expert=True, label="guideline clinician (expert)"),
        Method(
            "imitation",
            selection=SelectionConfig(eps=0.05, alpha=0.5),
            label="safety-imitation start",
        ),
        *(
            Method(
                name,
                improve=replace(BASE, shield=shield, lagrangian=lagrangian),
                start="imitation",
                label=label,
            )
            for name, (label, shield, lagrangian) in MODES.items()
        ),
    ),
    task="rehab",
    demos=Path("data/rehab_demos"),
    out=Path("results/improve/rehab"),
    train_seeds=(0, 1, 2),
    episodes=200,
    eval_seed=5,
    workers=0,
    reference="expert",
    paired_metrics=("reward", "violating_sessions"),
    totals=("any_violating_session", "last_session_violation", "violation_steps"),
    figures=(("learning_curves", "learning_curves.png"),),
    title="Beyond the expert: constrained improvement on the rehabilitation pathway",
    note="Reward: capacity gain (points). minutes / run: wall time of one improvement run.",
)
