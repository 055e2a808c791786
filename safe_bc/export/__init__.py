"""Demonstration sets in other tools' forms: Minari datasets (``minari_export.py``) with the
limits they carry for offline safe-RL tools (``limits.py``)."""
