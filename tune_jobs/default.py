"""The default study: eps, alpha, the eq. 5 reading, network, learning rate, batch size and
preprocessing, searched by constrained TPE for the highest mean reward with a safety mean at
least the expert's (on its demonstrations).

Budget: 20 trials, 2 at a time with 1 CPU each, 2000 training batches (the paper's budget)
and 3 held-out episodes per trial; then the winner, the alpha = 0 baseline (same network)
and the expert on 20 fresh held-out episodes each. A trial with the default network takes
about 2-3.5 minutes on a busy 2-core box (see the study's ``trials.parquet`` for measured
durations); the space leaves out the costliest settings (32-64-64 channels, batch 128,
4 stacked frames: 3-14x slower to train) to keep the study near 30 minutes.

Run: ``make tune`` (or ``safe-bc tune tune_jobs/default.py``); rerun to resume.
"""

from safe_bc.study import Choice, Float, StudySpec

STUDY = StudySpec(
    name="default",
    space={
        "selection.eps": Float(1.0, 15.0),
        "selection.alpha": Float(0.0, 1.0),
        "selection.rest": Choice(("all", "noncritical")),
        "bc.network.channels": Choice(((8, 16, 16), (16, 32, 32))),
        "bc.network.hidden": Choice((64, 128, 256)),
        "bc.train.lr": Float(1e-4, 3e-3, log=True),
        "bc.train.batch_size": Choice((32, 64)),
        "bc.preprocess.frame_stack": Choice((1, 2)),
        "bc.preprocess.grayscale": Choice((True, False)),
    },
    trials=20,
    max_concurrent=2,
    cpus_per_trial=1.0,
    batches=2000,
    eval_episodes=3,
    eval_seed=1,
    final_episodes=20,
    final_seed=2,
    startup_trials=8,
)
