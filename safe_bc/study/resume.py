"""What a study's rerun may resume: the study's own records decide, Tune's state must agree.

A study keeps its own records in ``results/<study>/``: ``study.json`` (what the trials depend
on and where the Tune experiment lives), ``history.jsonl`` (every report, and a line per trial
whose end Tune has saved), the trials' rounds and checkpoints, and its Optuna copy. Before a
rerun touches Tune, :func:`check_resume` compares them with this run and with Tune's saved
experiment state; a rerun that would drop, mix or redo finished work is refused with
:class:`ResumeRefused`, one line naming the difference and how to recover.

Tune (Ray 2.60) writes its experiment state in place and, when that state cannot be read,
silently starts the experiment over; :func:`install_atomic_upload` makes its copy to a local
storage folder whole-or-nothing, file by file.
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from safe_bc.data.atomic import atomic_write, write_json_atomic
from safe_bc.data.provenance import repo_relative

STUDY_RECORD = "study.json"
"""The study's identity in ``results/<study>/``: what its trials depend on."""
TUNE_STATE = "experiment_state-*.json"
"""Tune's saved experiment state in ``<storage>/<study>/`` (one file per driver run)."""
OWNER = "safe_bc_results.json"
"""In a local ``<storage>/<study>/``: the results folder whose study the Tune experiment is
(``{"results": "/abs/results/<study>"}``); another results folder may not resume it."""


class ResumeRefused(ValueError):
    """A rerun that would drop, mix or redo a study's finished work (one line)."""


# --- pure: what differs ---------------------------------------------------------------------


def _flat(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, Mapping):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out or {prefix.rstrip("."): {}}
    return {prefix.rstrip("."): value}


def differences(stored: Mapping[str, Any], now: Mapping[str, Any]) -> list[str]:
    """``"field old -> new"`` for every (nested, dotted) field that differs.

    >>> differences({"max_steps": 100, "base": {"lr": 1}}, {"max_steps": 160, "base": {"lr": 1}})
    ['max_steps 100 -> 160']
    """
    a, b = _flat(stored), _flat(now)
    missing = object()
    out = []
    for key in sorted(set(a) | set(b)):
        old, new = a.get(key, missing), b.get(key, missing)
        if old != new:
            show = ["(none)" if v is missing else json.dumps(v, default=str) for v in (old, new)]
            out.append(f"{key} {show[0]} -> {show[1]}")
    return out


def identity_problem(stored: Mapping[str, Any], now: Mapping[str, Any]) -> str:
    """What differs between the identity a study was started with and this run's (``""``:
    nothing). Keys the stored record lacks (a study started by an older safe_bc) are not
    compared."""
    shared = {k: v for k, v in now.items() if k in stored}
    changed = differences({k: stored[k] for k in shared}, shared)
    if not changed:
        return ""
    more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
    return ", ".join(changed[:3]) + more


# --- the study's records ------------------------------------------------------------------


def read_record(out: Path) -> dict[str, Any] | None:
    """``study.json`` of the study at ``out`` (``None``: none, or unreadable)."""
    try:
        record = json.loads((out / STUDY_RECORD).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return record if isinstance(record, dict) else None


def history_events(path: Path) -> tuple[set[str], set[str]]:
    """``(reported, ended)``: the trial ids with a report in the study's ``history.jsonl`` and
    those whose end Tune had saved (a ``complete`` or ``error`` event); a line cut short is
    skipped."""
    return _events(_history_rows(path))


def _events(rows: list[dict[str, Any]]) -> tuple[set[str], set[str]]:
    """:func:`history_events` of rows already read."""
    reported: set[str] = set()
    ended: set[str] = set()
    for row in rows:
        (ended if row.get("event") else reported).add(str(row["trial_id"]))
    return reported, ended


def _history_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of the study's ``history.jsonl`` that name a trial (a line cut short, or a
    missing file, gives none)."""
    rows = []
    with contextlib.suppress(OSError):
        for line in path.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(row, dict) and "trial_id" in row:
                rows.append(row)
    return rows


def reported_iterations(rows: list[dict[str, Any]]) -> dict[str, set[int]]:
    """Trial id -> the ``training_iteration`` of each report among the study's
    ``history.jsonl`` rows (:func:`_history_rows`)."""
    out: dict[str, set[int]] = {}
    for row in rows:
        if not row.get("event"):
            it = row.get("training_iteration")
            out.setdefault(str(row["trial_id"]), set()).update([it] if it is not None else [])
    return out


def state_iterations(file: Path) -> dict[str, int]:
    """Trial id -> the ``training_iteration`` of the last result Tune's experiment state
    ``file`` holds for it (trials that never reported are left out; ``{}`` when the file does
    not read whole)."""
    try:
        trials = json.loads(file.read_bytes())["trial_data"]
        out = {}
        for state, runtime in trials:
            last = (json.loads(runtime) or {}).get("last_result") or {}
            if last.get("training_iteration") is not None:
                out[str(json.loads(state)["trial_id"])] = int(last["training_iteration"])
    except (OSError, ValueError, KeyError, TypeError, IndexError, AttributeError):
        return {}
    return out


def newest_state(exp_path: str) -> Path | None:
    """The newest Tune experiment state file in the local folder ``exp_path`` (the one Tune
    restores from; ``None``: none)."""
    files = sorted(Path(exp_path).glob(TUNE_STATE))
    return files[-1] if files else None


def tune_state(exp_path: str) -> tuple[Path | None, set[str], str]:
    """``(file, trial ids, problem)`` of the newest Tune experiment state in the local folder
    ``exp_path`` (the one Tune restores from); ``problem`` is ``""`` when it reads whole."""
    newest = newest_state(exp_path)
    if newest is None:
        return None, set(), "no experiment state file"
    try:
        data = newest.read_bytes()
    except OSError as e:
        return newest, set(), f"unreadable ({e.strerror or e})"
    if not data.strip():
        return newest, set(), "empty"
    try:
        state = json.loads(data)
        ids = {str(json.loads(t[0])["trial_id"]) for t in state["trial_data"]}
    except (ValueError, KeyError, TypeError, IndexError) as e:
        what = " ".join(str(e).split())[:80]
        return newest, set(), f"not whole JSON Tune can read ({what})"
    return newest, ids, ""


def with_more_trials(stored: Mapping[str, Any], now: Mapping[str, Any]) -> dict[str, Any]:
    """``stored`` settings taking ``now``'s trial count where it is larger: more trials
    continue a study (the driver raises Tune's count), fewer would drop finished ones.

    >>> with_more_trials({"trials": 2, "batches": 5}, {"trials": 3, "batches": 6})
    {'trials': 3, 'batches': 5}
    >>> with_more_trials({"trials": 3}, {"trials": 2})
    {'trials': 3}
    """
    out = dict(stored)
    before, after = stored.get("trials"), now.get("trials")
    if isinstance(before, int) and isinstance(after, int) and after > before:
        out["trials"] = after
    return out


def check_resume(
    out: Path,
    *,
    settings: Mapping[str, Any],
    exp_path: str,
    restoring: bool,
    local: bool,
) -> None:
    """Refuse a rerun of the study at ``out`` that does not continue its records.

    Args:
        out: the study's ``results/<study>/``.
        settings: this run's :func:`safe_bc.study.spec.settings_of`.
        exp_path: this run's Tune experiment path.
        restoring: Tune has an experiment at ``exp_path`` to restore.
        local: ``exp_path`` is a local folder (its state file can be read).

    Raises:
        ResumeRefused: one line naming what differs and how to recover.
    """
    record = read_record(out)
    rows = _history_rows(out / "history.jsonl")
    reported, ended = _events(rows)
    tables = (out / "trials.parquet").exists()
    has_work = bool(reported or ended) or tables
    fresh = "pass --fresh to start the study over"
    if local:  # a results folder without any record cannot be resuming the experiment
        _check_owner(out, exp_path, restoring and record is None and not has_work)
    if record is not None:
        stored_path = record.get("experiment_path")  # relative to the repository inside it
        here = (exp_path, repo_relative(exp_path))
        if stored_path is not None and stored_path not in here and (has_work or restoring):
            raise ResumeRefused(
                f"the study at {out} keeps its Tune experiment at {stored_path}, not {exp_path}: "
                f"rerun with the --storage it was started with to resume it, or {fresh} here"
            )
        if "settings" in record and (has_work or restoring):
            what = identity_problem(with_more_trials(record["settings"], settings), settings)
            if what:
                raise ResumeRefused(
                    f"the study at {out} was started with other settings ({what}): its trials "
                    f"would mix both; rerun with the same study file to resume, or {fresh}"
                )
    if not restoring:
        if ended or tables:  # in-flight reports only: nothing finished is lost by a new start
            n = len(ended)
            raise ResumeRefused(
                f"the study at {out} has recorded trials ({n} finished) but no Tune experiment "
                f"at {exp_path} to resume them with: restore that folder, or {fresh}"
            )
        return
    if not local:
        return
    _check_state_knows_ended(out, exp_path, ended, fresh)
    _check_history_whole(out, exp_path, rows, fresh)


def published_settings(out: Path) -> dict[str, Any] | None:
    """The settings the study at ``out`` was made with: its ``study.json``'s, else those its
    trial table records (a study started before ``study.json`` kept them); ``None``: neither
    reads."""
    record = read_record(out)
    if record is not None and isinstance(record.get("settings"), dict):
        return record["settings"]
    from safe_bc.data.store import DatasetError, read_table_metadata
    from safe_bc.study.spec import settings_of

    try:
        summary = read_table_metadata(out / "trials.parquet").get("study")
    except DatasetError:
        return None
    return settings_of(summary) if isinstance(summary, dict) else None


def check_published(out: Path, settings: Mapping[str, Any]) -> None:
    """A committed study (:func:`safe_bc.data.provenance.committed_unchanged`) is run again from the
    start only with the settings it was made with (a reproduction, compared with ``git
    diff``); another trial count or ``--set`` would overwrite it with another study.

    Raises:
        ResumeRefused: one line naming what differs and the two ways out.
    """
    stored = published_settings(out)
    what = "its settings are unreadable" if stored is None else identity_problem(stored, settings)
    if what:
        raise ResumeRefused(
            f"{out} holds a committed study made with other settings ({what}) and no Tune "
            "experiment here to resume: pass --results DIR to write this study to DIR/"
            f"{out.name}/, or --fresh to replace the committed one (git keeps it)"
        )


def experiment_owner(exp_path: str) -> str | None:
    """The results folder recorded as the owner of the local Tune experiment ``exp_path``
    (:data:`OWNER`; ``None``: none recorded, or unreadable)."""
    try:
        owner = json.loads((Path(exp_path) / OWNER).read_text()).get("results")
    except (OSError, ValueError, AttributeError):
        return None
    return owner if isinstance(owner, str) else None


def claim_experiment(exp_path: str, out: Path) -> None:
    """Record ``out`` as the owner of the local Tune experiment ``exp_path`` (once)."""
    if experiment_owner(exp_path) is None:
        Path(exp_path).mkdir(parents=True, exist_ok=True)
        write_json_atomic(Path(exp_path) / OWNER, {"results": str(Path(out).resolve())})


def _check_owner(out: Path, exp_path: str, unrecorded: bool) -> None:
    """One storage experiment belongs to one results folder: an experiment another folder's
    study owns (:data:`OWNER`), or, ``unrecorded``, one this folder has no records of (an
    experiment without an owner file), is not resumed from here."""
    owner = experiment_owner(exp_path)
    here = str(Path(out).resolve())
    if owner is not None and owner != here:
        raise ResumeRefused(
            f"the Tune experiment at {exp_path} belongs to the study at {owner}, not {out}: "
            f"pass another --storage for this one, or --results {Path(owner).parent} to "
            "resume that one; nothing was run"
        )
    if owner is None and unrecorded:
        raise ResumeRefused(
            f"the Tune experiment at {exp_path} was started by a study with another --results "
            f"({out} holds no records of it): pass another --storage for this one, or the "
            "--results it was started with to resume it; nothing was run"
        )


def _check_state_knows_ended(out: Path, exp_path: str, ended: set[str], fresh: str) -> None:
    """Tune's experiment state must read whole and know every trial ``history.jsonl`` records
    as ended (when none has ended, Tune may start over without losing anything)."""
    if not ended:
        return
    file, known, problem = tune_state(exp_path)
    where = file or Path(exp_path)
    if problem:
        raise ResumeRefused(
            f"{where}: Tune's experiment state is {problem}; Tune would start over and drop the "
            f"study's {len(ended)} finished trial(s) kept in {out}: nothing was run; restore the "
            f"file from a copy, or {fresh}"
        )
    lost = sorted(ended - known)
    if lost:
        shown = ", ".join(lost[:5]) + (" ..." if len(lost) > 5 else "")
        raise ResumeRefused(
            f"{where}: Tune's experiment state does not know {len(lost)} trial(s) that "
            f"{out / 'history.jsonl'} records as finished ({shown}): it is older or damaged, "
            f"and resuming would drop them; nothing was run; restore the file, or {fresh}"
        )


def _check_history_whole(out: Path, exp_path: str, rows: list[dict[str, Any]], fresh: str) -> None:
    """``history.jsonl`` must hold every report Tune's experiment state knows of: Tune records
    a result only after the study's callback has appended it, so a trial whose last result is
    missing there (an emptied or cut-short file) would lose its rows in ``history.parquet``."""
    file = newest_state(exp_path)
    if file is None:
        return
    reported = reported_iterations(rows)
    missing = sorted(t for t, n in state_iterations(file).items() if n not in reported.get(t, ()))
    if missing:
        shown = ", ".join(missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise ResumeRefused(
            f"{out / 'history.jsonl'}: lacks reports of {len(missing)} trial(s) that Tune's "
            f"experiment state {file.name} records ({shown}): the file is damaged or cut short, "
            "and history.parquet would lose their rows; nothing was run; restore it from a "
            f"copy, or {fresh}"
        )


# --- Tune's copy of its state, whole or not at all ------------------------------------------


def _atomic_copy_tree(local_path: str, dest: str, exclude: list[str] | None) -> None:
    """Copy the file or folder ``local_path`` to the local path ``dest``, every file through
    a temporary file and a rename (a full disk leaves the old file, never half a new one)."""
    src = Path(local_path)
    if src.is_file():
        pairs = [(src, Path(dest))]
    else:
        pairs = []
        for root, _, files in os.walk(src):
            for name in files:
                path = Path(root, name)
                rel = path.relative_to(src).as_posix()
                if exclude and any(fnmatch.fnmatch(rel, pat) for pat in exclude):
                    continue
                pairs.append((path, Path(dest, rel)))
        Path(dest).mkdir(parents=True, exist_ok=True)
    for source, target in pairs:
        with open(source, "rb") as f, atomic_write(target) as g:
            shutil.copyfileobj(f, g)


_FAILED_COPIES: list[OSError] = []
"""The driver's copies of Tune's state to the storage that failed since the last
:func:`take_failed_copy` (Tune only logs them, in a thread)."""


def take_failed_copy() -> OSError | None:
    """The first copy of Tune's state to the storage that failed since the last call (``None``:
    none); the record is cleared."""
    failed = _FAILED_COPIES[0] if _FAILED_COPIES else None
    _FAILED_COPIES.clear()
    return failed


def install_atomic_upload() -> None:
    """Make Tune's copy of the driver's files (experiment state, searcher state,
    ``tuner.pkl``) to a *local* storage folder atomic per file; other filesystems keep Tune's
    own copy. A copy that fails is recorded for :func:`take_failed_copy`. Idempotent.

    Raises:
        RuntimeError: the installed Ray lacks the function this replaces.
    """
    import pyarrow.fs as pafs
    from ray.train._internal import storage

    original = getattr(storage, "_upload_to_fs_path", None)
    if original is None:
        raise RuntimeError(
            "ray.train._internal.storage has no _upload_to_fs_path; safe_bc's atomic copy of "
            "Tune's experiment state (study/resume.py) needs updating for this Ray version"
        )
    if getattr(original, "_safe_bc_atomic", False):
        return

    def copy(local_path: str, fs: Any, fs_path: str, exclude: list[str] | None) -> None:
        if isinstance(fs, pafs.LocalFileSystem) or (
            isinstance(fs, pafs.SubTreeFileSystem) and isinstance(fs.base_fs, pafs.LocalFileSystem)
        ):
            base = fs.base_path if isinstance(fs, pafs.SubTreeFileSystem) else ""
            _atomic_copy_tree(local_path, os.path.join(base, fs_path), exclude)
            return
        original(local_path, fs, fs_path, exclude)

    def upload(local_path: str, fs: Any, fs_path: str, exclude: list[str] | None = None) -> None:
        try:
            copy(local_path, fs, fs_path, exclude)
        except OSError as e:  # Tune logs it and goes on; the study stops on it instead
            _FAILED_COPIES.append(OSError(e.errno, e.strerror or str(e), e.filename or fs_path))
            raise

    upload._safe_bc_atomic = True  # type: ignore[attr-defined]
    storage._upload_to_fs_path = upload
