"""Every committed stored evaluation names the demonstrations it was made from."""

from __future__ import annotations

from pathlib import Path

from safe_bc.data.store import read_table_metadata

ROOT = Path(__file__).resolve().parents[1]


def test_every_stored_evaluation_names_a_digest() -> None:
    files = sorted(
        p for p in (ROOT / "results").rglob("stored_evaluations/*.parquet")
        if not p.name.endswith(".steps.parquet")
    )  # fmt: skip
    assert len(files) >= 200
    for path in files:
        demos = read_table_metadata(path)["inputs"]["demos"]
        assert demos and all(str(d["digest"]).startswith("sha256:") for d in demos), path
