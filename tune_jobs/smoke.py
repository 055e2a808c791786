"""A tiny study for tests and a quick end-to-end check: 3 trials of 100 batches on small nets,
2 evaluation episodes capped at 100 steps (one screened) (the first 50 CarRacing steps are warm-up).

Run: ``safe-bc tune tune_jobs/smoke.py`` (a few minutes, mostly starting Ray and loading
the demonstrations).
"""

from safe_bc.bc import BCConfig, NetworkConfig
from safe_bc.run_config import RunConfig
from safe_bc.study.spec import Choice, Float, StudySpec

STUDY = StudySpec(
    name="smoke",
    space={
        "selection.eps": Float(0.5, 4.0),
        "selection.alpha": Float(0.0, 1.0),
        "selection.rest": Choice(("all", "noncritical")),
        "bc.network.channels": Choice(((4, 8, 8), (8, 16, 16))),
        "bc.network.hidden": Choice((16, 32)),
        "bc.train.lr": Float(1e-4, 3e-3, log=True),
        "bc.train.batch_size": Choice((16, 32)),
        "bc.preprocess.frame_stack": Choice((1, 2)),
    },
    base=RunConfig(bc=BCConfig(network=NetworkConfig(channels=(8, 16, 16), hidden=32))),
    trials=3,
    max_concurrent=2,
    cpus_per_trial=1.0,
    batches=100,
    eval_episodes=2,
    screen_episodes=1,
    max_steps=100,
    final_episodes=2,
    final_candidates=2,
    final_train_seeds=2,
    final_workers=0,
    startup_trials=2,
)
