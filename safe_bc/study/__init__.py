"""A study: its spec (``spec``: the parameters, constraints, objective and the winner's rule),
its plan (``plan``), the driver (``run``) with its search, trials, final phase, certification,
resume and stop, the console, replicates (``replicates``, ``run_replicates``), the time table
(``timing``) and the recommender it leaves (``recommender``).

The spec's public names are importable from here (``from safe_bc.study import StudySpec``)."""

from safe_bc.moved import forward
from safe_bc.study.spec import Choice, Float, Int, SafetyConstraint, StudySpec, load_study

__all__ = ["Choice", "Float", "Int", "SafetyConstraint", "StudySpec", "load_study"]

__getattr__ = forward(__name__, "safe_bc.study.spec")
