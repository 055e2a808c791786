"""The rehabilitation pathway with the improvement stage: the best *safe* improver.

Every trial trains the safety-imitation agent of ``improve_rehab`` in
``tune_jobs/compare/improve.py`` (alpha 0.5, eps 0.05, 2000 batches), improves it by
constrained RL (``safe_bc.methods.improve``, a
short run: 100 iterations of 32 patients, half the patients per iteration of that comparison
and half its iterations) and is evaluated as an improved agent under the study's usual
constraints (safety mean at least the guideline clinician's, no session beyond ``d_s``).
Searched: the improvement's safety margin inside ``d_s``, its BC anchor, the multiplier's step
size and whether the critical-state shield is on.

Budget: 8 trials, 2 at a time, each screened on 5 simulated patients and evaluated on 20;
the top 3 are retrained and re-improved with 3 seeds each and re-evaluated on 102 fresh
patients beside plain BC and the guideline. About 10 minutes on 2 CPU cores (40 iterations:
4.5 minutes, and the winner stayed below the guideline; see ``results/rehab_improve``).

Run: ``make tune STUDY=rehab_improve`` (or ``safe-bc tune tune_jobs/rehab_improve.py``);
rerun to resume.
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.bc import BCConfig
from safe_bc.methods.improve import ImproveConfig
from safe_bc.run_config import RunConfig
from safe_bc.selection import SelectionConfig
from safe_bc.study.spec import Choice, Float, load_study
from safe_bc.tasks import task_defaults

# the rehab study's environment, demonstrations and evaluation budget; its own search space,
# start and improvement stage
STUDY = replace(
    load_study(Path(__file__).with_name("rehab.py")),
    name="rehab_improve",
    space={
        "improve.cost_margin": Float(0.02, 0.15),
        "improve.anchor_coef": Float(0.3, 3.0, log=True),
        "improve.lambda_lr": Float(0.05, 0.3, log=True),
        "improve.shield": Choice((False, True)),
    },
    base=RunConfig(
        selection=SelectionConfig(eps=task_defaults("rehab").eps, alpha=0.5), bc=BCConfig()
    ),
    improve=ImproveConfig(
        shield=False,
        iterations=100,
        episodes_per_iter=32,
        n_envs=32,
        eval_every=10,
        eval_episodes=64,
        checkpoint_every=10,
    ),
    trials=8,
    startup_trials=4,
)
