"""The clinic's handover, stage 3: the safest session in the zone.

Stages 1 and 2 (``rehab.py``, ``rehab_cap.py``; blocks 60 and 61) found no handover with zero
crossings: in the zone the guideline acted, or capped the agent's prescription, and the
guideline itself crosses ``d_s`` on a few patients (7 of 1000 on block 61), so neither can
promise fewer. The rehab study's certificate with the chosen cap (heart rate 0.1, fatigue 0.2,
blood pressure 0.2) counted 1 of 600 fresh patients beyond ``d_s`` (block 62). Here the zone's
session is the lightest the programme allows instead (``fallback="safest"``: 30% HRR for 10
minutes, each component at its bound in the task's safer direction), at heart-rate widths 0.05
or 0.1, fatigue 0.1 or 0.2, blood pressure 0.1, 0.2 or 0.3 (12 rows), beside the chosen cap
(the 13th row, h12).

Selection: 3 training seeds x 1000 patients of held-out block 66 (new: no other table uses
it), the same patients for every candidate, over the agents of the rehab study's recommender
certified with the cap (block 62; kept in ``results/rehab/handover_safest/recommender/``, its own
handover ignored). Rule, fixed here before the run:
among the candidates with no programme beyond d_s and under 10% of sessions deferred, the
fewest sessions deferred (ties: the higher reward); where none has zero, among those under 10%
the fewest programmes beyond d_s, then the fewest deferred. The chosen row becomes the task's
``TaskSpec.handover``; the rehab study then certifies it on fresh patients (block 67).

Run: ``python -m scripts.handover_choice tune_jobs/handover/rehab_safest.py``; writes
``results/rehab/handover_safest/``.
"""

from pathlib import Path

from safe_bc.compare.handover_choice import HandoverChoice, handover_grid
from safe_bc.handover import HandoverConfig

CHOSEN_CAP = HandoverConfig(
    0.2, widths=(("heart_rate", 0.1), ("fatigue", 0.2), ("blood_pressure", 0.2)), fallback="cap"
)
"""Stage 2's choice, measured again beside the new rows."""

CHOICE = HandoverChoice(
    name="rehab_safest",
    recommender=Path("results/rehab/handover_safest/recommender"),
    candidates=(
        *handover_grid(
            {
                "heart_rate": (0.05, 0.1),
                "fatigue": (0.1, 0.2),
                "blood_pressure": (0.1, 0.2, 0.3),
            },
            fallbacks=("safest",),
        ),
        CHOSEN_CAP,
    ),
    eval_seed=66,
    episodes=1000,
    deferred_limit=0.10,
    out=Path("results/rehab/handover_safest"),
    rule="fewest_deferred_else_fewest_beyond",
)
