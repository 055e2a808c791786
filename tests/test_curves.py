"""Learning curves: the Parquet table and the TensorBoard event files beside it, after a
`safe-bc train` run with and without held-out episodes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.bc.checkpoint import check_checkpoint_files, load_checkpoint, read_checkpoint_meta
from safe_bc.cli.commands import main
from safe_bc.data.curves import EVENTS_GLOB, read_events, write_curve, write_events
from safe_bc.data.store import load_demonstrations, read_table
from safe_bc.methods.experiment import RunConfig, train_run
from safe_bc.methods.rounds import weights_digest
from safe_bc.selection import SelectionConfig
from safe_bc.tasks import dataset_action_bounds


def test_events_mirror_the_table_and_a_rewrite_replaces_them(tmp_path: Path) -> None:
    table = pd.DataFrame(
        {"step": [1, 2, 4], "loss": [0.5, np.nan, 0.25], "ok": [True, False, True], "who": "a"}
    )
    write_curve(tmp_path / "curve.parquet", table, "step", "run", {"note": "x"})
    frame, meta = read_table(tmp_path / "curve.parquet")
    pd.testing.assert_frame_equal(frame, table)
    assert meta["note"] == "x"
    events = read_events(tmp_path)
    assert sorted(set(events["tag"])) == ["run/loss", "run/ok"]  # strings left out
    loss = events[events["tag"] == "run/loss"]
    assert loss["step"].tolist() == [1, 4] and loss["value"].tolist() == [0.5, 0.25]  # NaN left out
    longer = pd.concat([table, table.assign(step=[5, 6, 7])], ignore_index=True)
    write_events(tmp_path, longer, "step", "run")
    assert len(list(tmp_path.glob(EVENTS_GLOB))) == 1
    again = read_events(tmp_path)
    assert again[again["tag"] == "run/ok"]["step"].tolist() == [1, 2, 4, 5, 6, 7]


def test_a_damaged_event_file_is_refused(tmp_path: Path) -> None:
    path = write_events(tmp_path, pd.DataFrame({"s": [1], "v": [1.0]}), "s", "x")
    data = bytearray(path.read_bytes())
    data[-3] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="corrupt record"):
        read_events(tmp_path)


def _train(demos: Path, out: Path, *extra: str) -> None:
    argv = ["train", "--demos", str(demos), "--out", str(out), "--bc.train.batches", "30",
            "--bc.train.log-every", "10", "--bc.network.hidden", "8", "--quiet",
            *extra]  # fmt: skip
    assert main(argv) == 0


def test_train_writes_its_curve_with_held_out_episodes(rehab_demos: Path, tmp_path: Path) -> None:
    out = tmp_path / "ckpt"
    _train(rehab_demos, out, "--validation-episodes", "2")
    curve, meta = read_table(out / "curve.parquet")
    assert list(curve.columns) == ["batch", "train_loss", "val_loss", "samples", "seconds"]
    assert curve["batch"].tolist() == [10, 20, 30]  # monotone batch index
    assert np.isfinite(curve["val_loss"]).all() and np.isfinite(curve["train_loss"]).all()
    assert meta["validation_episodes"] == [6, 7]  # the 8 programmes' last two
    assert "curve.parquet" in check_checkpoint_files(out)["files_sha256"]  # sealed in the unit
    events = read_events(out)
    val = events[events["tag"] == "bc/val_loss"]
    assert val["step"].tolist() == [10, 20, 30]
    np.testing.assert_allclose(val["value"], curve["val_loss"], rtol=1e-6)  # float32 in events
    # retraining into the folder replaces the curve's event file, it does not add one
    _train(rehab_demos, out)
    assert len(list(out.glob(EVENTS_GLOB))) == 1
    assert set(read_events(out)["tag"]) == {"bc/train_loss", "bc/samples", "bc/seconds"}
    load_checkpoint(out)


def test_train_without_held_out_episodes_trains_on_every_episode(
    rehab_demos: Path, tmp_path: Path
) -> None:
    """By default the curve changes nothing: the checkpoint's weights are those of train_run
    on the whole set with the checkpoint's settings, and the curve has no validation loss."""
    out = tmp_path / "ckpt"
    _train(rehab_demos, out)
    curve, _ = read_table(out / "curve.parquet")
    assert curve["val_loss"].isna().all() and len(curve) == 3
    assert "validation_episodes" not in read_checkpoint_meta(out)["extra"]
    model, cfg = load_checkpoint(out)
    selection = SelectionConfig(**read_table(out / "selection.parquet")[1]["config"])
    result, _ = train_run(
        load_demonstrations(rehab_demos),
        RunConfig(selection=selection, bc=cfg),
        action_bounds=dataset_action_bounds(rehab_demos),
    )
    assert weights_digest(result.model.state_dict()) == weights_digest(model.state_dict())


def test_a_studys_validation_set_must_be_another_set_of_the_task(
    rehab_demos: Path, tmp_path: Path
) -> None:
    from safe_bc.data.store import init_dataset, read_meta
    from safe_bc.distributed.collect import dataset_meta
    from safe_bc.rollout.collect import CollectConfig
    from safe_bc.study.run import _check_validation_demos

    meta = read_meta(rehab_demos)
    with pytest.raises(ValueError, match="no demonstration set there"):
        _check_validation_demos(tmp_path / "none", rehab_demos, meta)
    with pytest.raises(ValueError, match="the training set itself"):
        _check_validation_demos(rehab_demos, rehab_demos, meta)
    car = tmp_path / "car"  # a CarRacing set (its dataset.json is what the check reads)
    init_dataset(car, dataset_meta(CollectConfig(episodes=1)))
    with pytest.raises(ValueError, match=r"holds CarRacing.* observations, the study's"):
        _check_validation_demos(car, rehab_demos, meta)
