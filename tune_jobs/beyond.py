"""The car's recommender beyond the expert: the safety-imitation start improved by
self-imitation, with the fourth design's handover, certified on fresh tracks.

Nothing is searched. The configuration is the one the committed beyond-the-expert designs
picked by their rule fixed before they ran (``tune_jobs/compare/selfimprove.py``,
docs/improvement.md). The agent: candidate D of the first design (``beyond_selection``, 3
training seeds x 50 selection tracks of block 24), self-imitation keeping only pushed runs that
beat the expert's run on the same track, exploring under the corner handover with the loop's
full-size pushes and keeping the best 2 pushed runs per track, from that design's start (BC with
alpha 0.1, eps 2 px). The handover: the fourth design's pick (``beyond_lean_selection``, block
94; met the goal on fresh blocks 97 and 98), the corner zone looking 3 steps ahead instead of
6, the expert restarting a car that stood still 20 steps (for 100 steps) and driving 50 steps
where the car's speed stayed below 30 for 10 steps. The study retrains the agent from scratch
(one trial, then 3 training seeds in the final phase) and certifies the recommender (the
improved agent with that handover) on 150 fresh episodes of a block of its own (3 seeds x 50
tracks of block 79, new to every table), beside its agent alone and the expert.

Constraints: the default study's (a safety mean at least the expert's, the 95% bound on
episodes beyond d_s, at most 5% of steps deferred).

Time on 2 cores: ``results/beyond/timing.md``.

Run: ``make tune STUDY=beyond`` (or ``safe-bc tune tune_jobs/beyond.py``); rerun to resume.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.bc import BCConfig
from safe_bc.methods.selfimprove.config import LOOP_PUSHES, SelfImproveConfig
from safe_bc.run_config import RunConfig
from safe_bc.selection import SelectionConfig
from safe_bc.study.spec import load_study
from safe_bc.tasks import task_defaults

CORNER = task_defaults("carracing").handover
"""The task's corner handover: the self-imitation runs' while they explore."""
HANDOVER = replace(
    CORNER, lookahead=3, stall=20, stall_hold=100, pace=30.0, pace_steps=10, pace_hold=50
)
"""The recommender's: the fourth design's pick (``pace30_look3``)."""
START = RunConfig(selection=SelectionConfig(eps=2.0, alpha=0.1), bc=BCConfig())
"""The design's start: safety imitation with alpha 0.1 and eps 2 px, the package's network."""
PICK = SelfImproveConfig(
    keep_against="expert", handover=CORNER, pushes=LOOP_PUSHES["carracing"], keep_best=2
)
"""Candidate D of the design (the rule's pick on the selection tracks)."""

STUDY = replace(
    load_study(Path(__file__).with_name("default.py")),
    name="beyond",
    space={},
    base=START,
    selfimprove=PICK,
    handover=HANDOVER,
    trials=1,
    batch_size=None,
    startup_trials=0,
    screen_episodes=0,
    eval_seed=80,
    final_candidates=1,
    final_seed=81,
    certify_seed=79,
)
