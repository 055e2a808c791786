"""A trial's training is a function of its run config alone: the weights a trial trains inside
Tune (a reused actor, after another trial in the same process, with a CPU reservation that
used to set the torch thread count) are bit-identical to ``train_run`` of the same config in
this process."""

from __future__ import annotations

import json
import random
import sys
from dataclasses import replace
from pathlib import Path

import cloudpickle
import numpy as np
import torch
from ray import tune

from safe_bc.bc import load_checkpoint, read_checkpoint_meta
from safe_bc.data.store import load_demonstrations
from safe_bc.methods.experiment import train_run
from safe_bc.study.spec import ConstraintBars, load_study
from safe_bc.study.trial import TrialJob, run_trial
from tests.conftest import tiny_collect

REPO = Path(__file__).resolve().parents[2]

# The trial wrapper below runs in Ray workers, which cannot import this test module.
cloudpickle.register_pickle_by_value(sys.modules[__name__])

TARGET = {
    "selection.eps": 3.0,
    "selection.alpha": 0.6,
    "selection.rest": "all",
    "bc.network.channels": "8-16-16",
    "bc.network.hidden": 32,
    "bc.train.lr": 1e-3,
    "bc.train.batch_size": 16,
    "bc.preprocess.frame_stack": 2,
}
OTHER = {**TARGET, "bc.network.channels": "4-8-8", "bc.preprocess.frame_stack": 1}


def trial_then_meddle(config: dict, job: TrialJob) -> None:
    """``run_trial``, then leave the process as a careless trial might: another torch thread
    count and other global seeds (the next trial of this reused actor inherits them)."""
    run_trial(config["params"], job)
    torch.set_num_threads(2)
    torch.manual_seed(1234)
    np.random.seed(1234)
    random.seed(1234)


def _state(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def test_trial_in_reused_actor_trains_bit_identical_to_in_process_train_run(
    tiny_demos: Path, tmp_path: Path
) -> None:
    spec = replace(
        load_study(REPO / "tune_jobs" / "smoke.py"),
        demos=tiny_demos,
        collect=tiny_collect(),
        storage=str(tmp_path / "ray"),
        results=tmp_path / "results",
        batches=30,
        max_steps=60,
        eval_episodes=1,
        screen_episodes=0,
        cpus_per_trial=2.0,  # the old code trained with max(1, floor(cpus)) = 2 threads
        max_concurrent=1,
    )
    demos = load_demonstrations(tiny_demos)
    limits = ConstraintBars(demos.safety_mean, demos.dim_safety_means(), 0.0)
    job = TrialJob(spec, str(tiny_demos), limits, tuple(float(x) for x in demos.limits))
    trainable = tune.with_resources(
        tune.with_parameters(trial_then_meddle, job=job),
        tune.PlacementGroupFactory([{"CPU": spec.cpus_per_trial}]),
    )
    tuner = tune.Tuner(
        trainable,
        param_space={"params": tune.grid_search([OTHER, TARGET, TARGET])},
        tune_config=tune.TuneConfig(reuse_actors=True, max_concurrent_trials=1),
        run_config=tune.RunConfig(name="repro", storage_path=str(tmp_path / "ray"), verbose=0),
    )
    grid = tuner.fit()
    assert not grid.errors
    results = list(grid)
    assert len(results) == 3
    assert len({r.metrics["pid"] for r in results}) == 1  # one reused process ran all three

    threads = torch.get_num_threads()
    torch.set_num_threads(2)  # this process's history differs too
    try:
        for r in results:
            with r.checkpoint.as_directory() as d:
                trained = _state(load_checkpoint(d)[0])
                recorded = read_checkpoint_meta(d)["extra"]["run_config"]
            expected = spec.run_config(r.config["params"], num_threads=1)
            # the thread count is explicit and recorded: 1, whatever the reservation
            assert recorded == json.loads(json.dumps(expected.to_dict()))
            here = _state(train_run(demos, expected)[0].model)
            assert trained.keys() == here.keys()
            same = [k for k in here if torch.equal(trained[k], here[k])]
            assert same == list(here), f"trial {r.metrics['trial_id']}: weights differ"
    finally:
        torch.set_num_threads(threads)
