"""The rehab improvement's defaults are the margin sweep's choice, not a copy that can drift."""

from __future__ import annotations

from safe_bc.improve import ImproveConfig
from scripts.improve_rehab import SHIELD_EPS
from scripts.improve_sweep import CANDIDATES, TESTED


def test_rehab_improvement_defaults_are_the_sweeps_last_choice() -> None:
    """The last tested candidate is the sweep's choice (``TESTED``); ``scripts/improve_rehab``
    runs with its margin (``ImproveConfig.cost_margin``) and its shield zone (``SHIELD_EPS``)."""
    chosen = CANDIDATES[TESTED[-1]]
    assert ImproveConfig().cost_margin == chosen["cost_margin"]
    assert chosen.get("eps") == SHIELD_EPS
    assert chosen["shield"] and chosen["lagrangian"]
    assert (ImproveConfig().shield, ImproveConfig().lagrangian) == (True, True)
