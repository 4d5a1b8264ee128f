"""Moved to :mod:`jaxcart.cli`, the one home of what every command shares: the checks of the
environment variables JAX reads (:func:`~jaxcart.cli.import_jax`,
:func:`~jaxcart.cli.check_backend`); this name is kept for the commands that import it."""

from jaxcart.cli import check_backend, import_jax, xla_flags_problem  # noqa: F401
