"""The rehabilitation-pathway study: eps, alpha, the eq. 5 reading and the MLP, searched by
constrained TPE for the highest functional gain with a safety mean (smallest margin to the
heart-rate, fatigue and blood-pressure limits) at least the guideline clinician's.

Budget: 24 trials in batches of 2, as many at once as the CPUs allow (up to the batch);
2000 training batches; each trial is screened on 5 simulated
patients (successive halving stops the weaker half) and evaluated on 20; then the top 3
trials are retrained with 3 seeds each and re-evaluated on 102 fresh patients (34 per seed)
beside plain BC (same seeds) and the guideline, and the winner is chosen there.
Demonstrations: 150 guideline programmes (~4,500 sessions) in ``data/rehab_demos``.

The study delivers a recommender (``results/rehab/recommender/``): every agent is evaluated
with the task's handover (``TaskSpec.handover``: where heart rate is within 0.1, fatigue within
0.1 or blood pressure within 0.2 of d_s the session is the lightest the programme allows, the
setting ``results/rehab/handover_safest/choice.md`` chose), its mean share of deferred
sessions is a constraint at the goal of at most 10%, and the winner is certified on 600 fresh
patients (3 seeds x 200 of block 67, new to every table) beside its agent alone and the
guideline.

Run: ``make tune STUDY=rehab`` (or ``safe-bc tune tune_jobs/rehab.py``); rerun to resume.
"""

from pathlib import Path

from safe_bc.bc import BCConfig, NetworkConfig
from safe_bc.run_config import RunConfig
from safe_bc.selection import SelectionConfig
from safe_bc.study.spec import Choice, Float, StudySpec
from safe_bc.tasks import task_defaults

REHAB = task_defaults("rehab")

STUDY = StudySpec(
    name="rehab",
    space={
        "selection.eps": Float(0.01, 0.2, log=True),
        "selection.alpha": Float(0.0, 1.0),
        "selection.rest": Choice(("all", "noncritical")),
        "bc.network.hidden": Choice((32, 64, 128)),
        "bc.network.mlp_layers": Choice((1, 2, 3)),
        "bc.train.lr": Float(1e-4, 3e-3, log=True),
        "bc.train.batch_size": Choice((32, 64, 128)),
    },
    # selection.eps is searched, so the base's width is never trained with; it is the 2.0
    # that results/rehab/ records as the base's (the study's identity)
    base=RunConfig(SelectionConfig(eps=2.0), BCConfig(network=NetworkConfig(hidden=64))),
    env=REHAB.env,
    demos=Path(REHAB.demos),
    critical_eps=REHAB.eps,
    trials=24,
    cpus_per_trial=1.0,
    batches=2000,
    eval_episodes=20,
    screen_episodes=5,
    eval_seed=1,
    final_episodes=102,
    final_seed=2,
    final_workers=0,
    startup_trials=8,
    handover=REHAB.handover,
    deferred_share_limit=0.10,
    certify_episodes=600,
    certify_seed=67,
)
