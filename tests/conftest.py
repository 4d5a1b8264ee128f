"""Test set-up: two host CPU devices, so the seed-sharded code path is what the tests run;
warnings as errors for the tests that ask (``no_warnings``); and the fault-injection figures
printed at the end of the session."""

import warnings
from collections import Counter

import pytest

from jaxcart.engine import devices

devices.use_all_host_cores(2)

FAULT_FIGURES: Counter = Counter()
"""Filled by tests/test_faults.py: runs killed, resumes verified, bad inputs tried/rejected."""


@pytest.fixture
def no_warnings():
    """Every warning an error while the test runs (set up after the wider-scoped fixtures, so
    their training is not held to it): matplotlib's, say, when a figure's layout collapses."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if FAULT_FIGURES:
        terminalreporter.section("fault injection")
        for name, count in sorted(FAULT_FIGURES.items()):
            terminalreporter.write_line(f"{name}: {count}")
