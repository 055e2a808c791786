"""The ways in: the ``safe-bc`` command (``commands``, its help in ``help``), its jobs
(``jobs``) and the Python API (``api``)."""

from safe_bc.moved import forward

__getattr__ = forward(__name__, "safe_bc.cli.commands")
