"""The clinic's handover, stage 2: the capping handover with wider fatigue and blood-pressure
zones, over the agents of the rehab recommender the study delivered before it
(``results/rehab/handover/recommender/``).

Stage 1 (``rehab.py``, block 60, ``results/rehab/handover/``) found no handover with zero
crossings in 3000 selection programmes; at every pair of widths the cap (the agent's
prescription, no harder than the guideline's in the zone) crossed 1.4-10x less often than handing
the session to the guideline; the fewest crossings (1 of 3000, a blood-pressure crossing) came
with the cap at heart rate 0.1 or 0.15 and fatigue 0.2, 7.8% and 15.9% of sessions deferred.
Candidates here: the cap at heart rate 0.05 or 0.1, fatigue 0.2 or 0.3, blood pressure 0.2, 0.3
or 0.4 (12 rows).

Selection: 3 training seeds x 1000 patients of held-out block 61 (new: no other table uses it),
the same patients for every candidate. Rule, fixed here before the run: among the candidates
with no programme beyond d_s and under 10% of sessions deferred, the fewest sessions deferred
(ties: the higher reward); where none has zero, among those under 10% the fewest programmes
beyond d_s, then the fewest deferred. The chosen row becomes the task's ``TaskSpec.handover``;
the rehab study then certifies it on fresh patients (block 62).

Run: ``python -m scripts.handover_choice tune_jobs/handover/rehab_cap.py``; writes
``results/rehab/handover_cap/``.
"""

from pathlib import Path

from safe_bc.compare.handover_choice import HandoverChoice, handover_grid

CHOICE = HandoverChoice(
    name="rehab_cap",
    recommender=Path("results/rehab/handover/recommender"),
    candidates=handover_grid(
        {
            "heart_rate": (0.05, 0.1),
            "fatigue": (0.2, 0.3),
            "blood_pressure": (0.2, 0.3, 0.4),
        },
        fallbacks=("cap",),
    ),
    eval_seed=61,
    episodes=1000,
    deferred_limit=0.10,
    out=Path("results/rehab/handover_cap"),
    rule="fewest_deferred_else_fewest_beyond",
)
