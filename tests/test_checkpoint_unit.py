"""A checkpoint folder is one unit: weights, config and selection are replaced together, a
crash at any point leaves the old unit or the new one (never a mix) and no temporary files,
a mixed folder is refused in one line, and improve's resume checks completeness the same way."""

from __future__ import annotations

import hashlib
import shutil
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest
import torch

from safe_bc.bc import BCConfig, BCNet, CheckpointError, ModelSpec, load_checkpoint, save_checkpoint
from safe_bc.bc.checkpoint import (
    EVALUATED_WEIGHTS,
    UNIT,
    check_checkpoint_files,
    checkpoint_unit,
)
from safe_bc.cli.commands import main
from safe_bc.data import atomic
from safe_bc.data.atomic import recover_dir
from safe_bc.data.store import read_table, write_table_atomic

from .bc.synth import TINY_MLP


def _write(directory: Path, seed: int) -> str:
    """A sealed unit whose net and selection both say ``seed``; returns the weights' sha256."""
    torch.manual_seed(seed)
    cfg = BCConfig(network=TINY_MLP)
    model = BCNet(ModelSpec.for_data((5,), 2), cfg.preprocess, cfg.network)
    with checkpoint_unit(directory) as unit:
        save_checkpoint(unit, model, cfg, extra={"seed": seed})
        write_table_atomic(unit / "selection.parquet", pd.DataFrame({"x": [seed]}), {"seed": seed})
    return hashlib.sha256((directory / "weights.pt").read_bytes()).hexdigest()


def _seed_of(directory: Path) -> int:
    load_checkpoint(directory)  # the whole unit checks out
    _, meta = read_table(directory / "selection.parquet")
    return meta["seed"]


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_units_replace_each_other_and_keep_other_entries(tmp_path: Path) -> None:
    ckpt = tmp_path / "ckpt"
    _write(ckpt, 1)
    (ckpt / "eval").mkdir()
    (ckpt / "eval" / "summary.parquet").write_bytes(b"an evaluation of the old unit")
    _write(ckpt, 2)
    assert _seed_of(ckpt) == 2 and _names(ckpt) == [
        "config.json",
        "eval",
        "selection.parquet",
        "weights.pt",
    ]
    assert (ckpt / "eval" / "summary.parquet").exists()
    assert _names(tmp_path) == ["ckpt"]
    assert "selection.parquet" in check_checkpoint_files(ckpt)["files_sha256"]


def test_a_crash_while_writing_keeps_the_old_unit(tmp_path: Path) -> None:
    ckpt = tmp_path / "ckpt"
    old = _write(ckpt, 1)
    torch.manual_seed(2)
    cfg = BCConfig(network=TINY_MLP)
    with pytest.raises(KeyboardInterrupt), checkpoint_unit(ckpt) as unit:
        save_checkpoint(unit, BCNet(ModelSpec.for_data((5,), 2), cfg.preprocess, cfg.network), cfg)
        raise KeyboardInterrupt  # killed before the selection is written
    assert (
        _seed_of(ckpt) == 1
        and hashlib.sha256((ckpt / "weights.pt").read_bytes()).hexdigest() == old
    )
    assert _names(tmp_path) == ["ckpt"]


def test_a_crash_between_two_renames_is_undone_by_the_next_write(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where the file system cannot swap two folders in one step: killed after the old unit
    was moved aside and before the new one took its place."""
    ckpt = tmp_path / "ckpt"
    _write(ckpt, 1)
    monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)
    renames, real = [], atomic.os.rename

    def rename(a, b):
        renames.append(a)
        if len(renames) == 2:
            raise KeyboardInterrupt
        real(a, b)

    monkeypatch.setattr(atomic.os, "rename", rename)
    with pytest.raises(KeyboardInterrupt):
        _write(ckpt, 2)
    monkeypatch.undo()
    assert not ckpt.exists()
    recover_dir(ckpt, UNIT)  # what the next write (under the lock) does first
    assert _seed_of(ckpt) == 1 and _names(tmp_path) == ["ckpt"]
    _write(ckpt, 2)
    assert _seed_of(ckpt) == 2 and _names(tmp_path) == ["ckpt"]


def test_a_crash_after_the_swap_carries_the_rest_on_the_next_write(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ckpt = tmp_path / "ckpt"
    _write(ckpt, 1)
    (ckpt / "eval").mkdir()

    def killed(old, new, unit, keep):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic, "_carry", killed)
    with pytest.raises(KeyboardInterrupt):
        _write(ckpt, 2)
    monkeypatch.undo()
    assert _seed_of(ckpt) == 2  # the new unit, whole
    _write(ckpt, 3)
    assert _seed_of(ckpt) == 3 and (ckpt / "eval").is_dir() and _names(tmp_path) == ["ckpt"]


def test_a_mixed_unit_is_refused_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The issue's mix: new weights beside another training's selection."""
    a, b = tmp_path / "a", tmp_path / "b"
    _write(a, 1)
    _write(b, 2)
    shutil.copy(b / "selection.parquet", a / "selection.parquet")
    with pytest.raises(CheckpointError, match=r"selection\.parquet does not match") as info:
        load_checkpoint(a)
    assert "\n" not in str(info.value)
    code = main(["evaluate", "--checkpoint", str(a), "--out", str(tmp_path / "eval")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "partial or mixed save" in err
    (a / "selection.parquet").unlink()
    with pytest.raises(CheckpointError, match=r"missing selection\.parquet"):
        check_checkpoint_files(a)


def test_checkpoints_without_files_sha256_still_load(tmp_path: Path) -> None:
    cfg = BCConfig(network=TINY_MLP)
    save_checkpoint(tmp_path, BCNet(ModelSpec.for_data((5,), 2), cfg.preprocess, cfg.network), cfg)
    assert "files_sha256" not in check_checkpoint_files(tmp_path)
    load_checkpoint(tmp_path)


def test_cli_train_killed_before_the_selection_keeps_the_old_checkpoint(
    rehab_demos: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import safe_bc.methods.experiment

    ckpt = tmp_path / "ckpt"
    argv = ["train", "--demos", str(rehab_demos), "--out", str(ckpt), "--bc.train.batches", "5",
            "--bc.network.hidden", "8", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    weights = (ckpt / "weights.pt").read_bytes()

    def killed(*args, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(safe_bc.methods.experiment, "save_selection", killed)
    assert main([*argv, "--selection.eps", "0.5", "--seed", "1"]) == 130
    monkeypatch.undo()
    assert (ckpt / "weights.pt").read_bytes() == weights
    _, meta = read_table(ckpt / "selection.parquet")
    assert meta["config"]["eps"] != 0.5
    load_checkpoint(ckpt)
    assert _names(tmp_path) == ["ckpt"]


def test_improve_rewrites_a_policy_missing_its_selection(rehab_start: Path, tmp_path: Path) -> None:
    """A policy folder without selection.parquet is not a finished run: the rerun writes the
    whole unit again from state.pt, with the same weights."""
    from safe_bc.methods.improve import ImprovedSource, improve

    from .test_improve import TINY

    cfg = replace(TINY, iterations=2, eval_every=1)
    out = tmp_path / "run"
    improve(rehab_start, out, cfg)
    weights = (out / "policy" / "weights.pt").read_bytes()
    (out / "policy" / "selection.parquet").unlink()
    again = improve(rehab_start, out, cfg)
    assert again.resumed_at == cfg.iterations  # from state.pt, not returned as finished
    assert (out / "policy" / "weights.pt").read_bytes() == weights
    check_checkpoint_files(out / "policy")
    ImprovedSource.from_run(out)
    names = [n for n in _names(out) if not n.startswith("events.out.tfevents.")]
    assert names == ["history.parquet", "policy", "state.pt"]


def test_a_symlinked_checkpoint_folder_is_replaced_behind_its_link(tmp_path: Path) -> None:
    real, link = tmp_path / "real", tmp_path / "link"
    _write(real, 1)
    (real / "eval").mkdir()
    link.symlink_to(real)
    _write(link, 2)
    assert link.is_symlink() and _seed_of(link) == 2 and (real / "eval").is_dir()
    assert _names(tmp_path) == ["link", "real"]


def test_an_edited_config_json_is_caught_by_its_own_checksum(tmp_path: Path) -> None:
    import json

    from safe_bc.bc import CheckpointError, load_checkpoint
    from safe_bc.bc.checkpoint import META_SHA256, save_checkpoint
    from safe_bc.bc.config import BCConfig
    from safe_bc.bc.net import BCNet, ModelSpec

    from .bc.synth import TINY_MLP

    cfg = BCConfig(network=TINY_MLP)
    save_checkpoint(tmp_path, BCNet(ModelSpec.for_data((5,), 2), cfg.preprocess, TINY_MLP), cfg)
    load_checkpoint(tmp_path)
    meta = json.loads((tmp_path / "config.json").read_text())
    assert META_SHA256 in meta
    meta["extra"]["env_id"] = "CarRacing-v3"  # parses, fits the net: only the checksum can tell
    (tmp_path / "config.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match=r"config\.json does not match the sha256"):
        load_checkpoint(tmp_path)


# --- evaluations kept in a checkpoint folder ---------------------------------------------


def _evaluation(folder: Path, **meta: object) -> Path:
    """A ``safe-bc evaluate`` folder whose tables carry ``meta``."""
    for name in ("episodes.parquet", "summary.parquet"):
        write_table_atomic(folder / name, pd.DataFrame({"reward": [1.0]}), dict(meta))
    return folder


def test_an_evaluation_of_the_replaced_weights_goes_with_them(tmp_path: Path) -> None:
    ckpt = tmp_path / "ckpt"
    old = _write(ckpt, 1)
    _evaluation(ckpt / "eval", **{EVALUATED_WEIGHTS: old})
    _evaluation(ckpt / "other", **{EVALUATED_WEIGHTS: "f" * 64})  # of weights never here
    (ckpt / "notes").mkdir()
    new = _write(ckpt, 2)
    assert new != old and _seed_of(ckpt) == 2
    assert _names(ckpt) == ["config.json", "notes", "other", "selection.parquet", "weights.pt"]
    assert _names(tmp_path) == ["ckpt"]


def test_an_evaluation_stays_when_the_same_weights_are_written_again(tmp_path: Path) -> None:
    ckpt = tmp_path / "ckpt"
    old = _write(ckpt, 1)
    _evaluation(ckpt / "eval", **{EVALUATED_WEIGHTS: old})
    assert _write(ckpt, 1) == old
    assert (ckpt / "eval" / "summary.parquet").is_file()


def test_an_older_evaluation_is_told_by_the_checkpoint_folder_it_names(tmp_path: Path) -> None:
    """Evaluations written before the weights were recorded name the checkpoint folder: one of
    this folder goes with its weights, one of another folder (or none named) stays."""
    ckpt = tmp_path / "ckpt"
    _write(ckpt, 1)
    _evaluation(ckpt / "eval", checkpoint=str(ckpt))
    _evaluation(ckpt / "elsewhere", checkpoint=str(tmp_path / "another"))
    _evaluation(ckpt / "unnamed")
    _write(ckpt, 2)
    assert _names(ckpt) == [
        "config.json",
        "elsewhere",
        "selection.parquet",
        "unnamed",
        "weights.pt",
    ]


def test_a_crash_after_the_swap_does_not_bring_a_stale_evaluation_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ckpt = tmp_path / "ckpt"
    old = _write(ckpt, 1)
    _evaluation(ckpt / "eval", **{EVALUATED_WEIGHTS: old})

    def killed(old, new, unit, keep):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic, "_carry", killed)
    with pytest.raises(KeyboardInterrupt):
        _write(ckpt, 2)
    monkeypatch.undo()
    assert _seed_of(ckpt) == 2 and len(_names(tmp_path)) == 2  # the old unit left beside it
    _write(ckpt, 2)  # the next write finishes the last one first
    assert "eval" not in _names(ckpt) and _names(tmp_path) == ["ckpt"]


def test_cli_retraining_removes_the_evaluation_of_the_old_weights(
    rehab_demos: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    ckpt = tmp_path / "ckpt"
    argv = ["train", "--demos", str(rehab_demos), "--out", str(ckpt), "--bc.train.batches", "3",
            "--bc.network.hidden", "8", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    evaluate = ["evaluate", "--checkpoint", str(ckpt), "--out", str(ckpt / "eval"),
                "--episodes", "1", "--workers", "0", "--quiet"]  # fmt: skip
    assert main(evaluate) == 0
    _, meta = read_table(ckpt / "eval" / "summary.parquet")
    assert meta[EVALUATED_WEIGHTS] == check_checkpoint_files(ckpt)["weights_sha256"]
    capsys.readouterr()
    assert main(argv) == 0  # the same weights again: the evaluation still holds
    assert (ckpt / "eval").is_dir() and "removed" not in capsys.readouterr().out
    assert main([*argv, "--seed", "1"]) == 0
    assert "removed eval, evaluated other weights" in capsys.readouterr().out
    names = _names(ckpt)  # the curve's event file is the new unit's own, one of them
    events = [n for n in names if n.startswith("events.out.tfevents.")]
    assert len(events) == 1
    assert [n for n in names if n not in events] == [
        "config.json", "curve.parquet", "selection.parquet", "weights.pt"
    ]  # fmt: skip


def test_an_edited_config_json_without_its_checksum_is_refused(tmp_path: Path) -> None:
    import json

    from safe_bc.bc.checkpoint import FORMAT, META_SHA256

    cfg = BCConfig(network=TINY_MLP)
    save_checkpoint(tmp_path, BCNet(ModelSpec.for_data((5,), 2), cfg.preprocess, cfg.network), cfg)
    meta = json.loads((tmp_path / "config.json").read_text())
    assert meta["format"] == FORMAT
    meta["extra"]["env_id"] = "CarRacing-v3"
    del meta[META_SHA256]
    (tmp_path / "config.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(tmp_path)
    message = str(info.value)
    assert "\n" not in message and str(tmp_path / "config.json") in message
    assert f"no {META_SHA256}" in message


def test_format_1_checkpoints_written_before_meta_sha256_still_load(tmp_path: Path) -> None:
    """The committed checkpoints of format ``safe_bc.bc/1`` without ``meta_sha256``."""
    import json

    from safe_bc.bc.checkpoint import META_SHA256

    cfg = BCConfig(network=TINY_MLP)
    save_checkpoint(tmp_path, BCNet(ModelSpec.for_data((5,), 2), cfg.preprocess, cfg.network), cfg)
    meta = json.loads((tmp_path / "config.json").read_text())
    meta["format"] = "safe_bc.bc/1"
    del meta[META_SHA256]
    (tmp_path / "config.json").write_text(json.dumps(meta))
    load_checkpoint(tmp_path)
    committed = Path(__file__).parent.parent / "results/improve/rehab/starts/seed0"
    assert META_SHA256 not in json.loads((committed / "config.json").read_text())
    load_checkpoint(committed)
