"""Errors a person can act on: unsafe checkpoints and stray files in a dataset."""

from __future__ import annotations

import hashlib
import json
import pathlib
from pathlib import Path

import pandas as pd
import pytest
import torch

from safe_bc.bc import BCConfig, BCNet, CheckpointError, ModelSpec, load_checkpoint, save_checkpoint
from safe_bc.bc.checkpoint import UnsafeCheckpointError, with_meta_sha256
from safe_bc.cli.commands import main
from safe_bc.data.store import (
    DatasetError,
    completed_episodes,
    init_dataset,
    load_demonstrations,
    read_episodes,
    write_episode,
)

from .bc.synth import TINY_MLP
from .data.test_store import make_episode, make_meta


def _unsafe_checkpoint(directory: Path) -> Path:
    """A real checkpoint whose weights.pt also pickles a non-tensor object (sha256 updated,
    so only safe loading stands in the way)."""
    spec = ModelSpec.for_data((5,), 2)
    cfg = BCConfig(network=TINY_MLP)
    model = BCNet(spec, cfg.preprocess, cfg.network)
    save_checkpoint(directory, model, cfg)
    weights = directory / "weights.pt"
    state = dict(model.state_dict())
    state["note"] = pathlib.PurePosixPath("not/a/tensor")
    torch.save(state, weights)
    meta = json.loads((directory / "config.json").read_text())
    meta["weights_sha256"] = hashlib.sha256(weights.read_bytes()).hexdigest()
    (directory / "config.json").write_text(json.dumps(with_meta_sha256(meta)))
    return weights


def test_unsafe_checkpoint_is_one_typed_line_naming_the_file(tmp_path: Path) -> None:
    weights = _unsafe_checkpoint(tmp_path / "ckpt")
    with pytest.raises(UnsafeCheckpointError) as info:
        load_checkpoint(tmp_path / "ckpt")
    message = str(info.value)
    assert isinstance(info.value, CheckpointError)
    assert str(weights) in message and "pathlib.PurePosixPath" in message
    assert "\n" not in message
    assert "weights_only=False" not in message and "weights_only` set to `False" not in message
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_cli_unsafe_checkpoint_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    weights = _unsafe_checkpoint(tmp_path / "ckpt")
    code = main(["evaluate", "--checkpoint", str(tmp_path / "ckpt"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and str(weights) in err
    assert err.startswith("safe-bc evaluate: error: ")
    assert "False" not in err


def test_corrupt_weights_are_one_line(tmp_path: Path) -> None:
    spec = ModelSpec.for_data((5,), 2)
    cfg = BCConfig(network=TINY_MLP)
    save_checkpoint(tmp_path, BCNet(spec, cfg.preprocess, cfg.network), cfg)
    weights = tmp_path / "weights.pt"
    torch.save({"other": torch.zeros(3)}, weights)  # loads safely, fits no net
    meta = json.loads((tmp_path / "config.json").read_text())
    meta["weights_sha256"] = hashlib.sha256(weights.read_bytes()).hexdigest()
    (tmp_path / "config.json").write_text(json.dumps(with_meta_sha256(meta)))
    with pytest.raises(CheckpointError, match="do not fit the net") as info:
        load_checkpoint(tmp_path)
    assert "\n" not in str(info.value) and str(weights) in str(info.value)


@pytest.mark.parametrize("name", ["notes.parquet", "episode-1.parquet", "episode-x.parquet"])
def test_stray_parquet_in_episodes_is_named(tmp_path: Path, name: str) -> None:
    meta = init_dataset(tmp_path, make_meta("raw"))
    write_episode(tmp_path, make_episode(0, n=4), meta)
    stray = tmp_path / "episodes" / name
    pd.DataFrame({"x": [1, 2]}).to_parquet(stray)
    for call in (
        lambda: completed_episodes(tmp_path, meta),
        lambda: read_episodes(tmp_path),
        lambda: load_demonstrations(tmp_path),
    ):
        with pytest.raises(DatasetError, match="not an episode file") as info:
            call()
        assert str(stray) in str(info.value) and "\n" not in str(info.value)
    stray.unlink()
    (tmp_path / "episodes" / ".episode-00001.parquet.abc.tmp").write_bytes(b"partial")
    (tmp_path / "episodes" / "README.txt").write_text("not parquet: left alone")
    assert completed_episodes(tmp_path, meta) == [0]


def test_cli_stray_parquet_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    meta = init_dataset(tmp_path / "demos", make_meta("raw"))
    write_episode(tmp_path / "demos", make_episode(0, n=4), meta)
    pd.DataFrame({"x": [1]}).to_parquet(tmp_path / "demos" / "episodes" / "extra.parquet")
    code = main(["describe", "--demos", str(tmp_path / "demos"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "extra.parquet" in err and "not an episode file" in err


# ------------------------------------------- a dataset is what its metadata says
def _rewrite(path: Path, change) -> None:
    """Rewrite an episode file through ``change(table) -> table``, keeping its metadata and
    sealing the new columns with their checksums (as a writer with that fault would)."""
    import json

    import pyarrow.parquet as pq

    from safe_bc.data.store import DIGEST_KEY, _column_digests

    table = pq.read_table(path)
    changed = change(table)
    digests = json.dumps(_column_digests(changed), sort_keys=True).encode()
    metadata = {**table.schema.metadata, DIGEST_KEY: digests}
    pq.write_table(changed.replace_schema_metadata(metadata), path)


def _dataset(root: Path, episodes: int = 2) -> Path:
    meta = init_dataset(root, make_meta("raw"))
    for i in range(episodes):
        write_episode(root, make_episode(i, n=4), meta)
    return root


def _refused(root: Path, match: str, named: Path) -> None:
    for call in (lambda: read_episodes(root), lambda: load_demonstrations(root)):
        with pytest.raises(DatasetError, match=match) as info:
            call()
        assert str(named) in str(info.value) and "\n" not in str(info.value)


def test_episode_of_another_collection_is_refused(tmp_path: Path) -> None:
    """The issue's mixed folder: episodes of --seed 2 beside a dataset.json of --seed 1."""
    root = _dataset(tmp_path)
    other = make_episode(2, n=4, seed=100)
    path = write_episode(root, other, make_meta("raw", seed=2))
    _refused(root, "another collection .*seed 2 vs 0", path)
    with pytest.raises(DatasetError, match="another collection"):  # a resumed collect too
        completed_episodes(root, init_dataset(root, make_meta("raw")))


def test_files_without_embedded_metadata_are_accepted(tmp_path: Path) -> None:
    """Episode files written by another tool (no embedded dataset.json) load on their schema."""
    import pyarrow.parquet as pq

    root = _dataset(tmp_path)
    path = root / "episodes" / "episode-00001.parquet"
    table = pq.read_table(path)
    pq.write_table(table.replace_schema_metadata(None), path)
    assert len(read_episodes(root)) == 2


def test_duplicated_rows_are_refused(tmp_path: Path) -> None:
    import pyarrow as pa

    root = _dataset(tmp_path)
    path = root / "episodes" / "episode-00001.parquet"
    _rewrite(path, lambda t: pa.concat_tables([t, t]))
    _refused(root, r"4 duplicated \(episode_id, step\) row", path)


def test_an_episode_under_a_second_name_is_refused(tmp_path: Path) -> None:
    import shutil

    import pyarrow as pa

    root = _dataset(tmp_path)
    copy = root / "episodes" / "episode-00002.parquet"
    shutil.copy(root / "episodes" / "episode-00000.parquet", copy)
    _refused(root, "not the episode its name says", copy)
    # the same episode with its id column rewritten: its env seed gives it away
    _rewrite(copy, lambda t: t.set_column(0, "episode_id", pa.array([2] * len(t), pa.int64())))
    _refused(root, "duplicated episode", copy)


@pytest.mark.parametrize("column", ["action", "executed_action"])
def test_non_finite_actions_are_refused(tmp_path: Path, column: str) -> None:
    import pyarrow as pa

    root = _dataset(tmp_path)
    path = root / "episodes" / "episode-00001.parquet"

    def poison(t):
        rows = t.column(column).to_pylist()
        rows[2][1] = float("nan")
        i = t.schema.get_field_index(column)
        return t.set_column(i, column, pa.array(rows, pa.list_(pa.float32())))

    _rewrite(path, poison)
    _refused(root, f"1 step.* non-finite {column}", path)


def test_non_finite_vector_observations_are_refused(tmp_path: Path) -> None:
    import dataclasses

    import numpy as np

    meta = init_dataset(
        tmp_path, dataclasses.replace(make_meta("raw"), obs_encoding="vector", obs_shape=(4,))
    )
    ep = make_episode(0, n=5)
    obs = np.zeros((5, 4), np.float32)
    obs[3, 1] = np.inf
    path = write_episode(tmp_path, dataclasses.replace(ep, observations=obs), meta)
    _refused(tmp_path, "non-finite observation", path)


def test_cli_train_on_nan_actions_exits_2_before_training(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    import pyarrow as pa

    root = _dataset(tmp_path / "demos")
    path = root / "episodes" / "episode-00000.parquet"

    def poison(t):
        rows = t.column("action").to_pylist()
        rows[0][0] = float("nan")
        return t.set_column(4, "action", pa.array(rows, pa.list_(pa.float32())))

    _rewrite(path, poison)
    code = main(["train", "--demos", str(root), "--out", str(tmp_path / "ckpt"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and str(path) in err and "non-finite action" in err
    assert not (tmp_path / "ckpt").exists()


# ------------------------------------------- check before work: settings, outputs, tasks
def _one_line(capsys: pytest.CaptureFixture, code: int, command: str, *parts: str) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith(f"safe-bc {command}: error: "), err
    for part in parts:
        assert part in err, err
    return err


@pytest.mark.parametrize(
    ("flag", "value"),
    [
        ("--lambda-lr", "inf"),
        ("--cost-budget", "inf"),
        ("--anchor-coef", "inf"),
        ("--cost-margin", "nan"),
        ("--eps", "inf"),
    ],
)
def test_improve_rejects_non_finite_settings_upfront(
    tmp_path: Path, capsys: pytest.CaptureFixture, flag: str, value: str
) -> None:
    argv = ["improve", "--start", str(tmp_path / "none"), "--out", str(tmp_path / "run"), flag,
            value]  # fmt: skip
    _one_line(capsys, main(argv), "improve", f"{flag}: ", "finite")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["cost_budget", "lambda_lr", "anchor_coef", "lambda_max"])
def test_improve_config_rejects_infinity(name: str) -> None:
    from safe_bc.methods.improve import ImproveConfig

    with pytest.raises(ValueError, match=f"{name} must be finite"):
        ImproveConfig(**{name: float("inf")})


def test_train_lr_inf_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code = main(["train", "--out", str(tmp_path / "c"), "--bc.train.lr", "inf"])
    _one_line(capsys, code, "train", "--bc.train.lr: lr must be a finite number")


def test_output_that_is_a_file_is_refused_before_work(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    demos = _dataset(tmp_path / "demos")
    target = tmp_path / "taken"
    target.write_text("a file")
    code = main(["train", "--demos", str(demos), "--out", str(target), "--quiet"])
    _one_line(capsys, code, "train", str(target), "not a folder")
    code = main(["evaluate", "--checkpoint", str(tmp_path / "x"), "--out", str(target)])
    _one_line(capsys, code, "evaluate", str(target), "not a folder")
    code = main(["describe", "--demos", str(demos), "--out", str(target / "sub")])
    _one_line(capsys, code, "describe", "is a file, not a folder")
    assert target.read_text() == "a file"


def test_read_only_output_is_refused_before_work(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """As root (tests in a container) permissions do not stop a write, so the read-only mount
    is what os.access reports there."""
    import safe_bc.data.locks

    monkeypatch.setattr(safe_bc.data.locks.os, "access", lambda path, mode: False)
    code = main(["train", "--demos", str(tmp_path / "none"), "--out", str(tmp_path / "c")])
    _one_line(capsys, code, "train", "not writable")


def test_an_os_error_while_writing_is_one_line_and_keeps_the_old_checkpoint(
    rehab_demos: Path, tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch
) -> None:
    import errno

    import safe_bc.methods.experiment

    ckpt = tmp_path / "ckpt"
    argv = ["train", "--demos", str(rehab_demos), "--out", str(ckpt), "--bc.train.batches", "5",
            "--bc.network.hidden", "8", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    weights = (ckpt / "weights.pt").read_bytes()
    capsys.readouterr()

    def full(directory, *args, **kw):
        raise OSError(errno.ENOSPC, "No space left on device", str(directory / "x.parquet"))

    monkeypatch.setattr(safe_bc.methods.experiment, "save_selection", full)
    _one_line(capsys, main([*argv, "--seed", "1"]), "train", "No space left on device")
    assert (ckpt / "weights.pt").read_bytes() == weights
    load_checkpoint(ckpt)


def test_train_on_a_full_disk_is_one_line_not_torchs_traceback(
    rehab_demos: Path, tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch
) -> None:
    import errno
    import io

    import torch

    real_save = torch.save

    class Full(io.BytesIO):
        def write(self, data):  # the disk fills while torch writes the weights
            raise OSError(errno.ENOSPC, "No space left on device")

    # torch turns the failed write into its own RuntimeError ("unexpected pos ...")
    monkeypatch.setattr(torch, "save", lambda obj, f, **kw: real_save(obj, Full(), **kw))
    ckpt = tmp_path / "ckpt"
    argv = ["train", "--demos", str(rehab_demos), "--out", str(ckpt), "--bc.train.batches", "5",
            "--bc.network.hidden", "8", "--quiet"]  # fmt: skip
    _one_line(capsys, main(argv), "train", "No space left on device", "weights.pt")
    assert not ckpt.exists() or not any(ckpt.iterdir())


def test_improve_with_demos_of_another_task_is_refused_upfront(
    rehab_start: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    demos = _dataset(tmp_path / "carracing")  # CarRacing-v3 demonstrations
    out = tmp_path / "run"
    argv = ["improve", "--start", str(rehab_start), "--demos", str(demos), "--out", str(out),
            "--quiet"]  # fmt: skip
    _one_line(capsys, main(argv), "improve", "CarRacing-v3 demonstrations", "RehabPathway")
    assert not out.exists()


def test_a_checkpoint_naming_another_task_is_refused_before_evaluation(
    rehab_start: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    import shutil

    ckpt = tmp_path / "ckpt"
    shutil.copytree(rehab_start, ckpt)
    meta = json.loads((ckpt / "config.json").read_text())
    meta["extra"]["env_id"] = "CarRacing-v3"
    (ckpt / "config.json").write_text(json.dumps(with_meta_sha256(meta)))
    code = main(["evaluate", "--checkpoint", str(ckpt), "--out", str(tmp_path / "e"), "--quiet"])
    _one_line(capsys, code, "evaluate", str(ckpt), "names CarRacing-v3")
    code = main(["improve", "--start", str(ckpt), "--out", str(tmp_path / "run"), "--quiet"])
    _one_line(capsys, code, "improve", "names CarRacing-v3")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ckpt"]


# ------------------------------------------- bad input: one line, exit 2, nothing made
def _damaged(root: Path) -> Path:
    """A two-episode set whose first episode's bytes changed after it was sealed."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    _dataset(root)
    path = root / "episodes" / "episode-00000.parquet"
    table = pq.read_table(path)
    rows = table.column("reward").to_pylist()
    rows[0] += 1.0
    column = table.schema.get_field_index("reward")
    pq.write_table(table.set_column(column, "reward", pa.array(rows, pa.float32())), path)
    return path


@pytest.mark.parametrize(
    ("argv", "parts"),
    [
        (["render", "--expert", "--out", "{tmp}/x.txt"], ("--out must end in .mp4 or .gif",)),
        (["render", "--expert", "--out", "{tmp}/nowhere/r.mp4"], ("does not exist",)),
        (["evaluate", "--checkpoint", "{tmp}/c", "--out", "{tmp}/o", "--max-steps", "-5"],
         ("--max-steps must be >= 1",)),
    ],
)  # fmt: skip
def test_bad_flags_are_one_line_and_make_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture, argv: list[str], parts: tuple[str, ...]
) -> None:
    code = main([a.format(tmp=tmp_path) for a in argv])
    _one_line(capsys, code, argv[0], *parts)
    assert list(tmp_path.iterdir()) == []


def test_a_damaged_set_is_refused_before_train_makes_its_frame_cache(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    path = _damaged(tmp_path / "demos")
    code = main(["train", "--demos", str(tmp_path / "demos"), "--out", str(tmp_path / "ckpt")])
    _one_line(capsys, code, "train", str(path), "damaged")
    assert sorted(p.name for p in (tmp_path / "demos").iterdir()) == ["dataset.json", "episodes"]
    assert not (tmp_path / "ckpt").exists()


def test_a_damaged_set_is_refused_before_export_writes(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch
) -> None:
    pytest.importorskip("minari")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    path = _damaged(tmp_path / "demos")
    code = main(
        ["export", "--dataset-id", "safe_bc/damaged-v0", "--demos", str(tmp_path / "demos")]
    )
    _one_line(capsys, code, "export", str(path), "damaged")
    assert not (tmp_path / "minari").exists()


@pytest.mark.parametrize("damage", ["file", "damaged"])
def test_tune_refuses_bad_demonstrations_before_ray_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch, damage: str
) -> None:
    import ray

    def no_ray(*_: object, **__: object) -> None:
        raise AssertionError("Ray started before the demonstrations were checked")

    monkeypatch.setattr(ray, "init", no_ray)
    if damage == "file":
        demos = tmp_path / "demos.txt"
        demos.write_text("not a set")
        parts: tuple[str, ...] = ("--demos", "a file, not a demonstration set folder")
    else:
        demos = tmp_path / "demos"
        parts = (str(_damaged(demos)), "damaged")
    study = Path(__file__).resolve().parents[1] / "tune_jobs" / "smoke.py"
    argv = ["tune", str(study), "--demos", str(demos), "--results", str(tmp_path / "r")]
    code = main(argv)
    _one_line(capsys, code, "tune", *parts)
    assert not (tmp_path / "r").exists()
