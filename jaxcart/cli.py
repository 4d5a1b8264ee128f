"""What every ``python -m jaxcart.*`` command shares: one-line errors with exit code 2, and
plain-text tables."""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable

from jaxcart.config import ConfigError
from jaxcart.files import RunDirError

EXIT_USAGE = 2


class UsageError(Exception):
    """A mistake a user made on the command line; printed as one line, exit code 2."""


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors raise :class:`UsageError` (one line, no usage dump)
    instead of exiting, so ``main(argv)`` can be called in-process."""

    def error(self, message: str):
        raise UsageError(f"{message} (see {self.prog} --help)")


def join_negative_values(argv: list[str]) -> list[str]:
    """``["--learning-rate", "-3e-4"]`` -> ``["--learning-rate=-3e-4"]``: argparse reads a
    value like ``-3e-4`` as an unknown option, which would hide the real problem (a negative
    value) behind "expected one argument"."""
    out: list[str] = []
    for token in argv:
        if (
            out
            and out[-1].startswith("--")
            and "=" not in out[-1]
            and re.fullmatch(r"-(\d|\.\d|inf|nan).*", token)
        ):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def format_table(rows: list[list], header: list[str]) -> str:
    """Right-aligned plain-text table."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    lines = ["  ".join(str(h).rjust(w) for h, w in zip(header, widths))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(str(c).rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(lines)


def run_command(body: Callable[[], int], also: tuple[type[Exception], ...] = ()) -> int:
    """Runs a command's body; a user's mistake (bad option, bad config, unusable run
    directory, unwritable path, or one of the exception types in ``also``) becomes
    ``error: ...`` on stderr and exit code 2."""
    try:
        return body()
    except ConfigError as exc:
        message, option = str(exc), exc.option
        if option and message.startswith(option):  # name the setting as the command line does
            message = "--" + option.replace("_", "-") + message[len(option) :]
        print(f"error: {message}", file=sys.stderr)
    except (UsageError, RunDirError, *also) as exc:
        print(f"error: {exc}", file=sys.stderr)
    except OSError as exc:
        where = f": {exc.filename}" if exc.filename else ""
        print(f"error: {exc.strerror or exc}{where}", file=sys.stderr)
    return EXIT_USAGE
