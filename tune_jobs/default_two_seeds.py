"""The default study before one seed per trial halved ``make tune``'s wall-clock, kept to
compare against: two training seeds per trial on the same 10 tracks (crossed bootstrap), one
env at a time; everything else is ``tune_jobs/default.py``'s. Its 3 replicates
on the committed default demonstrations (``safe-bc tune tune_jobs/default_two_seeds.py
--replicates 3``) are in ``results/default_two_seeds/replicates/``; the single study beside
them was made under the name ``default`` from the earlier exact-renderer set (its replicate 0
is the same study on the committed set). The two designs' replicates side by side:
``results/checks/make_tune/half/replicates.md``.

Run: ``safe-bc tune tune_jobs/default_two_seeds.py`` (results in ``results/default_two_seeds/``).
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.study.spec import load_study

STUDY = replace(
    load_study(Path(__file__).with_name("default.py")),
    name="default_two_seeds",
    train_seeds=2,
    eval_episodes=10,
    trial_envs=1,
)
