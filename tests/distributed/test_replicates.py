"""``safe-bc tune STUDY --replicates 2`` on a tiny study: two replicate folders with shifted
seeds, the replicate table from their final phases, and a rerun that does no new work."""

from __future__ import annotations

from pathlib import Path

import pytest

from safe_bc.cli.commands import main
from safe_bc.data.store import read_table
from safe_bc.study.replicates import CERT_COLUMNS, ROW_COLUMNS
from safe_bc.study.spec import load_study
from tests.conftest import TINY_COLLECT

REPO = Path(__file__).resolve().parents[2]
SMOKE = REPO / "tune_jobs" / "smoke.py"

pytestmark = pytest.mark.slow  # two studies with their final phases: minutes on 2 cores


def test_replicates_end_to_end_and_rerun_skips_them(tiny_demos: Path, tmp_path: Path,
                                                    capsys) -> None:  # fmt: skip
    study_file = tmp_path / "tiny.py"
    study_file.write_text(
        "from dataclasses import replace\n"
        "from pathlib import Path\n"
        "from safe_bc.study.spec import load_study\n"
        "from safe_bc.rollout.collect import CollectConfig\n"
        f"STUDY = replace(load_study({str(SMOKE)!r}), demos=Path({str(tiny_demos)!r}),\n"
        f"    collect={TINY_COLLECT},\n"
        f"    results=Path({str(tmp_path / 'results')!r}), trials=2, batches=30, max_steps=60,\n"
        "    eval_episodes=1, screen_episodes=0, final_episodes=1, final_candidates=1,\n"
        "    final_train_seeds=1, final_workers=0, startup_trials=2, certify_episodes=1,\n"
        "    certify_seed=30)\n"
    )
    argv = ["tune", str(study_file), "--storage", str(tmp_path / "ray"), "--replicates", "2"]
    assert main(argv) == 0, capsys.readouterr().out
    out = tmp_path / "results" / "smoke"
    spec = load_study(study_file)
    for k in range(2):
        folder = out / "replicates" / f"r{k}"
        trials, _ = read_table(folder / "trials.parquet")
        assert (trials["train_seed"] == 100 * k).all() and (
            trials["eval_seed"] == 1 + 100 * k
        ).all()
        _, meta = read_table(folder / "final.parquet")
        assert meta["seeds"]["final_seed"] == 2 + 100 * k
        assert meta["seeds"]["sampler_seed"] == 100 * k
        assert (tmp_path / "ray" / "smoke_replicates" / f"r{k}").is_dir()
    assert not (out / "trials.parquet").exists()  # the study itself was not run

    table, meta = read_table(out / "replicates.parquet")
    assert list(table.columns) == [*ROW_COLUMNS, *CERT_COLUMNS, *spec.params]
    assert table["replicate"].tolist() == [0, 1] and table["final_seed"].tolist() == [2, 102]
    assert table["certify_seed"].tolist() == [30, 130]  # each replicate certifies on its block
    for k, row in table.iterrows():
        final, fmeta = read_table(out / "replicates" / f"r{k}" / "final.parquet")
        winner = final[final["method"] == fmeta["winner"]].iloc[0]
        assert row["winner"] == fmeta["winner"] and row["reward"] == winner["reward"]
        assert row["crossings"] == winner["episodes_with_violation"]
        assert row["n_episodes"] == winner["n_episodes"] == 1
        _, cmeta = read_table(out / "replicates" / f"r{k}" / "certify.parquet")
        assert row["cert_beyond"] == cmeta["certificate"]["episodes_beyond"]
        assert row["cert_episodes"] == cmeta["certificate"]["episodes"] == 1
    assert meta["summary"]["replicates"] == 2 and meta["summary"]["verdict"]
    assert meta["provenance"]["cpu_model"] and meta["provenance"]["torch_cpu_capability"]
    assert set(meta["sources"]) == {"r0", "r1"}
    assert meta["sources"]["r1"]["provenance"]["torch_cpu_capability"]
    report = (out / "replicates.md").read_text()
    assert meta["summary"]["verdict"] in report and "--replicates 2" in report

    stamps = {p: p.stat().st_mtime_ns for p in (out / "replicates").rglob("*.parquet")}
    capsys.readouterr()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.count("finished before") == 2
    assert {p: p.stat().st_mtime_ns for p in (out / "replicates").rglob("*.parquet")} == stamps
    again, _ = read_table(out / "replicates.parquet")
    assert again.equals(table)
