"""The clinic's handover, chosen by measurement: per-dimension widths (heart rate and fatigue
are fractions, blood pressure is in 100 mmHg: one width does not fit all three) and what acts in
the zone (the guideline's prescription, or the agent's capped by it), over the agents of the
rehab recommender the study delivered before it (``results/rehab/handover/recommender/``).

Candidates: heart rate 0.05-0.15 (0.2, the committed width, deferred 26.7% of sessions in the
rehab study's certificate, beyond the 10% limit), fatigue 0.05-0.2, blood pressure 0.2 (the
committed width: within 20 mmHg of d_s is rare), each with either fallback: 24 rows.

Selection: 3 training seeds x 1000 patients of held-out block 60 (no other table uses it), the
same patients for every candidate. Rule, fixed here before the run: among the candidates with
no programme beyond d_s and under 10% of sessions deferred (the study's limit), the fewest
sessions deferred; ties go to the higher reward. The chosen row becomes the task's
``TaskSpec.handover``; the rehab study then certifies it on fresh patients.

Run: ``python -m scripts.handover_choice tune_jobs/handover/rehab.py``; writes
``results/rehab/handover/``.
"""

from pathlib import Path

from safe_bc.compare.handover_choice import HandoverChoice, handover_grid

CHOICE = HandoverChoice(
    name="rehab",
    recommender=Path("results/rehab/handover/recommender"),
    candidates=handover_grid(
        {
            "heart_rate": (0.05, 0.1, 0.15),
            "fatigue": (0.05, 0.1, 0.15, 0.2),
            "blood_pressure": (0.2,),
        },
        fallbacks=("expert", "cap"),
    ),
    eval_seed=60,
    episodes=1000,
    deferred_limit=0.10,
    out=Path("results/rehab/handover"),
)
