"""Ray plumbing only: start-up, actor pools for collection, evaluation, training and rollouts,
and rollout envs on actors. The study (``safe_bc/study/``) and the comparison runner
(``safe_bc/compare/``) run their work through it."""
