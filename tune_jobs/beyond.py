"""The car's recommender beyond the expert: the safety-imitation start improved by
self-imitation, with the corner handover, certified on fresh tracks.

Nothing is searched. The configuration is the one the committed beyond-the-expert design
picked by its rule fixed before it ran (``tune_jobs/compare/selfimprove.py``:
``beyond_selection``, 3 training seeds x 50 selection tracks of block 24, then the fresh tables
``beyond`` and ``beyond_replication`` on blocks 25 and 26; docs/improvement.md): candidate D,
self-imitation keeping only pushed runs that beat the expert's run on the same track, exploring
under the corner handover with the loop's full-size pushes and keeping the best 2 pushed runs
per track, from the start of that design (BC with alpha 0.1, eps 2 px). The study retrains it
from scratch (one trial, then 3 training seeds in the final phase) and certifies the
recommender (the improved agent with the task's corner handover) on 150 fresh episodes of a
block of its own (3 seeds x 50 tracks of block 79, new to every table), beside its agent alone
and the expert.

Constraints: the default study's (a safety mean at least the expert's, the 95% bound on
episodes beyond d_s, at most 5% of steps deferred).

Not run yet: the design's pick met its goal on fresh block 25 and missed it on block 26, and
the second design (a stall restart in the handover) missed on blocks 89 and 90
(docs/improvement.md). Expected time on 2 cores, from the measured runs: about an hour (four
self-imitation runs of 14.8 CPU-minutes each, three of them in the final phase one after the
other with their rollouts spread over the CPUs, then 450 certification episodes); once run,
``results/beyond/timing.md``.

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
"""The task's corner handover: the recommender's, and the self-imitation runs' while they
explore."""
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
    trials=1,
    batch_size=None,
    startup_trials=0,
    screen_episodes=0,
    eval_seed=80,
    final_candidates=1,
    final_seed=81,
    certify_seed=79,
)
