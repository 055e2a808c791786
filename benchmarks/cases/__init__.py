"""The cases of ``python -m benchmarks.bench``, one file each (see ``benchmarks/bench.py``)."""
