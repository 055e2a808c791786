"""Critical-zone queries (interactive imitation); deferral to the expert at use time is the
handover (:mod:`safe_bc.rollout.handover`), which the query rounds use too.

* :mod:`~safe_bc.methods.queries.config`: the settings (stdlib only, read by study files and the
CLI);
* :mod:`~safe_bc.methods.queries.logic`: which steps are queried or deferred, budgets, the aggregate
  selection (pure numpy);
* :mod:`~safe_bc.methods.queries.rollout`: one episode of the agent with the expert asked in the
zone;
* :mod:`~safe_bc.methods.queries.run`: the resumable rounds (roll out, label, retrain);
* :mod:`~safe_bc.methods.queries.stage`: the method's runner (``METHODS["queries"]``);
* :mod:`~safe_bc.methods.queries.summary`: the summary of the queries family
  (``tune_jobs/compare/queries.py``, run by the comparison runner; written by
  ``python -m scripts.queries_report``, drawn by ``python -m scripts.queries_figure``).
"""
