"""Save / load a ``BCNet``: ``weights.pt`` (state_dict) + ``config.json``, each written atomically.

``config.json`` is written last and records the SHA-256 of ``weights.pt``, so a directory
whose two files do not belong together (a crash between the two writes) is detected.

A checkpoint folder is one unit: :func:`checkpoint_unit` writes it (weights, config, and the
``selection.parquet`` and ``curve.parquet`` beside them) into a temporary folder that replaces
the old one whole (:func:`safe_bc.data.atomic.atomic_dir`), and seals it: ``config.json`` then
also records the SHA-256 of every other file of the unit (``files_sha256``), which
:func:`load_checkpoint` and :func:`check_checkpoint_files` verify. Checkpoints written
before ``files_sha256`` existed have only ``weights_sha256``; they load as before.

``config.json`` also records its own SHA-256 (``meta_sha256``). It is required from format
``safe_bc.bc/2`` on (a ``config.json`` edited and its ``meta_sha256`` removed is refused);
``safe_bc.bc/1`` checkpoints, some written before ``meta_sha256`` existed, load without it.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import pickle
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch

from safe_bc.bc.config import BCConfig
from safe_bc.bc.net import BCNet, ModelSpec
from safe_bc.data.atomic import atomic_dir, atomic_write, write_json_atomic
from safe_bc.data.curves import EVENTS_GLOB

WEIGHTS = "weights.pt"
CONFIG = "config.json"
SELECTION = "selection.parquet"
CURVE = "curve.parquet"
"""The learning curve of the weights (``TrainResult.curve``); its TensorBoard event files lie
beside it and go with the unit they were written in."""
UNIT = (WEIGHTS, CONFIG, SELECTION, CURVE)
"""The files of a checkpoint unit; anything else in the folder (an ``eval/`` folder) is kept
when the unit is rewritten, except an evaluation of the replaced weights when the new
weights differ (:func:`keeps_entry`)."""
EVALUATED_WEIGHTS = "checkpoint_weights_sha256"
"""Key in an evaluation table's metadata (``safe-bc evaluate``) of the SHA-256 of the weights
it evaluated: what ties an evaluation folder to one checkpoint's weights."""
EVALUATION_TABLES = ("summary.parquet", "episodes.parquet")
"""The tables of a ``safe-bc evaluate`` folder whose metadata names the evaluated weights."""
FORMAT = "safe_bc.bc/2"
"""The format :func:`save_checkpoint` writes: ``meta_sha256`` is required."""
FORMATS = ("safe_bc.bc/1", FORMAT)
"""The formats :func:`read_checkpoint_meta` accepts; ``safe_bc.bc/1`` (the same layout, written
before ``meta_sha256`` was required) loads with or without it."""


class CheckpointError(RuntimeError):
    """A checkpoint directory is missing, incomplete or malformed."""


class CheckpointNotFoundError(CheckpointError, FileNotFoundError):
    """The checkpoint directory or one of its files does not exist."""


class UnsafeCheckpointError(CheckpointError):
    """``weights.pt`` holds Python objects that safe loading (``torch.load(weights_only=True)``)
    refuses: it was not written by :func:`save_checkpoint`. safe_bc never retries unsafely."""


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def save_checkpoint(
    directory: str | Path,
    model: BCNet,
    configs: BCConfig,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``model``'s weights and ``{format, spec, config, extra, weights_sha256}``.

    Args:
        directory: created if needed; existing checkpoint files are replaced.
        model: the net (its ``spec`` and configs rebuild it on load).
        configs: the configs it was trained with.
        extra: strict-JSON-able metadata (e.g. the selection summary, metrics).

    Returns:
        ``directory`` as a ``Path``.
    """
    directory = Path(directory)
    if configs.preprocess != model.pre_cfg or configs.network != model.net_cfg:
        raise ValueError("configs do not match the model's preprocess/network configs")
    meta = {
        "format": FORMAT,
        "spec": model.spec.to_dict(),
        "config": configs.to_dict(),
        "extra": extra or {},
    }
    try:
        json.dumps(meta, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise ValueError(f"checkpoint metadata is not strict JSON: {e}") from e
    directory.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    try:
        with atomic_write(directory / WEIGHTS) as f:
            torch.save(state, f)
    except (RuntimeError, OSError) as e:  # torch wraps a failed write (a full disk) in its own
        raise _write_error(e, directory / WEIGHTS) from None
    meta["weights_sha256"] = _sha256(directory / WEIGHTS)
    write_json_atomic(directory / CONFIG, with_meta_sha256(meta), allow_nan=False)
    return directory


def _write_error(error: BaseException, path: Path) -> BaseException:
    """The ``OSError`` behind torch's ``RuntimeError`` of a failed write of ``path`` (a full
    disk: one line naming the file), else ``error`` itself."""
    seen: BaseException | None = error
    while seen is not None:
        if isinstance(seen, OSError):
            return OSError(seen.errno, seen.strerror or str(seen), seen.filename or str(path))
        seen = seen.__cause__ or seen.__context__
    return error


META_SHA256 = "meta_sha256"
"""Key in ``config.json`` of the SHA-256 of the rest of ``config.json`` (sorted JSON), so that
every file of a checkpoint, ``config.json`` included, is covered by a checksum."""


def meta_digest(meta: dict[str, Any]) -> str:
    """SHA-256 of ``meta`` without its :data:`META_SHA256` entry (sorted, compact JSON)."""
    rest = {k: v for k, v in meta.items() if k != META_SHA256}
    text = json.dumps(rest, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def with_meta_sha256(meta: dict[str, Any]) -> dict[str, Any]:
    """``meta`` with its :data:`META_SHA256` (re)computed."""
    return {**meta, META_SHA256: meta_digest(meta)}


@contextmanager
def checkpoint_unit(directory: str | Path) -> Iterator[Path]:
    """Write a checkpoint folder as one unit: yields a temporary folder beside ``directory``
    for :func:`save_checkpoint` and the ``selection.parquet``; on a clean exit it is sealed
    (``files_sha256`` in ``config.json``) and replaces ``directory``'s unit at once. An error
    (a crash) leaves the old unit as it was and no temporary files (the next write to
    ``directory`` removes those of a hard kill). Hold ``directory``'s lock while writing."""
    with atomic_dir(directory, unit=UNIT, keep=keeps_entry) as staging:
        yield staging
        _seal(staging)


def _weights_sha256(directory: Path) -> str | None:
    """The ``weights_sha256`` that ``directory``'s ``config.json`` records, or ``None``."""
    try:
        value = json.loads((directory / CONFIG).read_text()).get("weights_sha256")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        return None
    return value if isinstance(value, str) else None


def evaluated_weights(entry: Path, checkpoint: Path, weights: str | None) -> str | None:
    """The SHA-256 of the weights the ``safe-bc evaluate`` folder ``entry`` evaluated, or
    ``None`` when ``entry`` is not such a folder (or a link, or unreadable).

    Its tables record it (:data:`EVALUATED_WEIGHTS`); tables written before that record
    name only the evaluated checkpoint folder: when that is ``checkpoint`` (resolved), the
    evaluation was of the weights that folder held, given as ``weights``.
    """
    from safe_bc.data.store import DatasetError, read_table_metadata

    if entry.is_symlink() or not entry.is_dir():
        return None
    for name in EVALUATION_TABLES:
        if not (entry / name).is_file():
            continue
        try:
            meta = read_table_metadata(entry / name)
        except (DatasetError, ValueError):
            return None
        recorded = meta.get(EVALUATED_WEIGHTS)
        if isinstance(recorded, str):
            return recorded
        named = meta.get("checkpoint")
        if isinstance(named, str) and Path(named).resolve() == checkpoint.resolve():
            return weights
        return None
    return None


def keeps_entry(entry: Path, old: Path, new: Path) -> bool:
    """Whether ``entry`` of the replaced checkpoint folder ``old`` moves into the new unit
    ``new`` (:func:`safe_bc.data.atomic.atomic_dir`'s ``keep``): everything but an evaluation of
    the replaced weights (:func:`evaluated_weights`) when the new weights differ from them,
    and the replaced unit's TensorBoard event files (its curve's). What cannot be told apart
    (no recorded weights, an unreadable table, not an evaluation) is kept."""
    if fnmatch.fnmatch(entry.name, EVENTS_GLOB):
        return False
    old_weights, new_weights = _weights_sha256(old), _weights_sha256(new)
    if old_weights is None or old_weights == new_weights:
        return True
    return evaluated_weights(entry, new, old_weights) != old_weights


def _seal(directory: Path) -> None:
    """Record the SHA-256 of every file of the unit besides the weights in ``config.json``."""
    meta = read_checkpoint_meta(directory)
    meta["files_sha256"] = {
        p.name: _sha256(p)
        for p in sorted(directory.iterdir())
        if p.name in UNIT and p.name not in (WEIGHTS, CONFIG)
    }
    write_json_atomic(directory / CONFIG, with_meta_sha256(meta), allow_nan=False)


def check_checkpoint_files(directory: str | Path) -> dict[str, Any]:
    """Check that ``directory`` is a whole unit: ``config.json`` parses and matches its own
    ``meta_sha256`` (required in format :data:`FORMAT`), ``weights.pt`` and every file in
    ``files_sha256`` exist and match their recorded SHA-256. Returns the metadata.

    Raises:
        CheckpointNotFoundError: the folder or one of its files is missing.
        CheckpointError: a file does not match (a partial or mixed save).
    """
    directory = Path(directory)
    meta = read_checkpoint_meta(directory)
    if META_SHA256 not in meta and meta.get("format") == FORMAT:
        raise CheckpointError(
            f"{directory / CONFIG} has no {META_SHA256} (required for a {FORMAT} checkpoint: "
            "edited or damaged after the save); save the checkpoint again"
        )
    if META_SHA256 in meta and meta[META_SHA256] != meta_digest(meta):
        raise CheckpointError(
            f"{directory / CONFIG} does not match the sha256 recorded in it (edited or damaged "
            "after the save); save the checkpoint again"
        )
    files = meta.get("files_sha256", {})
    if not isinstance(files, dict):
        raise CheckpointError(f"malformed {directory / CONFIG}: files_sha256 is not a mapping")
    for name, digest in {WEIGHTS: meta.get("weights_sha256"), **files}.items():
        path = directory / name
        if not path.is_file():
            raise CheckpointNotFoundError(f"incomplete checkpoint at {directory}: missing {name}")
        if digest != _sha256(path):
            raise CheckpointError(
                f"{path} does not match the sha256 recorded in {CONFIG} (partial or mixed save)"
            )
    return meta


def read_checkpoint_meta(directory: str | Path) -> dict[str, Any]:
    """The parsed ``config.json`` (``format``, ``spec``, ``config``, ``extra``, ...)."""
    directory = Path(directory)
    path = directory / CONFIG
    if not directory.is_dir():
        raise CheckpointNotFoundError(f"no checkpoint directory at {directory}")
    if not path.is_file():
        raise CheckpointNotFoundError(f"incomplete checkpoint at {directory}: missing {CONFIG}")
    try:
        meta = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CheckpointError(f"malformed {path}: {e}") from e
    if not isinstance(meta, dict) or meta.get("format") not in FORMATS:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise CheckpointError(f"{path} is not a {FORMAT} checkpoint (format={got!r})")
    return meta


def load_checkpoint(directory: str | Path) -> tuple[BCNet, BCConfig]:
    """Rebuild the net saved by ``save_checkpoint`` (eval mode, CPU) and its configs.

    Raises:
        CheckpointNotFoundError: the directory or a file is missing.
        UnsafeCheckpointError: ``weights.pt`` is refused by safe loading (``weights_only``).
        CheckpointError: malformed JSON, configs, weights, or weights from another save.
    """
    directory = Path(directory)
    meta = check_checkpoint_files(directory)
    weights = directory / WEIGHTS
    try:
        configs = BCConfig.from_dict(meta["config"])
        spec = ModelSpec.from_dict(meta["spec"])
        model = BCNet(spec, configs.preprocess, configs.network)
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"malformed configs in {directory / CONFIG}: {e!r}") from e
    state = _load_weights(weights)
    try:
        model.load_state_dict(state)
    except Exception as e:  # RuntimeError for mismatched keys/shapes, others for non-dicts
        raise CheckpointError(
            f"cannot load weights from {weights}: they do not fit the net in {CONFIG} "
            f"({_one_line(e)})"
        ) from None
    return model.eval(), configs


def _one_line(e: BaseException, limit: int = 300) -> str:
    text = " ".join(line.strip() for line in str(e).splitlines() if line.strip())
    text = text or type(e).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _first_line(e: BaseException) -> str:
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    return lines[0] if lines else type(e).__name__


def _load_weights(weights: Path) -> Any:
    """``torch.load(weights_only=True)`` with one-line errors that name the file.

    A file that safe loading refuses raises :class:`UnsafeCheckpointError` naming the
    offending Python type; torch's advice to retry with ``weights_only=False`` (which
    would run arbitrary code from the file) is deliberately not passed on.
    """
    try:
        return torch.load(weights, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        text = str(e)
        found = re.search(r"GLOBAL ([\w.]+)", text)
        if found:
            raise UnsafeCheckpointError(
                f"{weights}: refused by safe loading: it holds a {found.group(1)} object, not "
                "just tensors (not written by safe_bc's save_checkpoint; retrain, or re-save "
                "the state_dict)"
            ) from None
        marker = "WeightsUnpickler error:"
        detail = text.split(marker, 1)[1] if marker in text else text
        if detail.startswith("Weights only load failed"):  # torch's advice, no detail
            detail = "refused by safe loading"
        raise CheckpointError(
            f"cannot load weights from {weights}: not a torch weights file ({_first_line(detail)})"
        ) from None
    except Exception as e:  # torch raises several types for corrupt files
        raise CheckpointError(f"cannot load weights from {weights}: {_first_line(e)}") from None
