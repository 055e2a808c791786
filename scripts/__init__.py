"""Developer scripts outside the package; run from the repository root as
``python -m scripts.<name>``."""
