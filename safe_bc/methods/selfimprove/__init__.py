"""Safe self-improvement by iterated, filtered self-imitation (expert iteration).

The agent's own rollouts, pushed to explore (an executed-action offset or scale, none where
the state is in the critical zone), are kept only where they stay inside ``d_s`` minus a
margin and beat the unperturbed run on the same track; the agent is retrained on the
demonstrations plus the kept data, for rounds; a round's agent is kept only when its
validation episodes beyond ``d_s`` are bounded (Clopper-Pearson) and its validation reward
is not below the previous agent's.

* :mod:`~safe_bc.methods.selfimprove.config`: the settings and push specs (stdlib only);
* :mod:`~safe_bc.methods.selfimprove.logic`: pushes, what is kept, the keep rule (pure numpy);
* :mod:`~safe_bc.methods.selfimprove.rollout`: one track's unperturbed and pushed runs, validation;
* :mod:`~safe_bc.methods.selfimprove.data`: round files (atomic) and the training data;
* :mod:`~safe_bc.methods.selfimprove.run`: the resumable rounds;
* :mod:`~safe_bc.methods.selfimprove.stage`: the method's runner (``METHODS["selfimprove"]``).
"""
