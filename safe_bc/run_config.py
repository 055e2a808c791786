"""What defines a trained safety-imitation agent: selection and behaviour cloning settings (no
torch: study files and the CLI read it without importing the training code)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from safe_bc.bc.config import BCConfig
from safe_bc.selection import SelectionConfig


@dataclass(frozen=True)
class RunConfig:
    """Everything that defines a trained safety-imitation agent."""

    selection: SelectionConfig = field(default_factory=SelectionConfig)
    """eps, alpha and the eq. 5 reading, or a peer baseline (``mode``: ``"bc_safe"`` with its
    ``segment_steps``, ``"cost_weighted"`` with its ``beta``); a study searches them as
    ``selection.mode``, ``selection.segment_steps``, ``selection.beta``."""
    bc: BCConfig = field(default_factory=BCConfig)
    """Preprocessing, network and training (its ``train.seed`` is the training seed)."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-able nested dict."""
        return {"selection": self.selection.to_dict(), "bc": self.bc.to_dict()}
