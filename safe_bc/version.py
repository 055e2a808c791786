"""The package's version (``safe_bc.__version__``), recorded in every result's provenance.

Its own module so that :mod:`safe_bc.data.provenance` reads it without importing the package's
``__init__`` (which registers the env ids and so imports the tasks)."""

__version__ = "0.1.0"
