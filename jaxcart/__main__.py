"""``python -m jaxcart`` is ``python -m jaxcart.train``."""

from jaxcart.train import cli_main

cli_main()
