"""Test set-up: two host CPU devices, so the seed-sharded code path is what the tests run."""

from jaxcart import devices

devices.use_all_host_cores(2)
