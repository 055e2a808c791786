"""Every committed stored evaluation names the demonstrations it was made from."""

from __future__ import annotations

from safe_bc.data.store import read_table_metadata
from scripts.input_sets import REHAB_LIMITS
from scripts.stored_inputs import inputs_for, stored_evaluations


def test_every_stored_evaluation_names_a_digest() -> None:
    files = stored_evaluations()
    assert len(files) >= 200
    for path in files:
        demos = read_table_metadata(path)["inputs"]["demos"]
        assert demos and all(str(d["digest"]).startswith("sha256:") for d in demos), path


def test_a_set_is_identified_by_its_limits_or_not_at_all() -> None:
    assert inputs_for(REHAB_LIMITS)["demos"][0]["digest"].startswith("sha256:")
    assert inputs_for((41.58, 49.29, 42.06))["demos"][0]["digest"].startswith("sha256:741ea082")
    assert inputs_for((1.0, 2.0, 3.0)) == {}
