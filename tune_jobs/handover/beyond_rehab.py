"""The clinic's beyond-the-guideline handover, measured again over the agents the study
certified.

The study ``tune_jobs/beyond_rehab.py`` (PPO-Lagrangian from the safety-imitation start, the
guideline capping it within 0.6 of the cap's widths of d_s and for 2 sessions after) certified
its recommender on 600 fresh patients of block 85 with 1 programme beyond d_s (a blood-pressure
excursion of 0.002 on one patient of seed 1, where the agent alone went 0.028 beyond and the
guideline stayed inside), 4.0% of sessions deferred: the goal (0 of >= 600) missed by one
patient. The handover was chosen on the design's agents; the study's agents, retrained on this
CPU type, differ. Here the candidates run over the agents the study certified (copied, with
their certificate, to ``results/beyond_rehab/handover/recommender/``; their own handover
ignored): the cap at 0.6, 0.8 or 1.0 of its widths, held 2 or 3 sessions after a zone session
(6 rows; the certified handover is the first).

Selection: 3 training seeds x 200 patients of held-out block 99 (new: no other table uses it),
the same patients for every candidate. Rule, fixed here before the run: among the candidates
with no programme beyond d_s and under 10% of sessions deferred, the highest lower bound of the
paired reward interval against the guideline (ties: fewer sessions deferred); none qualifies:
none. A chosen row would have become the study's handover, certified on fresh patients (block
100). None qualified (``results/beyond_rehab/handover/choice.md``): the study's handover stays.

Run: ``python -m scripts.handover_choice tune_jobs/handover/beyond_rehab.py``; writes
``results/beyond_rehab/handover/``.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.compare.handover_choice import HandoverChoice
from safe_bc.handover import HandoverConfig

CAP = HandoverConfig(
    0.2, widths=(("heart_rate", 0.1), ("fatigue", 0.2), ("blood_pressure", 0.2)), fallback="cap"
)
"""The clinic's cap handover (``results/rehab/handover_cap/choice.md``)."""


def scaled(factor: float, hold: int) -> HandoverConfig:
    """The cap at ``factor`` of its widths, held ``hold`` sessions after a zone session."""
    return replace(
        CAP,
        width=round(CAP.width * factor, 6),
        widths=tuple((d, round(w * factor, 6)) for d, w in CAP.widths),
        hold=hold,
    )


CHOICE = HandoverChoice(
    name="beyond_rehab",
    recommender=Path("results/beyond_rehab/handover/recommender"),
    candidates=tuple(scaled(f, h) for f in (0.6, 0.8, 1.0) for h in (2, 3)),
    eval_seed=99,
    episodes=200,
    deferred_limit=0.10,
    out=Path("results/beyond_rehab/handover"),
    rule="best_lower_bound",
)
