"""A study's rerun resumes only what its own records say it may: Tune's saved state, the
storage, the study file and the Optuna copy are checked against them before anything runs
(``safe_bc/study/resume.py``), and the files involved are written whole or not at all."""

from __future__ import annotations

import errno
import json
import math
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest

from safe_bc.study.plan import settings_of
from safe_bc.study.resume import (
    OWNER,
    ResumeRefused,
    check_resume,
    claim_experiment,
    differences,
    experiment_owner,
    identity_problem,
    install_atomic_upload,
    tune_state,
)

SETTINGS = {"trials": 2, "max_steps": 100, "base": {"bc": {"lr": 0.001}}}


def test_differences_name_each_changed_field_old_and_new() -> None:
    now = {**SETTINGS, "max_steps": 160, "base": {"bc": {"lr": 0.01}}}
    assert differences(SETTINGS, now) == ["base.bc.lr 0.001 -> 0.01", "max_steps 100 -> 160"]
    assert differences(SETTINGS, SETTINGS) == []
    assert differences({"a": 1}, {"b": 1}) == ["a 1 -> (none)", "b (none) -> 1"]
    # a field an older record lacks is not compared; more than three changes are counted
    assert identity_problem({"trials": 2}, SETTINGS) == ""
    many = {f"f{i}": i for i in range(5)}
    assert identity_problem(many, {k: v + 1 for k, v in many.items()}).endswith("and 2 more")


def test_settings_leave_out_where_and_how_fast_only() -> None:
    from safe_bc.study.spec import Float, StudySpec

    spec = StudySpec("s", {"selection.alpha": Float(0.0, 1.0)}, trials=2, max_steps=100)
    fast = StudySpec(
        "s", {"selection.alpha": Float(0.0, 1.0)}, trials=2, max_steps=100, max_concurrent=4,
        cpus_per_trial=0.5, storage="/elsewhere", results=Path("/other"), max_failures=5,
    )  # fmt: skip
    assert settings_of(spec.summary()) == settings_of(fast.summary())
    longer = StudySpec("s", {"selection.alpha": Float(0.0, 1.0)}, trials=2, max_steps=160)
    changed = differences(settings_of(spec.summary()), settings_of(longer.summary()))
    assert changed == ["max_steps 100 -> 160"]


def _study(tmp_path: Path, finished: tuple[str, ...] = ("a", "b")) -> tuple[Path, Path]:
    """A study's records (``results/s``) and its Tune experiment (``ray/s``) whose state knows
    trials a, b and c; a and b ended (``history.jsonl``)."""
    out, exp = tmp_path / "results" / "s", tmp_path / "ray" / "s"
    out.mkdir(parents=True)
    exp.mkdir(parents=True)
    (out / "study.json").write_text(
        json.dumps({"trials": 3, "experiment_path": str(exp), "settings": SETTINGS})
    )
    rows = [{"trial_id": t, "phase": "evaluated"} for t in ("a", "b", "c")]
    rows += [{"trial_id": t, "event": "complete", "timestamp": 1.0} for t in finished]
    (out / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    _state(exp, ("a", "b", "c"))
    (exp / "tuner.pkl").write_bytes(b"pickled tuner")
    return out, exp


def _state(exp: Path, ids: tuple[str, ...], name: str = "2026-01-01_00-00-00") -> Path:
    """An experiment state as Tune 2.60 writes it (trial states as JSON strings)."""
    data = [[json.dumps({"trial_id": t, "status": "TERMINATED"}), "{}"] for t in ids]
    path = exp / f"experiment_state-{name}.json"
    path.write_text(json.dumps({"trial_data": data, "runner_data": {}, "stats": {}}))
    return path


def _check(out: Path, exp: Path, settings=SETTINGS, restoring: bool = True) -> None:
    check_resume(out, settings=settings, exp_path=str(exp), restoring=restoring, local=True)


def _refused(out: Path, exp: Path, **kw) -> str:
    with pytest.raises(ResumeRefused) as e:
        _check(out, exp, **kw)
    message = str(e.value)
    assert "\n" not in message and "--fresh" in message
    return message


def test_a_whole_tune_state_that_knows_every_finished_trial_resumes(tmp_path: Path) -> None:
    out, exp = _study(tmp_path)
    _check(out, exp)
    file, ids, problem = tune_state(str(exp))
    assert problem == "" and ids == {"a", "b", "c"} and file is not None


@pytest.mark.parametrize(
    "damage,what",
    [
        (lambda p: p.write_bytes(b""), "is empty"),
        (lambda p: p.write_bytes(p.read_bytes()[:40]), "not whole JSON"),
        (lambda p: p.write_text('{"stats": {}}'), "not whole JSON"),
        (lambda p: p.write_bytes(b"\0" * 64), "not whole JSON"),
    ],
    ids=["empty", "cut-short", "no-trials", "zeroed"],
)
def test_an_unreadable_tune_state_is_refused_in_one_line_and_deletes_nothing(
    tmp_path: Path, damage, what: str
) -> None:
    out, exp = _study(tmp_path)
    (exp / "trial_a").mkdir()
    state = next(exp.glob("experiment_state-*.json"))
    damage(state)
    message = _refused(out, exp)
    assert message.startswith(f"{state}: ") and what in message
    assert "2 finished trial(s)" in message and "nothing was run" in message
    assert (exp / "trial_a").is_dir() and (out / "history.jsonl").exists()


def test_a_tune_state_that_lost_a_finished_trial_is_refused(tmp_path: Path) -> None:
    out, exp = _study(tmp_path)
    _state(exp, ("a", "c"), name="2026-01-02_00-00-00")  # newer, older content: b is gone
    message = _refused(out, exp)
    assert "does not know 1 trial(s)" in message and "(b)" in message
    # trials reported but never recorded as ended (lost in flight) do not block the resume
    out2, exp2 = _study(tmp_path / "two", finished=("a",))
    _state(exp2, ("a", "x"), name="2026-01-02_00-00-00")
    _check(out2, exp2)


def _reported_state(exp: Path, iterations: dict[str, int]) -> None:
    """A newer Tune state whose trials' last results carry these ``training_iteration``s."""
    data = [
        [json.dumps({"trial_id": t, "status": "TERMINATED"}),
         json.dumps({"last_result": {"training_iteration": n}, "last_result_time": -math.inf})]
        for t, n in iterations.items()
    ]  # fmt: skip
    path = exp / "experiment_state-2026-01-03_00-00-00.json"
    path.write_text(json.dumps({"trial_data": data, "runner_data": {}, "stats": {}}))


@pytest.mark.parametrize("ended", [("a", "b"), ()], ids=["ended-recorded", "nothing-ended"])
def test_a_history_that_lost_reports_tunes_state_knows_is_refused_naming_it(
    tmp_path: Path, ended: tuple[str, ...]
) -> None:
    out, exp = _study(tmp_path, finished=ended)
    history = out / "history.jsonl"
    rows = [{"trial_id": t, "phase": p, "training_iteration": n}
            for t in ("a", "b") for n, p in ((1, "screened"), (2, "evaluated"))]  # fmt: skip
    history.write_text("".join(json.dumps(r) + "\n" for r in rows))
    _reported_state(exp, {"a": 2, "b": 2, "c": 1})
    message = _refused(out, exp)  # c's only report is missing
    assert message.startswith(f"{history}: lacks reports of 1 trial(s)") and "(c)" in message
    assert "history.parquet would lose their rows" in message and "nothing was run" in message
    history.write_text("".join(json.dumps(r) + "\n" for r in rows[:3]))  # cut short: b's last
    assert "(b, c)" in _refused(out, exp)
    history.write_bytes(b"")  # emptied
    assert "lacks reports of 3 trial(s)" in _refused(out, exp)
    rows.append({"trial_id": "c", "phase": "screened", "training_iteration": 1})
    history.write_text("".join(json.dumps(r) + "\n" for r in rows))
    _check(out, exp)  # whole: every result Tune knows is there


def test_another_storage_or_study_file_or_a_lost_experiment_is_refused(tmp_path: Path) -> None:
    out, exp = _study(tmp_path)
    other = tmp_path / "elsewhere" / "s"
    message = _refused(out, other, restoring=False)
    assert f"keeps its Tune experiment at {exp}, not {other}" in message
    message = _refused(out, exp, settings={**SETTINGS, "max_steps": 160})
    assert "other settings (max_steps 100 -> 160)" in message
    shutil.rmtree(exp)  # the experiment is gone, the records are not
    message = _refused(out, exp, restoring=False)
    assert "no Tune experiment" in message and "2 finished" in message


def test_an_experiment_belongs_to_one_results_folder(tmp_path: Path) -> None:
    out, exp = _study(tmp_path)
    claim_experiment(str(exp), out)
    claim_experiment(str(exp), tmp_path / "other" / "s")  # the first claim stays
    assert experiment_owner(str(exp)) == str(out.resolve())
    _check(out, exp)
    other = tmp_path / "other" / "s"
    for restoring in (True, False):  # its Tune state saved or not yet
        message = _refused_without_fresh(other, exp, restoring=restoring)
        assert message.startswith(f"the Tune experiment at {exp} belongs to the study at {out}")
        assert f"--results {out.parent} to resume that one" in message
        assert "--storage" in message and not other.exists()
    (exp / OWNER).unlink()  # an experiment started before its owner was recorded
    message = _refused_without_fresh(other, exp)
    assert f"({other} holds no records of it)" in message
    _check(out, exp)  # its own results folder resumes it


def _refused_without_fresh(out: Path, exp: Path, **kw) -> str:
    with pytest.raises(ResumeRefused) as e:
        _check(out, exp, **kw)
    assert "\n" not in str(e.value) and "--fresh" not in str(e.value)
    return str(e.value)


def test_a_record_of_the_experiment_relative_to_the_repository_resumes_it(tmp_path: Path) -> None:
    from safe_bc.data.provenance import RESULTS

    out = tmp_path / "results" / "s"
    out.mkdir(parents=True)
    (out / "study.json").write_text(json.dumps({"experiment_path": "results/ray/s"}))
    (out / "history.jsonl").write_text('{"trial_id": "a", "phase": "trained"}\n')
    _check(out, RESULTS / "ray" / "s", restoring=False)  # the same folder, however spelled
    message = _refused(out, RESULTS / "ray" / "t", restoring=False)
    assert "keeps its Tune experiment at results/ray/s, not " in message


def test_a_study_without_records_starts(tmp_path: Path) -> None:
    out, exp = tmp_path / "results" / "s", tmp_path / "ray" / "s"
    _check(out, exp, restoring=False)  # nothing at all
    out.mkdir(parents=True)
    (out / "study.json").write_text(json.dumps({"experiment_path": "/old", "settings": {}}))
    _check(out, exp, restoring=False)  # a record but no work: a new experiment may start
    (out / "history.jsonl").write_text('{"trial_id": "a", "phase": "trained"}\n')
    assert "keeps its Tune experiment at /old" in _refused(out, exp, restoring=False)
    (out / "study.json").write_text(json.dumps({"experiment_path": str(exp), "settings": {}}))
    _check(out, exp, restoring=False)  # only a report in flight, no experiment: a new start
    exp.mkdir(parents=True)
    (exp / "tuner.pkl").write_bytes(b"x")  # Tune stopped before its first state: nothing ended
    _check(out, exp)
    (exp / "experiment_state-1.json").write_bytes(b"")
    _check(out, exp)


def test_tunes_copy_to_a_local_storage_is_whole_or_the_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pyarrow.fs as pafs
    from ray.train._internal import storage

    import safe_bc.study.resume as resume

    install_atomic_upload()
    install_atomic_upload()  # idempotent
    upload = storage._upload_to_fs_path
    assert upload._safe_bc_atomic
    # what Tune's syncer of the experiment state runs is this copy
    syncer = storage._FilesystemSyncer(storage_filesystem=pafs.LocalFileSystem())
    command, _ = syncer._sync_up_command(local_path=str(tmp_path), uri=str(tmp_path / "x"))
    assert command is upload
    staging, dest = tmp_path / "staging", tmp_path / "storage" / "exp"
    (staging / "sub").mkdir(parents=True)
    (staging / "experiment_state-1.json").write_text('{"trial_data": []}')
    (staging / "sub" / "searcher-state-1.pkl").write_bytes(b"x" * 1000)
    (staging / "skip.png").write_bytes(b"png")
    upload(str(staging), pafs.LocalFileSystem(), str(dest), exclude=["*.png"])
    assert (dest / "experiment_state-1.json").read_text() == '{"trial_data": []}'
    assert (dest / "sub" / "searcher-state-1.pkl").read_bytes() == b"x" * 1000
    assert not (dest / "skip.png").exists()

    (staging / "experiment_state-1.json").write_text('{"trial_data": [["new"]]}')

    def full(src, dst, *a, **kw):
        dst.write(src.read(5))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(resume.shutil, "copyfileobj", full)
    with pytest.raises(OSError, match="No space"):
        upload(str(staging), pafs.LocalFileSystem(), str(dest))
    assert (dest / "experiment_state-1.json").read_text() == '{"trial_data": []}'
    assert sorted(p.name for p in dest.iterdir()) == ["experiment_state-1.json", "sub"]


def _tiny_study(tmp_path: Path, extra: str = "") -> Path:
    """A study file: the smoke study with its demonstrations and storage under ``tmp_path``
    (``extra``: more ``replace`` keywords, each ending in ``, ``)."""
    smoke = Path(__file__).resolve().parents[2] / "tune_jobs" / "smoke.py"
    study_file = tmp_path / "tiny.py"
    study_file.write_text(
        "from dataclasses import replace\n"
        "from pathlib import Path\n"
        "from safe_bc.study.spec import load_study\n"
        f"STUDY = replace(load_study({str(smoke)!r}), demos=Path({str(tmp_path / 'demos')!r}),\n"
        f"    {extra}storage={str(tmp_path / 'ray')!r})\n"
    )
    return study_file


def test_a_refused_resume_at_the_cli_is_one_line_exit_2_before_ray_starts(
    tmp_path: Path, capsys
) -> None:
    from safe_bc.cli.commands import main

    study_file = _tiny_study(tmp_path, f"results=Path({str(tmp_path / 'results')!r}), ")
    out, exp = tmp_path / "results" / "smoke", tmp_path / "ray" / "smoke"
    out.mkdir(parents=True)
    (out / "history.jsonl").write_text('{"trial_id": "a", "event": "complete"}\n')
    exp.mkdir(parents=True)
    (exp / "tuner.pkl").write_bytes(b"x")
    (exp / "experiment_state-2026.json").write_bytes(b"")
    import ray

    started = ray.is_initialized()
    assert main(["tune", str(study_file)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("safe-bc tune: error: ")
    assert "experiment state is empty" in err and "--fresh" in err
    assert ray.is_initialized() == started  # refused before Ray was started


def test_another_results_folder_on_the_same_storage_is_refused_at_the_cli(
    tmp_path: Path, capsys
) -> None:
    from safe_bc.cli.commands import main

    study_file = _tiny_study(tmp_path)
    first, exp = tmp_path / "first" / "smoke", tmp_path / "ray" / "smoke"
    exp.mkdir(parents=True)
    (exp / "tuner.pkl").write_bytes(b"x")
    claim_experiment(str(exp), first)
    import ray

    started = ray.is_initialized()
    assert main(["tune", str(study_file), "--results", str(tmp_path / "second")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("safe-bc tune: error: the Tune experiment")
    assert f"belongs to the study at {first}" in err
    assert ray.is_initialized() == started  # refused before Ray was started
    assert not (tmp_path / "second" / "smoke" / "study.json").exists()


def test_the_os_error_of_a_stopped_study_says_what_a_rerun_does_once() -> None:
    from safe_bc.study.run import _os_error_in

    inner = OSError(errno.ENOSPC, "No space left on device", "/full/history.jsonl")
    once = _os_error_in(RuntimeError("wrapped").with_traceback(None))
    assert once is None
    try:
        raise RuntimeError("Tune's wrapper") from inner
    except RuntimeError as e:
        first = _os_error_in(e)
    again = _os_error_in(first)
    assert again is first and str(again).count("rerun the same command") == 1


def test_a_damaged_candidate_checkpoint_is_named_and_left_for_the_final_phase_to_retrain(
    tmp_path: Path, capsys
) -> None:
    import pyarrow.fs as pafs
    from ray import tune

    from safe_bc.bc import BCConfig, BCNet, ModelSpec, PreprocessConfig, save_checkpoint
    from safe_bc.study.run import _checkpoints
    from tests.bc.synth import TINY_MLP

    spec = ModelSpec.for_data((4,), 2)
    good, bad = tmp_path / "good", tmp_path / "bad"
    for folder in (good, bad):
        save_checkpoint(
            folder,
            BCNet(spec, PreprocessConfig(), TINY_MLP),
            BCConfig(PreprocessConfig(), TINY_MLP),
        )
    (bad / "weights.pt").write_bytes(b"\0" * 64)
    grid = [
        SimpleNamespace(
            metrics={"trial_id": t},
            checkpoint=tune.Checkpoint(str(d)),
            filesystem=pafs.LocalFileSystem(),
            path=str(tmp_path / t),
        )
        for t, d in (("g", good), ("b", bad))
    ]
    nets = _checkpoints(grid, ["g", "b"])
    assert set(nets) == {"g"} and isinstance(nets["g"], BCNet)
    printed = capsys.readouterr().out
    assert printed.count("\n") == 1 and "trial b: its checkpoint is damaged" in printed
    assert "trains it again" in printed


def test_a_checkpoint_on_a_full_disk_is_an_os_error_naming_the_file_and_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import io

    import safe_bc.data.atomic as atomic
    from safe_bc.bc import BCConfig, BCNet, ModelSpec, PreprocessConfig, save_checkpoint
    from tests.bc.synth import TINY_MLP

    class Full(io.BufferedWriter):
        def write(self, data):  # what a full disk does to torch's writer
            raise OSError(errno.ENOSPC, "No space left on device")

    real_fdopen = atomic.os.fdopen
    monkeypatch.setattr(
        atomic.os, "fdopen", lambda fd, mode, **kw: Full(real_fdopen(fd, "wb", buffering=0))
    )
    spec = ModelSpec.for_data((4,), 2)
    with pytest.raises(OSError) as e:
        save_checkpoint(tmp_path / "ckpt", BCNet(spec, PreprocessConfig(), TINY_MLP),
                        BCConfig(PreprocessConfig(), TINY_MLP))  # fmt: skip
    assert type(e.value) is OSError and e.value.errno == errno.ENOSPC
    assert e.value.filename == str(tmp_path / "ckpt" / "weights.pt")
    assert list((tmp_path / "ckpt").iterdir()) == []


@pytest.mark.parametrize("recorded", [True, False])
def test_a_trial_resumed_from_an_unrecorded_checkpoint_reports_its_trained_row_again(
    monkeypatch: pytest.MonkeyPatch, recorded: bool
) -> None:
    import safe_bc.study.trial as trial
    from safe_bc.study.spec import ConstraintBars, Float, StudySpec

    class Reached(Exception):
        pass

    # no handover: agents alone need no demonstrations (a handover reads their expert)
    spec = StudySpec("s", {"selection.alpha": Float(0.0, 1.0)}, trials=1, handover=None)
    job = trial.TrialJob(spec, "/none", ConstraintBars(1.0, {}, 0.0), (1.0, 1.0, 1.0))
    train = {"train_loss": 0.5, "train_seconds": 2.0, "n_critical": 3, "critical_fraction": 0.1}
    extra = {"train": train, "trained_s": 4.0}
    reports: list[dict] = []

    def stop(*args, **kwargs):  # the trial's evaluation starts: far enough
        raise Reached

    monkeypatch.setattr(trial, "resume_point", lambda: ([object()], extra, recorded))
    monkeypatch.setattr(trial.tune, "report", lambda metrics, **kw: reports.append(metrics))
    monkeypatch.setattr(trial.NetSource, "from_model", lambda *a: object())
    monkeypatch.setattr(trial, "trial_folder", stop)
    with pytest.raises(Reached):
        trial.run_trial({"selection.alpha": 0.5}, job)
    if recorded:  # Tune has the checkpoint and the driver had the report
        assert reports == []
    else:
        (row,) = reports
        assert row["phase"] == "trained" and row["resumed"] and row["duration_s"] == 4.0
        assert row["train_loss"] == 0.5 and row["n_critical"] == 3


class FullOnce:
    """A Tune callback whose first write fails as on a full disk (``marker``: it has failed);
    Tune pickles it with the experiment, so the resumed run has it too, with space again."""

    def __new__(cls, marker: str):
        from ray import tune

        class _FullOnce(tune.Callback):
            def on_trial_result(self, iteration, trials, trial, result, **info):
                if not Path(marker).exists():
                    Path(marker).touch()
                    raise OSError(errno.ENOSPC, "No space left on device", "/full/history.jsonl")

        return _FullOnce()


@pytest.mark.slow
def test_a_real_study_keeps_its_trials_through_a_damaged_state_and_refuses_other_inputs(
    tiny_demos: Path, tmp_path: Path, capsys
) -> None:
    from dataclasses import replace

    from safe_bc.study.run import FINISHED, run_study
    from safe_bc.study.spec import load_study
    from tests.conftest import tiny_collect
    from tests.distributed.test_study_faults import SMOKE

    spec = replace(
        load_study(SMOKE), demos=tiny_demos, collect=tiny_collect(), storage=str(tmp_path / "ray"),
        results=tmp_path / "results", batches=10, max_steps=40, trials=2, max_concurrent=1,
        screen_episodes=0, final_candidates=1, final_train_seeds=1, final_episodes=1,
        final_workers=0,
    )  # fmt: skip
    out, exp = tmp_path / "results" / spec.name, tmp_path / "ray" / spec.name
    # a full disk in the loop: one line; the rerun resumes once there is space again
    with pytest.raises(OSError) as e:
        run_study(spec, progress=False, callbacks=[FullOnce(str(tmp_path / "full"))])
    assert "\n" not in str(e.value) and str(e.value).count("rerun the same command") == 1
    first = run_study(spec, progress=False, final=False)
    assert first.complete and len(first.trials) == 2
    folders = sorted(p.name for p in exp.glob("trial_*"))
    assert len(folders) == 2

    state = max(exp.glob("experiment_state-*.json"))
    whole = state.read_bytes()
    for damaged in (b"", whole[: len(whole) // 2]):  # what a full disk or a cut copy leaves
        state.write_bytes(damaged)
        with pytest.raises(ResumeRefused, match=r"experiment state is .*--fresh"):
            run_study(spec, progress=False)
        assert sorted(p.name for p in exp.glob("trial_*")) == folders  # nothing deleted
    state.write_bytes(whole)
    tuner = exp / "tuner.pkl"
    pickled = tuner.read_bytes()
    tuner.write_bytes(pickled[: len(pickled) // 2])  # Tune writes it in place at the start
    with pytest.raises(ResumeRefused, match=r"tuner\.pkl: Tune's saved tuner is unreadable"):
        run_study(spec, progress=False)
    tuner.write_bytes(pickled)

    with pytest.raises(ResumeRefused, match=r"other settings \(max_steps 40 -> 60\)"):
        run_study(replace(spec, max_steps=60), progress=False)
    elsewhere = replace(spec, storage=str(tmp_path / "other"))
    with pytest.raises(ResumeRefused, match="keeps its Tune experiment at"):
        run_study(elsewhere, progress=False)
    db = out / "optuna.db"
    copy = db.read_bytes()
    db.write_bytes(copy[:4096])  # a broken Optuna copy is refused on the resuming path too
    with pytest.raises(ValueError, match=r"optuna\.db: "):
        run_study(spec, progress=False)
    db.write_bytes(copy)
    assert not (out / FINISHED).exists()

    done = run_study(spec, progress=False)  # resumes: the trials are not run again
    assert done.complete and set(done.trials["trial_id"]) == set(first.trials["trial_id"])
    assert (out / FINISHED).exists()
    # a finished study never reruns silently: another storage or study file is refused
    with pytest.raises(ResumeRefused, match="keeps its Tune experiment at"):
        run_study(elsewhere, progress=False)
    with pytest.raises(ResumeRefused, match=r"max_steps 40 -> 60"):
        run_study(replace(spec, max_steps=60), progress=False)
    assert not (tmp_path / "other").exists()


def test_other_demonstrations_are_refused_naming_their_digests(tmp_path: Path) -> None:
    from safe_bc.study.run import _check_resume

    identity = {"trials": 2, "threshold": 1.0, "demos_digest": "sha256:aaa", "settings": {}}
    _check_resume(
        tmp_path, identity, restoring=False, exp_path=str(tmp_path)
    )  # a new study records its identity
    assert json.loads((tmp_path / "study.json").read_text()) == identity
    _check_resume(tmp_path, identity, restoring=True, exp_path=str(tmp_path))
    with pytest.raises(ValueError) as e:
        _check_resume(
            tmp_path,
            {**identity, "demos_digest": "sha256:bbb"},
            restoring=True,
            exp_path=str(tmp_path),
        )
    message = str(e.value)
    assert "demos_digest sha256:aaa -> sha256:bbb" in message and "--fresh" in message
    assert "\n" not in message
