"""Test set-up: two host CPU devices, so the seed-sharded code path is what the tests run;
and the fault-injection figures printed at the end of the session."""

from collections import Counter

from jaxcart.engine import devices

devices.use_all_host_cores(2)

FAULT_FIGURES: Counter = Counter()
"""Filled by tests/test_faults.py: runs killed, resumes verified, bad inputs tried/rejected."""


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if FAULT_FIGURES:
        terminalreporter.section("fault injection")
        for name, count in sorted(FAULT_FIGURES.items()):
            terminalreporter.write_line(f"{name}: {count}")
