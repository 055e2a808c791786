"""OSRL's own algorithms beside safe_bc's methods (``make peers``, docs/peers.md).

:mod:`~safe_bc.peers.plan` (what is trained, budgets), :mod:`~safe_bc.peers.data` (the
demonstrations in DSRL's layout), :mod:`~safe_bc.peers.bridge` (an exported actor as a safe_bc
policy), :mod:`~safe_bc.peers.table` (the table) and :mod:`~safe_bc.peers.run` (the steps).
"""
