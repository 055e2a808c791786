"""The comparison runner: spec validation, the table builder, Table 1 re-derived from its
committed episodes, and a tiny comparison with an improvement row end to end."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.bc import BCConfig
from safe_bc.compare.families import load_comparison
from safe_bc.compare.spec import (
    Comparison,
    Method,
    Plot,
    Report,
    ReportFiles,
    build_table,
    check_report_files,
    render_markdown,
)
from safe_bc.data.store import read_table
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig

ROOT = Path(__file__).resolve().parents[1]
BC = Method("bc", selection=SelectionConfig(alpha=0.0))
EXPERT = Method("expert", expert=True)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: Method("x"), "exactly one of"),
        (lambda: Method("x", selection=SelectionConfig(), expert=True), "exactly one of"),
        (lambda: Method("x", improve=ImproveConfig()), "start="),
        (lambda: Method("x", expert=True, bc=BCConfig()), "bc= is for BC rows"),
        (lambda: Comparison("t", methods=()), "no methods"),
        (lambda: Comparison("t/x", methods=(BC,)), "file stem"),
        (lambda: Comparison("t", methods=(BC, BC)), "repeat"),
        (lambda: Comparison("t", methods=(BC,), train_seeds=()), "train_seeds"),
        (lambda: Comparison("t", methods=(BC,), train_seeds=(1, 1)), "train_seeds"),
        (lambda: Comparison("t", methods=(BC,), episodes=0), "episodes"),
        (lambda: Comparison("t", methods=(BC,), eps=float("nan")), "eps"),
        (lambda: Comparison("t", methods=(BC,), reference="plain"), "reference"),
        (lambda: Comparison("t", methods=(BC,), traces=("expert",)), "traces"),
        (lambda: Comparison("t", methods=(BC,), figures=(("pie", "p.png"),)), "figure"),
        (lambda: Comparison("t", methods=(BC,), task="atari"), "task"),
        (lambda: Report("safe_bc.methods.selfimprove.choice", "c.md"), "module:function"),
        (lambda: Report("a b:f", "c.md"), "module:function"),
        (lambda: Report("m:f", "sub/c.md"), "file name"),
        (lambda: Report("m:f", reads=("steps",)), "report reads"),
        (lambda: Report("m:f", reads=("episodes", "episodes")), "report reads"),
        (lambda: Plot("plots.plot", {}), "plot must be 'module:function'"),
        (lambda: Comparison("t", methods=(BC,), report=Report("m:f", "t.parquet")), "the table's"),
        (
            lambda: Comparison("t", methods=(BC,), report=Report("m:f", "t_episodes.parquet")),
            "the table's",
        ),
        (
            lambda: Comparison(
                "t", methods=(EXPERT, Method("i", improve=ImproveConfig(), start="expert"))
            ),
            "not a BC row",
        ),
    ],
)
def test_spec_validation_one_line(make, match) -> None:
    with pytest.raises(ValueError, match=match) as err:
        make()
    assert "\n" not in str(err.value)


def methods_report(table: pd.DataFrame, meta: dict, source: Path, command: str) -> str:
    """A report step for the tiny comparison: its table's rows, the table, the command."""
    return f"{', '.join(table['method'])} from {source.name} ({meta['git_revision']}); {command}\n"


def test_a_report_step_is_no_part_of_the_recorded_config() -> None:
    step = Report("tests.test_compare:methods_report", "rows.txt")
    assert Comparison("t", methods=(BC,), report=step).to_dict() == (
        Comparison("t", methods=(BC,)).to_dict()
    )


def test_a_report_step_names_its_files_but_none_of_the_tables() -> None:
    """A step's files may replace the table's Markdown, never its tables or figures, and are
    plain file names named once."""
    comp = Comparison("t", methods=(BC,), figures=(("traces", "t_traces.png"),))
    check_report_files(comp, ReportFiles(tables={"summary": pd.DataFrame()}, texts={"t.md": ""}))
    for files, match in (
        (ReportFiles(tables={"t": pd.DataFrame()}), "'t.parquet' is comparison 't''s"),
        (ReportFiles(tables={"t_training": pd.DataFrame()}), "'t_training.parquet' is"),
        (ReportFiles(figures={"t_traces.png": Plot("m:f")}), "'t_traces.png' is"),
        (ReportFiles(texts={"t_runs": ""}), "'t_runs' is"),
        (ReportFiles(texts={"../x.md": ""}), "no file name"),
        (ReportFiles(tables={"s": pd.DataFrame()}, texts={"s.parquet": ""}), "named twice"),
    ):
        with pytest.raises(ValueError, match=match):
            check_report_files(replace(comp, report=Report("m:f")), files)


def test_a_step_returns_what_its_kind_writes(tmp_path: Path) -> None:
    """A step with a file returns its text; one without returns its files (else a TypeError)."""
    from safe_bc.compare.run import run_report
    from safe_bc.data.store import write_table_atomic

    table = pd.DataFrame({"method": ["bc"]})
    write_table_atomic(tmp_path / "t.parquet", table, {"git_revision": "abc"})
    text = Report("tests.test_compare:methods_report", "rows.txt")
    comp = Comparison("t", methods=(BC,), out=tmp_path, report=text)
    assert run_report(comp, "cmd") == [tmp_path / "rows.txt"]
    assert (tmp_path / "rows.txt").read_text() == "bc from t.parquet (abc); cmd\n"
    with pytest.raises(TypeError, match="returned a str, not a ReportFiles"):
        run_report(replace(comp, report=Report(text.step)), "cmd")
    assert run_report(replace(comp, report=None)) == []


def test_load_comparison_files(tmp_path: Path) -> None:
    table1 = load_comparison(ROOT / "tune_jobs/compare/table1.py")
    assert table1.name == "table1" and table1.reference == "alpha=0 (rest=all)"
    assert table1.methods[-1].kind == "expert" and len(table1.train_seeds) == 11
    improve = load_comparison(ROOT / "tune_jobs/compare/improve.py", "improve_carracing")
    assert [m.kind for m in improve.methods] == ["expert", "bc"] + ["improve"] * 4
    with pytest.raises(ValueError, match=r"name one comparison \(--name\): improve_carracing, "):
        load_comparison(ROOT / "tune_jobs/compare/improve.py")
    bad = tmp_path / "bad.py"
    bad.write_text("COMPARISONS = 3\n")
    with pytest.raises(ValueError, match="defines no COMPARISONS"):
        load_comparison(bad)
    bad.write_text("COMPARISONS = {'a': 3}\n")
    with pytest.raises(ValueError, match="'a' is a int, not a Comparison"):
        load_comparison(bad)
    with pytest.raises(FileNotFoundError):
        load_comparison(tmp_path / "none.py")


def _episodes() -> pd.DataFrame:
    """3 seeds x 4 shared tracks with a large track effect; ``better`` beats ``bc`` by 5 on
    every seed, ``worse`` loses 5; the expert ran once."""
    rng = np.random.default_rng(1)
    track = rng.normal(0, 200, 4)
    rows = []
    for name, mode, gain in (
        ("bc", "mix", 0.0),
        ("better", "mix", 5.0),
        ("worse", "improve", -5.0),
    ):
        for s in range(3):
            for t in range(4):
                rows.append({"method": name, "mode": mode, "train_seed": s, "env_seed": t,
                             "reward": 300 + track[t] + gain})  # fmt: skip
    rows += [{"method": "expert", "mode": "expert", "train_seed": 0, "env_seed": t,
              "reward": 900 + track[t]} for t in range(4)]  # fmt: skip
    df = pd.DataFrame(rows).assign(alpha=np.nan, rest="")
    df["policy"] = df["method"] + " seed=" + df["train_seed"].astype(str)
    df["safety_mean"], df["safety_std"], df["safety_min"] = 6.0, 1.0, 3.0
    df["offroad_steps"], df["critical_share"] = 0.0, 0.1
    df["violation_steps"] = np.where(df["method"] == "worse", 2.0, 0.0)
    df["any_violation"] = (df["violation_steps"] > 0).astype(float)
    return df


def test_table_builder_on_synthetic_episodes() -> None:
    methods = (
        EXPERT,
        Method("worse", improve=ImproveConfig(), start="bc"),
        BC,
        Method("better", selection=SelectionConfig(alpha=0.5)),
    )
    comp = Comparison("t", methods=methods, train_seeds=(0, 1, 2), reference="bc")
    table = build_table(comp, _episodes()).set_index("method")
    assert table.index.tolist() == ["expert", "worse", "bc", "better"]  # the spec's order
    assert table.loc["better", "d_reward"] == pytest.approx(5.0)  # the track effect cancels
    assert table.loc["better", "d_reward_hi"] - table.loc["better", "d_reward_lo"] < 1e-9
    assert table.loc["bc", "reward_hi"] - table.loc["bc", "reward_lo"] > 50  # unpaired: wide
    assert table.loc["better", "seeds_better"] == 3 and table.loc["worse", "seeds_better"] == 0
    assert pd.isna(table.loc["expert", "d_reward"])  # trained once: never paired
    assert table.loc["worse", "d_violation_steps"] == pytest.approx(2.0)
    assert table.loc["worse", "episodes_with_violation"] == 12
    assert table.loc["expert", ["n_train_seeds", "n_tracks"]].tolist() == [1, 4]
    md = render_markdown(comp, table.reset_index(), {"git_revision": "r", "command": "c"})
    assert md.count("\n|") == 5 and "3/3 seeds better" in md and "reward - bc" in md
    no_ref = build_table(replace(comp, reference=None), _episodes())
    assert "d_reward" not in no_ref and "seeds better" not in render_markdown(
        replace(comp, reference=None), no_ref, {"git_revision": "r", "command": "c"}
    )


def test_committed_table1_rederives_exactly_from_its_episodes() -> None:
    """results/table1.parquet from the committed episodes and training table, through the
    Table 1 comparison file's spec: the same values, exactly."""
    comp = load_comparison(ROOT / "tune_jobs/compare/table1.py")
    episodes, meta = read_table(ROOT / "results/table1_episodes.parquet")
    training, _ = read_table(ROOT / "results/table1_training.parquet")
    committed, _ = read_table(ROOT / "results/table1.parquet")
    assert [m["name"] for m in meta["config"]["methods"]] == [m.name for m in comp.methods]
    pd.testing.assert_frame_equal(
        build_table(comp, episodes, training), committed, check_exact=True
    )


def stored_evaluations(out: Path) -> dict[str, str]:
    """The stored evaluations' episode files under a comparison's ``out`` (named by what made
    them, not by row): file name -> the policy it holds."""
    from safe_bc.compare.eval_store import FOLDER

    found = {}
    for path in sorted((out / FOLDER).glob("*.parquet")):
        if not path.name.endswith(".steps.parquet"):
            (found[path.name],) = set(read_table(path)[0]["policy"])
    return found


TINY = ImproveConfig(
    iterations=2,
    episodes_per_iter=2,
    n_envs=2,
    update_epochs=1,
    minibatch_size=32,
    anchor_batch=16,
    critic_hidden=16,
    critic_warmup=1,
    eval_every=2,
    eval_episodes=2,
    checkpoint_every=1,
)


def test_tiny_comparison_with_an_improvement_row_resumes(rehab_demos, tmp_path: Path) -> None:
    """BC start, its improvement and the expert on rehab, 2 seeds x 3 patients; a rerun
    trains, improves and evaluates nothing and gives the same table; the CLI verb runs it."""
    from safe_bc.cli.commands import main

    file = tmp_path / "tiny.py"
    file.write_text(
        f"""from pathlib import Path
from safe_bc.bc import BCConfig, NetworkConfig, TrainConfig
from safe_bc.compare.spec import Comparison, Method, Report
from safe_bc.rollout.collect import CollectConfig
from safe_bc.selection import SelectionConfig
from safe_bc.tasks import task_defaults
from tests.test_compare import TINY

TINY_COMPARISON = Comparison(
    "tiny",
    methods=(
        Method("expert", expert=True),
        Method("start", selection=SelectionConfig(eps=0.05, alpha=0.5)),
        Method("improved", improve=TINY, start="start"),
    ),
    task="rehab",
    demos=Path({str(rehab_demos)!r}),
    collect=CollectConfig.for_task(task_defaults("rehab"), episodes=8, workers=1),
    out=Path({str(tmp_path)!r}),
    train_seeds=(0, 1),
    episodes=3,
    workers=1,
    bc=BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=5, batch_size=8)),
    reference="start",
    traces=("start",),
    report=Report("tests.test_compare:methods_report", "tiny_rows.txt"),
)
COMPARISONS = (TINY_COMPARISON,)
"""
    )
    comp = load_comparison(file)
    assert main(["compare", str(file), "--quiet"]) == 0
    table, meta = read_table(tmp_path / "tiny.parquet")
    assert table["method"].tolist() == ["expert", "start", "improved"]
    assert table.set_index("method").loc["improved", "n_train_seeds"] == 2
    assert table["d_reward"].notna().tolist() == [False, False, True]
    episodes, _ = read_table(tmp_path / "tiny_episodes.parquet")
    assert len(episodes) == 3 + 2 * 3 * 2
    assert set(episodes["mode"]) == {"expert", "mix", "improve"}
    history, _ = read_table(tmp_path / "tiny_history.parquet")
    assert sorted(set(history["train_seed"])) == [0, 1]
    traces, _ = read_table(tmp_path / "tiny_traces.parquet")
    assert set(traces["policy"]) == {"start seed=0"}
    md = (tmp_path / "tiny.md").read_text()
    assert "seeds better than start" in md and meta["git_revision"] in md
    rows = (tmp_path / "tiny_rows.txt").read_text()  # the report step, after the table
    assert rows.startswith(f"expert, start, improved from tiny.parquet ({meta['git_revision']}); ")
    assert rows.endswith(f"; {meta['command']}\n")

    from safe_bc.compare.run import run_comparison

    weights = tmp_path / "tiny_runs" / "start" / "seed1" / "agent" / "config.json"

    def stored() -> dict[str, int]:  # the stored evaluations, by what made them
        return {p.name: p.stat().st_mtime_ns for p in (tmp_path / "stored_evaluations").iterdir()}

    before = weights.stat().st_mtime_ns, stored()
    assert len(before[1]) == 5 + 1  # 5 cells' episodes, the traced row's steps
    assert {f"stored_evaluations/{n}" for n in before[1] if "steps" not in n} <= set(
        meta["inputs"]["runs"]
    )
    curve, _ = read_table(weights.parent / "curve.parquet")  # every agent's learning curve
    assert curve["batch"].tolist() == [5] and curve["train_loss"].notna().all()
    again = run_comparison(comp, progress=False)
    assert (weights.stat().st_mtime_ns, stored()) == before
    pd.testing.assert_frame_equal(again, table, check_exact=True)
    # another comparison sharing the runs folder with the same settings shares every
    # evaluation (nothing evaluated); one with other settings gets its own, overwriting none
    same = run_comparison(replace(comp, name="same", runs="tiny"), progress=False)
    assert stored() == before[1]
    pd.testing.assert_frame_equal(same, table, check_exact=True)
    # a changed setting redoes only what it changes: more tracks re-evaluate every cell
    more = run_comparison(replace(comp, name="more", runs="tiny", episodes=4), progress=False)
    assert weights.stat().st_mtime_ns == before[0] and (more["n_tracks"] == 4).all()
    after = stored()
    assert len(after) == 2 * len(before[1]) and {n: after[n] for n in before[1]} == before[1]
    pd.testing.assert_frame_equal(run_comparison(comp, progress=False), table, check_exact=True)
    assert stored() == after


def test_agents_trained_on_other_demonstrations_are_trained_again(
    rehab_demos, tmp_path: Path, monkeypatch
) -> None:
    """A stored agent is reused only when the set at its demonstrations' path has the content
    digest it was trained on: the same path holding other content trains it again."""
    import safe_bc.compare.run as runner
    from safe_bc.bc import NetworkConfig, TrainConfig, read_checkpoint_meta
    from safe_bc.data.store import data_digest
    from safe_bc.rollout.collect import CollectConfig
    from safe_bc.tasks import task_defaults

    comp = Comparison(
        "digest",
        methods=(Method("bc", selection=SelectionConfig(eps=0.05, alpha=0.5)),),
        task="rehab",
        demos=rehab_demos,
        collect=CollectConfig.for_task(task_defaults("rehab"), episodes=8, workers=1),
        out=tmp_path,
        train_seeds=(0,),
        episodes=2,
        workers=1,
        bc=BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=5, batch_size=8)),
    )
    table = runner.run_comparison(comp, progress=False)
    config = tmp_path / "digest_runs" / "bc" / "seed0" / "agent" / "config.json"
    assert read_checkpoint_meta(config.parent)["extra"]["demos_digest"] == data_digest(rehab_demos)
    before = config.stat().st_mtime_ns
    runner.run_comparison(comp, progress=False)
    assert config.stat().st_mtime_ns == before  # same set: reused
    read = runner.read_demonstrations

    def other_content(path):  # the same path holding another set's content
        demos, record = read(path)
        return demos, {**record, "digest": "sha256:" + "0" * 64}

    monkeypatch.setattr(runner, "read_demonstrations", other_content)
    again = runner.run_comparison(comp, progress=False)
    assert config.stat().st_mtime_ns != before  # other content at the same path: trained again
    speed = ["samples_per_s"]  # the retraining's wall-clock; everything else is the same
    pd.testing.assert_frame_equal(again.drop(columns=speed), table.drop(columns=speed))


def test_with_deferral_replaces_the_deferral_rows_and_keeps_the_others_in_order() -> None:
    base = Comparison(
        "c",
        methods=(
            Method("expert", expert=True),
            Method("start", selection=SelectionConfig()),
            Method("start+d1", fallback_of="start", defer_width=1.0),
            Method("late", selection=SelectionConfig(alpha=0.5)),
        ),
    )
    grid = base.with_deferral(
        (Method(f"start+d{w}", fallback_of="start", defer_width=w) for w in (2.0, 3.0)),
        name="grid",
        episodes=7,
    )
    assert [m.name for m in grid.methods] == ["expert", "start", "late", "start+d2.0", "start+d3.0"]
    assert (grid.name, grid.episodes) == ("grid", 7) and base.name == "c"
    assert [m.name for m in base.with_deferral(()).methods] == ["expert", "start", "late"]


@pytest.mark.parametrize("args", [[], ["--name", "nope"]])
def test_cli_lists_a_familys_names_when_the_name_is_missing_or_wrong(
    args: list[str], capsys: pytest.CaptureFixture
) -> None:
    from safe_bc.cli.commands import main

    family = ROOT / "tune_jobs/compare/margin_sweep.py"
    code = main(["compare", str(family), *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err, err
    assert err.endswith("(--name): sweep_screen_seed0, sweep_selection, sweep_test")
