"""A cheaper candidate for the default study, measured to halve ``make tune``'s wall-clock:
the two-seed default of then (``tune_jobs/default_two_seeds.py``) with one training seed per
trial instead of two, and 15 tracks per surviving trial instead of 10 (zero crossings in 15
episodes bound the share at 18.1%, under the study's 20% limit; 10 would bound it at 25.9% and
admit no trial), one env at a time. Everything else, the final phase included (the top 3 and
plain BC retrained with 3 seeds on 51 fresh tracks), is that study's. Its wall-clock and final
phase against it: ``results/checks/make_tune/one_seed/side_by_side.md``. The default since then
(``tune_jobs/default.py``) is this design with 4 tracks in lockstep per trial.

Run: ``safe-bc tune tune_jobs/default_one_seed.py`` (results in ``results/default_one_seed/``).
"""

from dataclasses import replace
from pathlib import Path

from safe_bc.study.spec import load_study

STUDY = replace(
    load_study(Path(__file__).with_name("default_two_seeds.py")),
    name="default_one_seed",
    train_seeds=1,
    eval_episodes=15,
)
