"""The default study: eps, alpha, the eq. 5 reading, network, learning rate and batch size,
searched by constrained TPE for the highest 90% lower confidence bound on reward (one training
seed per trial, bootstrap over its tracks) subject to two constraints: a safety mean at least
the expert's on its (safe) demonstrations, and a 95% Clopper-Pearson upper bound of at most 20%
on the share of episodes with a step beyond the expert's limit d_s in any dimension (a trial's
15 tracks must all stay within d_s to be feasible: zero crossings in 15 bound the share at
18.1%; the final phase's 51 episodes, 17 fresh tracks per seed, may hold at most 5 beyond d_s).
One seed per trial, 15 tracks per surviving trial and 4 tracks stepped in lockstep with one
batched forward pass (``trial_envs``) replaced 2 seeds x 10 tracks one env at a time for
``make tune`` at half the wall-clock of the two-seed design on 2 cores, measured side by
side in one session (``results/checks/make_tune/half/side_by_side.md``); the seed spread then
enters in the final phase only (3 training seeds per candidate). What the change did to the
study's outcome, replicate against replicate: ``results/checks/make_tune/half/replicates.md``
(the two-seed design's runs: ``results/default_two_seeds/``, ``tune_jobs/default_two_seeds.py``).
(Also requiring every dimension's mean to reach the expert's, ``safety_constraint="per_dim"``,
is not used: no policy of Table 1, the expert included, reaches it; see
``StudySpec.safety_constraint``.)

Budget: 16 trials (each 1 training seed, 1 CPU), 2000 training batches (the paper's
budget), suggested in 2 batches of 8: a trial's settings depend on the batches before it,
never on how many trials run at once, which is as many as the cluster's CPUs allow (2 on a
2-core laptop, 8 on 16 CPUs; ``--max-concurrent`` caps it). Batch 8 was chosen by
``results/checks/batch_schedule.md`` (``python -m scripts.cluster_schedule``, the committed
runs replayed): +1% wall-clock against batches of 2 on 2 cores, 2.5x the trial rate on 16
CPUs, TPE still suggests 8 of the 16 trials (batches of 16: a random search without
screening); how much worse TPE's picks get with 8 instead of ~10 results is not measured.
Each trial is screened on 3 held-out tracks; successive halving stops the weaker half,
the others are evaluated on 15 tracks in all. Then the top 3 feasible trials are retrained
with 3 training seeds each and re-evaluated on 51 fresh tracks (17 per seed) beside plain BC
(same seeds) and the expert, on every CPU of the cluster, and the winner is chosen on that
re-evaluation. The space leaves out the costliest settings (32-64-64 channels, batch 128:
slower to train) to keep it affordable on 2 cores (its wall-clock is in the README).
The observation is not searched: trials see ``PreprocessConfig``'s default (colour, the
indicator bar kept with its steering indicator masked, one frame), which the observation
ablation chose (``results/ablation/observation/``: grey and stacked frames crossed d_s more often).

The study delivers a recommender (``results/default/recommender/``, ``safe_bc.load_recommender``):
every agent is evaluated with the task's critical-zone handover (``TaskSpec.handover``: the
expert acts where the cost extrapolated 6 steps is within 2 px of d_s, held 6 steps after a
front-distance handover; fixed by the committed measurement
``results/selfimprove/carracing/defer_corner_selection.md``, not searched), its mean share of
deferred steps is a third constraint (at most 5%, the measured handover's 4.1-4.3% with room),
and the winner is certified on 150 fresh episodes of a block of its own (3 seeds x 50 tracks of
block 30: zero crossings in 150 bound the share at 2.0%, 95% one-sided), with its agent alone
and the expert on the same tracks.

Run: ``make tune`` (or ``safe-bc tune tune_jobs/default.py``); rerun to resume.
"""

from safe_bc.study.spec import Choice, Float, StudySpec
from safe_bc.tasks import task_defaults

STUDY = StudySpec(
    name="default",
    space={
        "selection.eps": Float(0.5, 4.0),
        "selection.alpha": Float(0.0, 1.0),
        "selection.rest": Choice(("all", "noncritical")),
        "bc.network.channels": Choice(((8, 16, 16), (16, 32, 32))),
        "bc.network.hidden": Choice((64, 128, 256)),
        "bc.train.lr": Float(1e-4, 3e-3, log=True),
        "bc.train.batch_size": Choice((32, 64)),
    },
    trials=16,
    batch_size=8,
    cpus_per_trial=1.0,
    batches=2000,
    eval_episodes=15,
    screen_episodes=3,
    eval_seed=1,
    final_episodes=50,
    final_candidates=3,
    final_train_seeds=3,
    final_seed=2,
    startup_trials=6,
    train_seeds=1,
    trial_envs=4,
    reward_bound=0.9,
    violation_bound=0.95,
    violation_share_limit=0.2,
    handover=task_defaults("carracing").handover,
    deferred_share_limit=0.05,
    certify_episodes=150,
    certify_seed=30,
)
