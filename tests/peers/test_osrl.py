"""OSRL's own code on a safe_bc task's demonstrations, through ``make peers``'s steps: runs
only where the peers' environment exists (``make peers-env``: ``.venv-peers``), else skips.
A few updates per peer (seconds): that each trains on the DSRL dict and exports an actor that
safe_bc acts with, not how well."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from safe_bc.peers.bridge import ScriptedSource, read_actor
from safe_bc.peers.run import prepare

ROOT = Path(__file__).resolve().parents[2]
PEERS_PY = ROOT / ".venv-peers" / "bin" / "python"

pytestmark = pytest.mark.skipif(
    not PEERS_PY.exists(), reason="no peers environment (make peers-env)"
)


def test_osrl_trains_every_peer_and_safe_bc_acts_with_its_actors(rehab_demos, tmp_path) -> None:
    runs = tmp_path / "runs"
    line = prepare(rehab_demos, runs, seeds=(0,), scale=0.0005)
    assert "transitions of 8 episodes" in line
    done = _train(runs)
    assert done.stdout.count(" updates in ") == 4
    trained = json.loads((runs / "train.json").read_text())
    assert sorted(trained) == ["BC-All_seed0", "BC-Safe_seed0", "COptiDICE_seed0", "CPQ_seed0"]
    obs = np.load(runs / "dsrl.npz")["observations"][0]
    for key, record in trained.items():
        path = runs / "actors" / f"{key}.pt"
        _, meta = read_actor(path)
        assert meta["osrl_lib"] == "0.1.0" and meta["updates"] == record["updates"] >= 1
        action = ScriptedSource.from_file(path).build().act(obs, None)
        assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    assert trained["BC-Safe_seed0"]["episodes"] <= trained["BC-All_seed0"]["episodes"] == 8
    assert _train(runs).stdout.count(" updates in ") == 0  # the same plan: every actor kept
    prepare(rehab_demos, runs, seeds=(0,), scale=0.0005, cost_limit=2)  # another budget: again
    assert _train(runs).stdout.count(" updates in ") == 4


def _train(runs: Path) -> subprocess.CompletedProcess:
    done = subprocess.run(
        [str(PEERS_PY), str(ROOT / "peers" / "osrl_train.py"), "--runs", str(runs)],
        capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    return done
