"""Name the demonstrations every committed stored evaluation was made from: an evaluation
stored before digests were recorded gets ``inputs`` (the set's content digest, identified by
the d_s its stamp records) in its metadata; its rows, stamp and file name are unchanged.

    python -m scripts.stored_inputs
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from scripts.input_sets import (
    REHAB_CARD,
    REHAB_LIMITS,
    ROOT,
    described_set,
    rehab_card,
    rounded_limits,
)

KEY = b"safe_bc"


def rehab_set(root: Path = ROOT) -> dict[str, Any]:
    """The rehab task's default set: the digest its committed recommender card records."""
    where = f"its d_s, as the rehab recommender's card ({REHAB_CARD})"
    return {"digest": rehab_card(root)["demos"]["digest"], "identified_by": where}


def inputs_for(thresholds: Any, root: Path = ROOT) -> dict[str, Any]:
    """The ``inputs`` record of an evaluation whose stamp records ``thresholds`` (``{}``: no
    known set has those d_s)."""
    limits = rounded_limits(thresholds)
    found = rehab_set(root) if limits == REHAB_LIMITS else described_set(limits, root)
    return {"demos": [found]} if found else {}


def stored_evaluations(root: Path = ROOT) -> list[Path]:
    """Every committed stored evaluation (not its steps)."""
    return sorted(
        p for p in (root / "results").rglob("stored_evaluations/*.parquet")
        if not p.name.endswith(".steps.parquet")
    )  # fmt: skip


def main() -> None:
    added = 0
    for path in stored_evaluations():
        table = pq.read_table(path)
        meta = json.loads((table.schema.metadata or {})[KEY])
        if "inputs" in meta:
            continue
        inputs = inputs_for(meta["stamp"]["thresholds"])
        if not inputs:
            raise SystemExit(
                f"{path}: no known demonstration set has d_s {meta['stamp']['thresholds']}"
            )
        meta["inputs"] = inputs
        schema_meta = {**(table.schema.metadata or {}), KEY: json.dumps(meta).encode()}
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        os.close(fd)
        pq.write_table(table.replace_schema_metadata(schema_meta), tmp)
        os.replace(tmp, path)
        added += 1
    print(f"named the demonstrations of {added} stored evaluations")


if __name__ == "__main__":
    main()
