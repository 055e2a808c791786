"""The car's beyond-the-expert study (tune_jobs/beyond.py) retrains exactly what its design
picked: the same start and self-imitation settings as the comparison's row, the handover the
fourth design's rule picked, nothing searched, and a certification block no table runs on."""

from __future__ import annotations

from pathlib import Path

import pytest

from safe_bc.compare.families import load_comparisons
from safe_bc.study.spec import load_study
from safe_bc.tasks import task_defaults

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def study():
    return load_study(ROOT / "tune_jobs" / "beyond.py")


@pytest.fixture(scope="module")
def selection():
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(ROOT)
        return load_comparisons(ROOT / "tune_jobs/compare/selfimprove.py", planned=True)[
            "beyond_selection"
        ]


def test_the_study_runs_the_designs_pick_from_the_designs_start(study, selection) -> None:
    rows = {m.name: m for m in selection.methods}
    pick = rows["si_explore_best2"]
    assert study.selfimprove == pick.config
    start = rows[pick.start]
    assert study.base.selection == start.selection
    assert study.base.bc == selection.bc
    assert study.batches == selection.bc.train.batches


def test_the_recommender_is_the_agent_with_the_picked_handover(study) -> None:
    """The handover of the row the fourth design's rule picked on its selection tracks (the
    fresh table's handover row, resolved from the committed selection table)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(ROOT)
        fresh = load_comparisons(ROOT / "tune_jobs/compare/selfimprove.py")["beyond_lean"]
    (picked,) = [m for m in fresh.methods if m.name.startswith("si_explore_best2+")]
    assert picked.handover == study.handover != task_defaults("carracing").handover
    assert study.selfimprove.handover == task_defaults("carracing").handover
    assert dict(study.space) == {}
    assert study.trials == 1 and study.final_candidates == 1
    assert study.certify_episodes == 150 and study.final_train_seeds == 3


def _assert_blocks_new(study) -> None:
    """The study's certification block is no table's and no other study's certification
    block; its trial and final-phase blocks are no table's."""
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(ROOT)
        blocks = {
            c.eval_seed
            for f in sorted((ROOT / "tune_jobs/compare").glob("*.py"))
            for c in load_comparisons(f, planned=True).values()
        }
    studies = [load_study(p) for p in sorted((ROOT / "tune_jobs").glob("*.py"))]
    others = {s.certify_seed for s in studies if s.name != study.name and s.certify_episodes}
    assert study.certify_seed not in blocks | others
    assert study.eval_seed not in blocks and study.final_seed not in blocks


def test_the_certification_block_is_new_to_every_table(study) -> None:
    _assert_blocks_new(study)


@pytest.fixture(scope="module")
def clinic():
    return load_study(ROOT / "tune_jobs" / "beyond_rehab.py")


@pytest.fixture(scope="module")
def clinic_selection():
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(ROOT)
        return load_comparisons(ROOT / "tune_jobs/compare/selfimprove.py", planned=True)[
            "beyond_early_selection_rehab_lagrangian"
        ]


def test_the_clinic_study_runs_its_designs_pick(clinic, clinic_selection) -> None:
    rows = {m.name: m for m in clinic_selection.methods}
    pick = rows["lagrangian+cap_060_hold"]
    agent = rows[pick.of]
    assert clinic.handover == pick.handover
    assert clinic.improve == agent.config
    assert clinic.base.selection == rows[agent.start].selection
    assert clinic.base.bc == clinic_selection.bc
    assert dict(clinic.space) == {} and clinic.trials == 1
    assert clinic.certify_episodes == 600 and clinic.deferred_share_limit == 0.10
    assert clinic.threshold == 0.0  # the limit d_s binds, not the guideline's mean margin


def test_the_clinic_certification_block_is_new_to_every_table(clinic) -> None:
    _assert_blocks_new(clinic)
