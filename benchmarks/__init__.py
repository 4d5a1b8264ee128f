"""jaxcart's benchmarks, a package so that every script runs as ``python -m benchmarks.GROUP.NAME``
from the repository root (it is not installed: run from there). See ``benchmarks/README.md``."""
