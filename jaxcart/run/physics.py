"""Moved to :mod:`jaxcart.core.physics`, CartPole's one physics module; this name is kept
for the modules that still import it from here."""

from jaxcart.core.physics import *  # noqa: F403
