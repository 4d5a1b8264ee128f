"""Every code block of README.md and docs/*.md runs in the test suite (with Sybil).

- ``python`` blocks run in this process, each document's blocks in one namespace, in order. A
  block that starts with ``>>>`` is a doctest: what it prints must match the output written
  under it (for numbers that hold on every CPU; training's do not).
- ``bash`` blocks run through :func:`run_shell_block`: each block in one ``bash`` process,
  with two CPU devices as the tests' training subprocesses have (tests/helpers.py
  ``TRAIN_ENV``) and a timeout. Only ``python -m jaxcart...`` commands are run, so a block
  that installs, downloads, benchmarks or trains for minutes must be marked skipped in the
  Markdown, with its reason: ``<!-- skip: next "needs Stable-Baselines3" -->``.
- ``text`` blocks (sample output, trees) are not code. A fence with another language, or
  none, fails, so that no block is silently left untested.

Every code block is in the slow tier (``pytest.mark.slow``): ``python -m pytest -q`` leaves
them out, ``python -m pytest -q -m slow`` (in ``.ci/run``) runs them, all of them in document
order, since a block reads what an earlier one, in this document or another, wrote.

Every document's blocks run in one shared temporary directory, as a reader who follows
README.md, the course and the guides in one folder would: ``runs/...`` written by one block is
read by the next, and two pages that reuse a run name collide here (``--out ... is not
empty``) instead of in a reader's folder. It is removed when the tests end.
"""

from __future__ import annotations

import atexit
import importlib.util
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path

import pytest
from sybil import Document, Example, Region, Sybil
from sybil.parsers.markdown import PythonCodeBlockParser, SkipParser
from sybil.parsers.markdown.lexers import RawFencedCodeBlockLexer

import jaxcart

# The compilation cache of the runs that use one (not --no-compile-cache): a new temporary
# directory for the test session, inherited by the processes the tests start, so that the
# tests compile as on a fresh clone and neither read nor fill the user's own cache
# (~/.cache/jaxcart). A test that sets JAXCART_CACHE_DIR itself (tests/test_conventions.py)
# still can.
_SESSION_CACHE = tempfile.mkdtemp(prefix="jaxcart-test-cache-")
os.environ["JAXCART_CACHE_DIR"] = _SESSION_CACHE
atexit.register(shutil.rmtree, _SESSION_CACHE, ignore_errors=True)

# Two CPU devices for the Python blocks too, as tests/conftest.py sets for the tests (the flag
# must be in place before JAX starts; a later call is then a no-op).
jaxcart.use_all_host_cores(2)

REPO = Path(__file__).resolve().parent
SHELL_TIMEOUT_S = 300
"""One bash block's limit: a block that needs longer belongs behind a skip directive."""

RUNNABLE_COMMAND = re.compile(r"^python -m jaxcart(\.\w+)?( |$)")
"""The commands a bash block may hold: jaxcart's own, which leave files in the temp dir only."""

TESTED_LANGUAGES = ("python", "bash")
UNTESTED_LANGUAGES = ("text",)  # sample output and diagrams, not code


def shell_commands(source: str) -> list[str]:
    """The commands of a bash block: comments and blank lines dropped, ``\\`` lines joined."""
    commands, pending = [], ""
    for line in source.splitlines():
        line = pending + line.strip()
        if line.endswith("\\"):
            pending = line[:-1]
            continue
        pending = ""
        words = shlex.split(line, comments=True)
        if words:
            commands.append(shlex.join(words))
    return commands


def shell_env() -> dict[str, str]:
    """The environment of a bash block: this interpreter first on PATH (so ``python`` is the
    one running the tests), this checkout importable, two CPU devices."""
    python_path = os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)
    return {
        **os.environ,
        "PATH": os.pathsep.join((str(Path(sys.executable).parent), os.environ.get("PATH", ""))),
        "PYTHONPATH": python_path,
        "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
    }


def run_shell_block(example: Example) -> None:
    """Runs a bash block's commands in the document's temporary directory; each must succeed."""
    source = example.parsed
    for command in shell_commands(source):
        if not RUNNABLE_COMMAND.match(command):
            raise AssertionError(
                f"refusing to run {command!r}: doc tests run only `python -m jaxcart...` "
                'commands; mark the block with <!-- skip: next "why" --> above it'
            )
    try:
        done = subprocess.run(
            ["bash", "-e", "-o", "pipefail", "-c", source],
            cwd=example.namespace["workdir"],
            env=shell_env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=SHELL_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired as e:
        raise AssertionError(f"bash block still running after {SHELL_TIMEOUT_S} s") from e
    if done.returncode != 0:
        raise AssertionError(f"bash block exited {done.returncode}:\n{done.stdout[-4000:]}")


def refuse_block(example: Example) -> None:
    """The evaluator of a fence in a language the doc tests do not run."""
    language = example.parsed or "(none)"
    raise AssertionError(
        f"code block with language {language}: use ```python or ```bash (both run in the "
        "tests) or ```text (output, diagrams)"
    )


class UntestedFenceParser:
    """Yields every fenced block whose language is neither tested nor declared as text."""

    def __init__(self) -> None:
        self.lexer = RawFencedCodeBlockLexer(
            info_pattern=re.compile(r"(?P<language>[^\n]*)$\n", re.MULTILINE),
            mapping={"language": "language"},
        )

    def __call__(self, document: Document) -> Iterable[Region]:
        for region in self.lexer(document):
            language = region.lexemes["language"].strip()
            if language not in TESTED_LANGUAGES + UNTESTED_LANGUAGES:
                yield Region(region.start, region.end, language, refuse_block)


class BashBlockParser:
    """Yields the ``bash`` fenced blocks, evaluated by :func:`run_shell_block`."""

    def __init__(self) -> None:
        self.lexer = RawFencedCodeBlockLexer(
            info_pattern=re.compile(r"(?P<language>bash)$\n", re.MULTILINE),
            mapping={"source": "source"},
        )

    def __call__(self, document: Document) -> Iterable[Region]:
        for region in self.lexer(document):
            yield Region(region.start, region.end, region.lexemes["source"], run_shell_block)


_shared_workdir: list[str] = []


def shared_workdir() -> str:
    """The one temporary directory every document's blocks run in (made on first use)."""
    if not _shared_workdir:
        path = tempfile.mkdtemp(prefix="jaxcart-docs-")
        atexit.register(shutil.rmtree, path, ignore_errors=True)
        _shared_workdir.append(path)
    return _shared_workdir[0]


def enter_workdir(namespace: dict) -> None:
    """Before a document: the shared working directory for its blocks."""
    namespace["workdir"] = shared_workdir()
    # For `<!-- skip: next if(not GYMNAX, reason="...") -->`: gymnax is an optional extra that
    # the main test venv does not install (.ci/run tests it in a venv of its own).
    namespace["GYMNAX"] = importlib.util.find_spec("gymnax") is not None
    namespace["previous_cwd"] = os.getcwd()
    os.chdir(namespace["workdir"])


def leave_workdir(namespace: dict) -> None:
    """After a document: back to where pytest was (the directory stays for the next one)."""
    os.chdir(namespace["previous_cwd"])


pytest_collect_file = Sybil(
    parsers=[SkipParser(), PythonCodeBlockParser(), BashBlockParser(), UntestedFenceParser()],
    patterns=["README.md", "docs/*.md"],
    excludes=["*/README.md"],  # benchmarks/README.md and others: only the top-level README
    setup=enter_workdir,
    teardown=leave_workdir,
).pytest()


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The documents' code blocks join the slow tier (before ``-m`` selects): see the module's
    docstring."""
    from sybil.integration.pytest import SybilItem

    for item in items:
        if isinstance(item, SybilItem):
            item.add_marker(pytest.mark.slow)
