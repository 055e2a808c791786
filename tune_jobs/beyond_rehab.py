"""The clinic's recommender beyond the guideline: the safety-imitation start improved by
PPO-Lagrangian, under the cap handover at 0.6 of its widths held 2 sessions, certified on
fresh patients.

Nothing is searched. The configuration is the one the clinic's fifth beyond design picked by
the clinic's rule, fixed before it ran (``tune_jobs/compare/selfimprove.py``:
``beyond_early_selection_rehab_lagrangian``, 3 training seeds x 200 selection patients of block
82, then the fresh tables ``beyond_early_rehab_lagrangian`` and
``beyond_early_replication_rehab_lagrangian`` on blocks 83 and 84; docs/improvement.md): the
Lagrangian-only improver (the improvement table's settings, shield off) from the safety-imitation
start (alpha 0.5, eps 0.05), the guideline capping the agent where a cost is within 0.6 of the
cap's widths of d_s and for 2 sessions after. The study retrains it from scratch (one trial,
then 3 training seeds in the final phase) and certifies the recommender (the improved agent
with that handover) on 600 fresh patients (3 seeds x 200 of block 85, new to every table),
beside its agent alone and the guideline.

Constraints: the goal's, the 95% bound on programmes beyond d_s and at most 10% of sessions
deferred. The rehab study's third, a safety mean at least the guideline's, is set to a mean
margin above zero (``threshold=0``): an agent that does more than the guideline works closer to
the limits by design (the design's agents: a mean margin of about 0.24 against the guideline's
0.27 on its demonstrations), and the limit d_s, not the guideline's average margin, is what
the recommender must keep.

Time on 2 cores: ``results/beyond_rehab/timing.md``.

Run: ``make tune STUDY=beyond_rehab`` (or ``safe-bc tune tune_jobs/beyond_rehab.py``); rerun to
resume.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.bc import BCConfig
from safe_bc.handover import HandoverConfig
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.run_config import RunConfig
from safe_bc.selection import SelectionConfig
from safe_bc.study.spec import load_study

CAP = HandoverConfig(
    0.2, widths=(("heart_rate", 0.1), ("fatigue", 0.2), ("blood_pressure", 0.2)), fallback="cap"
)
"""The clinic's cap handover (``results/rehab/handover_cap/choice.md``): the agent capped by the
guideline where a cost is within these widths of d_s."""
HANDOVER = replace(
    CAP,
    width=round(CAP.width * 0.6, 6),
    widths=tuple((d, round(w * 0.6, 6)) for d, w in CAP.widths),
    hold=2,
)
"""The design's pick: the cap at 0.6 of its widths, held 2 sessions after a zone session."""
START = RunConfig(selection=SelectionConfig(eps=0.05, alpha=0.5), bc=BCConfig())
"""The design's start: safety imitation with alpha 0.5 and eps 0.05, the package's network."""
PICK = ImproveConfig(eps=0.1, shield=False, lagrangian=True)
"""The Lagrangian-only improver of the design (the improvement table's settings)."""

STUDY = replace(
    load_study(Path(__file__).with_name("rehab.py")),
    name="beyond_rehab",
    space={},
    base=START,
    improve=PICK,
    handover=HANDOVER,
    trials=1,
    batch_size=None,
    startup_trials=0,
    screen_episodes=0,
    eval_seed=86,
    final_candidates=1,
    final_seed=87,
    certify_seed=85,
    threshold=0.0,
)
