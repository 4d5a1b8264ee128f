"""``python -m jaxcart`` is ``python -m jaxcart.train``."""

from jaxcart import devices

devices.use_all_host_cores()

from jaxcart.train import main  # noqa: E402

raise SystemExit(main())
