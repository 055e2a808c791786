"""The per-policy evaluation cache of the result scripts (scripts/eval_cache.py)."""

from __future__ import annotations

from dataclasses import replace

import pandas as pd

import safe_bc.distributed.evaluate as evaluate_module
import scripts.eval_cache as eval_cache
from safe_bc.evaluation import EvalConfig, ExpertSource
from safe_bc.experts.rehab import GuidelineConfig
from safe_bc.tasks import task_defaults


def test_only_policies_whose_stamp_changed_are_evaluated_again(tmp_path, monkeypatch):
    task = task_defaults("rehab")
    sources = {"guideline": ExpertSource(task.expert),
               "cautious/0": ExpertSource(GuidelineConfig(max_intensity=0.55))}  # fmt: skip
    config = EvalConfig(episodes=3, workers=0, seed=5, env=task.env)
    first = eval_cache.evaluate_cached(sources, config, None, tmp_path, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cautious-0.parquet", "guideline.parquet"]
    assert list(first["policy"].unique()) == list(sources) and len(first) == 6

    evaluated: list[list[str]] = []
    real = evaluate_module.evaluate_policies

    def recording(policies, *args, **kwargs):
        evaluated.append(list(policies))
        return real(policies, *args, **kwargs)

    monkeypatch.setattr(evaluate_module, "evaluate_policies", recording)
    again = eval_cache.evaluate_cached(sources, replace(config, workers=2), None, tmp_path,
                                       progress=False)  # fmt: skip
    pd.testing.assert_frame_equal(again, first)  # where episodes run changes nothing
    assert evaluated == []

    changed = {**sources, "cautious/0": ExpertSource(GuidelineConfig(max_intensity=0.5))}
    assert len(eval_cache.evaluate_cached(changed, config, None, tmp_path, progress=False)) == 6
    assert evaluated == [["cautious/0"]]
    more = eval_cache.evaluate_cached(changed, replace(config, episodes=4), None, tmp_path,
                                      progress=False)  # fmt: skip
    assert evaluated[-1] == ["guideline", "cautious/0"] and len(more) == 8


def test_fingerprint_follows_content_not_identity():
    a = ExpertSource(GuidelineConfig())
    assert eval_cache.fingerprint(a) == eval_cache.fingerprint(ExpertSource(GuidelineConfig()))
    other = ExpertSource(GuidelineConfig(max_intensity=0.55))
    assert eval_cache.fingerprint(a) != eval_cache.fingerprint(other)
