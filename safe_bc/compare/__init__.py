"""A comparison: its spec and tables (``spec``), its rows (``rows``), the runner (``run``),
the protocol, the families of designs, the stored evaluations (``eval_store``), the
hand-over choice and the reproduction of committed tables (``reproduce``)."""

from safe_bc.moved import forward

__getattr__ = forward(__name__, "safe_bc.compare.spec")
