"""A study's TensorBoard runs (safe_bc/study/trial_curves.py) written from tables like a
study's and read back from the event files: named runs, BC curves per logged batch, evaluation
rounds, HParams entries with feasibility and the winner, final-phase curves."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.data.curves import read_events, read_hparams, write_curve
from safe_bc.study.trial_curves import (
    BOARD,
    final_run_name,
    run_names,
    write_board,
    write_final_curve,
)

PARAMS = ["selection.eps", "selection.alpha", "bc.network.channels"]


def _curve(batches: int = 5, val: bool = True) -> pd.DataFrame:
    b = np.arange(1, batches + 1) * 10
    return pd.DataFrame(
        {
            "batch": b,
            "train_loss": 1.0 / b,
            "val_loss": 2.0 / b if val else np.nan,
            "samples": b * 32,
            "seconds": b / 100,
        }
    )


def _study(tmp_path: Path) -> tuple[pd.DataFrame, pd.DataFrame, Path]:
    """Two trials: ``a`` evaluated in two rounds (feasible), ``b`` stopped by the screening."""
    trials = pd.DataFrame(
        {
            "trial_id": ["a", "b"],
            "trial_number": [0, 1],
            "status": ["done", "stopped"],
            "selection.eps": [0.5, 2.25],
            "selection.alpha": [0.1, 0.9],
            "bc.network.channels": ["8-16-16", "16-32-32"],
            "reward_lcb": [850.0, 400.0],
            "constraint": [-0.05, 0.2],
            "constraint_safety": [-0.05, 0.2],
            "constraint_violation": [-0.1, -0.1],
            "constraint_deferral": [-0.05, math.nan],
            "feasible": [True, False],
        }
    )
    nan = math.nan
    history = pd.DataFrame(
        {
            "trial_id": ["a", "a", "a", "b", "b"],
            "phase": ["trained", "screened", "evaluated", "trained", "screened"],
            "eval_round": [0, 1, 2, 0, 1],
            "reward_mean": [nan, 800.0, 880.0, nan, 420.0],
            "any_violation": [nan, 0.0, 0.1, nan, 0.5],
            "deferred_share": [nan, 0.02, 0.03, nan, 0.0],
            "constraint": [nan, -0.05, -0.05, nan, 0.2],
        }
    )
    exp = tmp_path / "ray" / "study"
    for tid in ("a", "b"):
        write_curve(exp / f"trial_{tid}" / "bc" / "curve.parquet", _curve(), "batch", "bc")
    write_curve(exp / "trial_a" / "bc_seed_1" / "curve.parquet", _curve(val=False), "batch", "bc")
    stage = pd.DataFrame({"iteration": [0, 1, 2], "val_reward": [700.0, 720.0, 710.0]})
    write_curve(exp / "trial_a" / "selfimprove" / "curve.parquet", stage, "iteration", "x")
    retrained = exp / "trial_a" / "selfimprove" / "round_1" / "bc" / "curve.parquet"
    write_curve(retrained, _curve(3), "batch", "bc")  # a round's retraining
    return trials, history, exp


def test_board_runs_read_back(tmp_path: Path) -> None:
    trials, history, exp = _study(tmp_path)
    out = tmp_path / "results" / "study"
    kw = dict(params=PARAMS, objective="reward_lcb", stages=["selfimprove"], exp_path=str(exp))
    board = write_board(out, trials, history, winner=None, **kw)
    assert board == out / BOARD
    names = run_names(trials, PARAMS)
    assert names == {"a": "t000_eps0.5_alpha0.1_channels8-16-16",
                     "b": "t001_eps2.25_alpha0.9_channels16-32-32"}  # fmt: skip
    assert sorted(p.name for p in board.iterdir()) == sorted(names.values())

    a = read_events(board / names["a"])
    steps = a.groupby("tag")["step"].apply(list).to_dict()
    assert steps["bc/train_loss"] == [10, 20, 30, 40, 50] == steps["bc/val_loss"]
    assert steps["bc_seed_1/train_loss"] == [10, 20, 30, 40, 50]
    assert "bc_seed_1/val_loss" not in steps  # NaN: no validation set for that seed
    assert steps["selfimprove/val_reward"] == [0, 1, 2]
    assert steps["selfimprove/round_1/bc/train_loss"] == [10, 20, 30]
    assert steps["eval/reward_mean"] == [1, 2] and steps["eval/deferred_share"] == [1, 2]
    value = a.set_index(["tag", "step"])["value"]
    assert value[("eval/any_violation", 2)] == pytest.approx(0.1)
    assert value[("hparams/reward_lcb", 0)] == 850.0 and value[("hparams/feasible", 0)] == 1.0
    assert value[("hparams/winner", 0)] == 0.0  # no winner yet
    b = read_events(board / names["b"])
    assert b.loc[b["tag"] == "eval/reward_mean", "step"].tolist() == [1]  # stopped after round 1
    assert "hparams/constraint_deferral" not in set(b["tag"])  # NaN left out

    hp = read_hparams(board / names["a"])
    assert hp == {"selection.eps": 0.5, "selection.alpha": 0.1,
                  "bc.network.channels": "8-16-16", "trial": 0, "status": "done",
                  "feasible": True, "winner": False}  # fmt: skip

    # the winner known: the entries are rewritten (one event file per run, no step twice)
    final = pd.DataFrame({"method": ["a", "plain_bc"], "reward": [870.0, 860.0],
                          "constraint": [-0.02, -0.01]})  # fmt: skip
    write_board(out, trials, history, winner="a", final=final, **kw)
    assert read_hparams(board / names["a"])["winner"] is True
    hp_values = read_events(board / names["a"]).set_index("tag")["value"]
    assert hp_values["hparams/final_reward"] == 870.0
    assert "hparams/final_reward" not in set(read_events(board / names["b"])["tag"])
    # every run's entry names the same columns (TensorBoard takes one run's list for all)
    assert _hparams_columns(board / names["b"]) == _hparams_columns(board / names["a"])
    assert "hparams/final_reward" in _hparams_columns(board / names["b"])
    assert read_hparams(board / names["b"])["winner"] is False
    again = read_events(board / names["a"])
    assert not again.duplicated(["tag", "step"]).any()
    assert len(list((board / names["a"]).glob("events.out.tfevents.*"))) == 1


def _hparams_columns(run: Path) -> list[str]:
    """The metric columns of the HParams experiment summary in ``run``'s event file."""
    from tensorboardX.proto.event_pb2 import Event
    from tensorboardX.proto.plugin_hparams_pb2 import HParamsPluginData

    from safe_bc.data.curves import _records

    (path,) = run.glob("events.out.tfevents.*")
    for record in _records(path):
        for value in Event.FromString(record).summary.value:
            if value.metadata.plugin_data.plugin_name == "hparams":
                data = HParamsPluginData.FromString(value.metadata.plugin_data.content)
                if data.HasField("experiment"):
                    return [m.name.tag for m in data.experiment.metric_infos]
    return []


def test_final_phase_curve_run(tmp_path: Path) -> None:
    board = tmp_path / BOARD
    name = final_run_name("a", 1, {"a": "t000_eps0.5"})
    write_final_curve(board, name, _curve())
    events = read_events(board / "final_t000_eps0.5_seed1")
    assert events.loc[events["tag"] == "bc/train_loss", "step"].tolist() == [10, 20, 30, 40, 50]
    assert final_run_name("plain_bc", 0, {}) == "final_plain_bc_seed0"


def test_tensorboard_reads_the_board(tmp_path: Path) -> None:
    """TensorBoard's own reader sees the scalars and the HParams entry (skipped without it)."""
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    trials, history, exp = _study(tmp_path)
    board = write_board(
        tmp_path / "out", trials, history, params=PARAMS, objective="reward_lcb",
        exp_path=str(exp), winner="a",
    )  # fmt: skip
    acc = EventAccumulator(str(board / run_names(trials, PARAMS)["a"]))
    acc.Reload()
    scalars = set(acc.Tags()["scalars"])
    assert {"bc/train_loss", "bc/val_loss", "eval/reward_mean", "hparams/winner"} <= scalars
    assert [e.step for e in acc.Scalars("eval/reward_mean")] == [1, 2]
    assert acc.PluginTagToContent("hparams")  # the entry: experiment, session start, end


def test_fresh_keeps_the_earlier_run_beside_the_latest(tmp_path: Path) -> None:
    """``--fresh`` moves the run it replaces into ``results/<study>/earlier/<stamp>/``."""
    from safe_bc.study.run import EARLIER, keep_earlier_run

    out = tmp_path / "study"
    assert keep_earlier_run(out) is None  # nothing yet
    (out / "recommender").mkdir(parents=True)
    (out / "recommender" / "card.json").write_text("{}")
    for name in ("trials.parquet", "finished.json", "best.json"):
        (out / name).write_text(name)
    (out / "replicates.md").write_text("not a run's output")
    first = keep_earlier_run(out)
    assert first is not None and first.parent == out / EARLIER
    assert sorted(p.name for p in first.iterdir()) == [
        "best.json", "finished.json", "recommender", "trials.parquet"
    ]  # fmt: skip
    assert sorted(p.name for p in out.iterdir()) == [EARLIER, "replicates.md"]
    (out / "trials.parquet").write_text("again")
    second = keep_earlier_run(out)  # the same second: a name of its own
    assert second is not None and second != first and (second / "trials.parquet").exists()
