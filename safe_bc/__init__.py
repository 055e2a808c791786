"""safe_bc: safety-focused behaviour cloning."""

__version__ = "0.1.0"
