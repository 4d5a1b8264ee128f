"""Test set-up: two host CPU devices, so the seed-sharded code path is what the tests run;
warnings as errors for the tests that ask (``no_warnings``); and the fault-injection figures
printed at the end of the session."""

import os
import warnings
from collections import Counter

import pytest

from jaxcart.engine import devices

devices.use_all_host_cores(2)

FAST_TIER_XLA_FLAG = "--xla_backend_optimization_level=0"
"""LLVM's optimisation of the compiled programs, off for the fast tier (``-m 'not slow'``, the
README's command): its tests check behaviour (files, errors, values compared between two paths
compiled alike) on tiny programs whose time is mostly compile, and that optimisation was a
fifth of the tier's CPU. The slow tier keeps XLA's default, so its golden runs check the programs users get."""


def pytest_configure(config):
    markexpr = config.option.markexpr or ""
    flags = os.environ.get("XLA_FLAGS", "")
    if "not slow" in markexpr and "xla_backend_optimization_level" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {FAST_TIER_XLA_FLAG}".strip()


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
