"""`python -m benchmarks.bench --quick`: table schema, finite positive ratios, metadata.

No timing thresholds: the machine is shared, only the shape of the results is checked.
"""

from __future__ import annotations

import argparse
import math

import pytest

from benchmarks import bench
from benchmarks.cases import env as bench_env
from benchmarks.cases import eval as bench_eval
from safe_bc.data.store import read_table


@pytest.fixture(scope="module")
def quick_table(tmp_path_factory):
    """The quick env + train cases, each in its own subprocess, as ``(frame, metadata)``."""
    out = tmp_path_factory.mktemp("bench") / "bench.parquet"
    rc = bench.main(["--quick", "--cases", "env,train", "--repeats", "2", "--out", str(out)])
    assert rc == 0
    return read_table(out)


def test_quick_table_schema(quick_table):
    frame, _ = quick_table
    assert list(frame.columns) == list(bench.COLUMNS)
    assert set(frame["case"]) == {"env", "train"}
    assert {"stock", "exact renderer"} <= set(frame.loc[frame["case"] == "env", "variant"])
    assert {"bare torch loop", "train_bc pipeline"} <= set(frame["variant"])
    assert (frame["value"] > 0).all()
    assert (frame["repeats"] >= 1).all()


def test_quick_ratios_finite_and_positive(quick_table):
    frame, _ = quick_table
    compared = frame[frame["baseline"] != ""]
    assert len(compared) == len(frame)  # every env/train row has a baseline
    assert all(math.isfinite(r) and r > 0 for r in compared["ratio"])
    baselines = compared[compared["baseline"] == compared["variant"]]
    assert (baselines["ratio"] == 1.0).all()
    for _, row in compared.iterrows():  # each baseline is a row of the same case
        assert row["baseline"] in set(frame.loc[frame["case"] == row["case"], "variant"])


def test_env_step_breakdown_adds_up(quick_table):
    """The profiled step's parts (drawing, scaling, physics, costs, the rest) sum to it."""
    frame, _ = quick_table
    parts = frame[frame["variant"].str.startswith("step part: ")]
    total = frame.loc[frame["variant"] == bench_env.PROFILED, "value"].item()
    assert len(parts) == len(bench_env.STEP_PARTS) + 1
    assert math.isclose(parts["value"].sum(), total, rel_tol=1e-9)
    assert math.isclose(parts["ratio"].sum(), 1.0, rel_tol=1e-9)


def test_quick_memory_and_metadata(quick_table):
    frame, meta = quick_table
    assert (frame["peak_mb"] > 0).all()
    assert meta["provenance"]["git_revision"]
    machine = meta["machine"]
    for key in ("cpu_model", "cpu_count", "python", "torch", "ray", "gymnasium"):
        assert machine[key], key
    assert meta["settings"]["quick"] is True
    assert meta["settings"]["failed_cases"] == []
    assert meta["settings"]["inputs"]["demos"] is None  # env and train read no dataset
    assert set(meta["memory_notes"]) == {c for c in bench.COLUMNS if c.startswith("peak_")}


def test_format_table_is_aligned():
    rows = [
        bench._self_row("train", "bare", [10.0, 12.0], "samples/s"),
        bench._row("train", "pipeline", [5.0, 6.0], "samples/s", ("bare", [10.0, 12.0])),
        bench._row("eval", "share", [20.0], "%"),
    ]
    lines = bench.format_table(rows).splitlines()
    assert len({len(line) for line in lines[:2]}) == 1  # header and rule line up
    assert "0.50x" in lines[3] and "(baseline)" in lines[2]
    assert math.isnan(rows[2]["ratio"])


def test_paired_ratio_is_the_median_of_per_repetition_ratios():
    base, runs = [10.0, 20.0, 30.0], [9.0, 10.0, 33.0]  # ratios 0.9, 0.5, 1.1
    paired = bench._row("train", "p", runs, "samples/s", ("bare", base), paired=True)
    plain = bench._row("train", "p", runs, "samples/s", ("bare", base))
    assert paired["ratio"] == pytest.approx(0.9)
    assert plain["ratio"] == pytest.approx(0.5)  # median 10 / median 20
    with pytest.raises(ValueError, match="equal repetitions"):
        bench._row("train", "p", runs[:2], "samples/s", ("bare", base), paired=True)


def test_parse_cases_rejects_unknown():
    assert bench._parse_cases("env, train") == ["env", "train"]
    with pytest.raises(argparse.ArgumentTypeError):
        bench._parse_cases("env,nope")


@pytest.mark.slow
def test_quick_study_and_final_cases_measure_ratios():
    """The study's trials/min at 1 vs 2 concurrent trials, the final phase's episodes/min and
    the improvement rollout's steps/s on Ray actors vs in-process."""
    rows = bench.run_case("study", bench.QUICK, repeats=1)["rows"]
    rows += bench.run_case("final", bench.QUICK, repeats=1)["rows"]
    rows += bench.run_case("improve", bench.QUICK, repeats=1)["rows"]
    by = {(r["case"], r["variant"]): r for r in rows}
    two = by[("study", "2 concurrent trials")]
    assert two["baseline"] == "1 concurrent trial" and two["unit"] == "trials/min"
    assert math.isfinite(two["ratio"]) and two["ratio"] > 0
    one = by[("final", "1 worker")]
    assert one["unit"] == "episodes/min" and one["value"] > 0
    ray_envs = next(r for (c, v), r in by.items() if c == "improve" and v != "in-process")
    assert ray_envs["baseline"] == "in-process" and ray_envs["unit"] == "steps/s"
    assert math.isfinite(ray_envs["ratio"]) and ray_envs["ratio"] > 0


def test_quick_eval_case_times_the_batched_forward_against_the_exact_one_env_path():
    """The eval case's per-core rows: the raster renderer's lockstep with one batched forward
    against the exact (fast renderer) one-env path, measured in the same run."""
    rows = bench.run_case("eval", bench.QUICK, repeats=1)["rows"]
    by = {r["variant"]: r for r in rows}
    base = by["BC net, exact renderer, 1 env, per core"]
    assert base["unit"] == "episodes/min" and base["value"] > 0
    for envs in (bench_eval.BATCHED_ENVS, bench_eval.WIDE_BATCHED_ENVS):
        row = by[
            f"BC net, raster renderer, {envs} envs in lockstep with one batched forward, per core"
        ]
        assert row["baseline"] == "BC net, exact renderer, 1 env, per core"
        assert math.isfinite(row["ratio"]) and row["ratio"] > 0
    assert by["BC net, raster renderer, 4 envs in lockstep, one batched forward"]["value"] > 0


def test_a_dirty_tree_fails_before_measuring(monkeypatch, capsys):
    """make bench writes under results/: with uncommitted code it stops at once (one line),
    not after minutes of measuring."""
    import safe_bc.data.provenance as provenance

    monkeypatch.setattr(provenance, "_changed_files", lambda: ["safe_bc/some_module.py"])
    monkeypatch.delenv(provenance.ALLOW_DIRTY, raising=False)
    ran: list[str] = []
    monkeypatch.setattr(bench, "_run_all", lambda *a: ran.append("ran") or 0)
    assert bench.main(["--quick", "--out", str(provenance.RESULTS / "bench.parquet")]) == 2
    assert ran == []
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "safe_bc/some_module.py" in err[0] and "commit first" in err[0]


def test_quick_stream_case_compares_memory_and_streamed_frames():
    """The stream case trains in fresh processes on both frame modes: the same weights, and a
    peak RSS, speed and load time for each mode and dataset size."""
    result = bench.run_case("stream", bench.QUICK, repeats=1)
    rows = {r["variant"]: r for r in result["rows"]}
    for episodes in bench.QUICK.stream_episodes:
        for mode in ("memory", "stream"):
            for what in ("peak RSS", "train_bc", "load"):
                assert rows[f"{episodes} episodes, {mode}: {what}"]["value"] > 0
        assert (
            "weights identical across modes: yes"
            in rows[f"{episodes} episodes, memory: peak RSS"]["note"]
        )


def test_quick_cli_case_times_the_help_against_a_bare_interpreter():
    """``safe-bc --help`` and ``safe-bc train --help`` in fresh processes, each paired with
    ``python -c pass`` in the same run: absolute seconds and the ratio (no threshold: the
    machine is shared)."""
    rows = bench.run_case("cli", bench.QUICK, repeats=2)["rows"]
    assert [r["variant"] for r in rows] == [
        "python -c pass",
        "safe-bc --help",
        "safe-bc train --help",
    ]
    assert all(r["unit"] == "s" and r["repeats"] == 2 for r in rows)
    assert all(math.isfinite(r["value"]) and r["value"] > 0 for r in rows)
    assert rows[0]["ratio"] == 1.0
    assert all(r["baseline"] == "python -c pass" and r["ratio"] > 0 for r in rows[1:])
    assert "target: at most 0.5 s" in rows[1]["note"]


def test_a_case_that_makes_its_inputs_names_their_digest() -> None:
    """The self-imitation case reads no dataset: it names the frames it made (their SHA-256,
    the same frames made again give it) and the harness records them beside ``demos``."""
    import hashlib

    from benchmarks.cases import selfimprove

    result = bench.run_case("selfimprove", bench.QUICK, repeats=1)
    made = result["inputs"]
    frames = selfimprove._car_frames(bench.QUICK.selfimprove_kept, 0)
    assert made["kept_frames_sha256"] == hashlib.sha256(frames.tobytes()).hexdigest()
    assert made["kept_frames_shape"] == list(frames.shape) and made["seed"] == 0
    recorded = bench.bench_inputs(["selfimprove"], bench.QUICK, {"selfimprove": made})
    assert recorded["demos"] is None and recorded["made_digests"]["selfimprove"] == made
