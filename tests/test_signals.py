"""Signals: ``import jaxcart`` leaves them alone (and the import system too); every command,
however it is started, turns Ctrl-C or SIGTERM into one line and exit code 130 through
:func:`jaxcart.cli.command_main`; the training's own handling (a checkpoint on the first
signal, a stop at once on the second) is installed only while it trains.

A signal in the interpreter's first second, before a command's ``main()`` runs, meets Python's
own handling (a ``KeyboardInterrupt`` traceback, or CPython's report while it imports
``site``): accepted, provided nothing was printed or written by then. Once ``main()`` runs,
never a traceback. The counts go to the "fault injection" summary.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from conftest import FAULT_FIGURES
from helpers import TRAIN_ENV, fresh_python, tiny_args

from jaxcart import train
from jaxcart.engine import signals
from jaxcart.run import lifecycle

SCRIPTS = Path(sys.executable).parent
"""Where the installed ``jaxcart`` and ``jaxcart-train`` scripts are."""

INTERRUPTED = "error: interrupted; nothing more was written"


def handlers() -> tuple[object, object]:
    return signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)


# ---- import jaxcart ---------------------------------------------------------------------


def test_importing_jaxcart_leaves_signal_handlers_and_the_import_system_as_they_were():
    code = (
        "import signal, sys\n"
        "signal.signal(signal.SIGTERM, lambda signum, frame: None)\n"
        "def state():\n"
        "    sigs = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM))\n"
        "    return sigs, list(sys.meta_path), list(sys.path_hooks)\n"
        "before = state()\n"
        "import jaxcart\n"
        "assert state() == before, (before, state())\n"
        "print('jax' in sys.modules, 'jaxcart.gym.adapter' in sys.modules)\n"
    )
    assert fresh_python(code, TRAIN_ENV, timeout=60) == "False False"


def test_importing_jaxcart_in_another_thread():
    """Only the main thread may set signal handlers; the import sets none, so it works from
    any thread, registration included."""
    code = (
        "import importlib, signal, threading\n"
        "errors = []\n"
        "def load():\n"
        "    try:\n"
        "        importlib.import_module('jaxcart').PPOConfig\n"
        "    except BaseException as e:\n"
        "        errors.append(repr(e))\n"
        "t = threading.Thread(target=load)\n"
        "t.start(); t.join()\n"
        "assert not errors, errors\n"
        "assert signal.getsignal(signal.SIGINT) is signal.default_int_handler\n"
        "import gymnasium\n"
        "print('jaxcart/CartPole-v1' in gymnasium.registry)\n"
    )
    assert fresh_python(code, TRAIN_ENV, timeout=60) == "True"


# ---- every command: one line, exit 130 ----------------------------------------------------

INTERRUPT_WHILE_PARSING = """\
import argparse, os, runpy, signal, sys, time
def parse_known_args(self, *args, **kwargs):  # every command parses its options in main()
    os.kill(os.getpid(), signal.{sig})
    time.sleep(60)
argparse.ArgumentParser.parse_known_args = parse_known_args
sys.argv = {argv!r}
{run}
"""

ENTRIES = [
    ("module", "jaxcart.train", []),
    ("module", "jaxcart.evaluate", ["RUN"]),
    ("module", "jaxcart.plot", ["RUN"]),
    ("module", "jaxcart.compare", ["RUN"]),
    ("module", "jaxcart.env", []),
    ("module", "jaxcart.sb3", []),
    ("module", "jaxcart", ["evaluate", "RUN"]),
    ("module", "jaxcart", ["train"]),
    ("script", "jaxcart", ["plot", "RUN"]),
    ("script", "jaxcart", ["env"]),
    ("script", "jaxcart-train", []),
]


def run_interrupted(kind: str, name: str, argv: list[str], sig: str) -> subprocess.CompletedProcess:
    """``python -m NAME ARGV`` or the installed script NAME, with SIG sent while ``main()``
    parses the options."""
    if kind == "module":
        run = f"runpy.run_module({name!r}, run_name='__main__', alter_sys=True)"
        program = name
    else:
        script = SCRIPTS / name
        if not script.is_file():
            pytest.skip(f"the {name} script is not installed here")
        run, program = f"runpy.run_path({str(script)!r}, run_name='__main__')", str(script)
    code = INTERRUPT_WHILE_PARSING.format(sig=sig, argv=[program, *argv], run=run)
    return subprocess.run(
        [sys.executable, "-c", code], env=TRAIN_ENV, capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize(
    ("kind", "name", "argv"), ENTRIES, ids=[f"{k}-{n}-{'-'.join(a)}" for k, n, a in ENTRIES]
)
def test_every_command_turns_ctrl_c_into_one_line(kind, name, argv):
    done = run_interrupted(kind, name, argv, "SIGINT")
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip() == INTERRUPTED
    FAULT_FIGURES["signals: commands interrupted in main()"] += 1


@pytest.mark.parametrize(
    ("kind", "name", "argv"),
    [("module", "jaxcart.plot", ["RUN"]), ("script", "jaxcart-train", [])],
    ids=["module-plot", "script-jaxcart-train"],
)
def test_sigterm_is_ctrl_c_for_a_command(kind, name, argv):
    done = run_interrupted(kind, name, argv, "SIGTERM")
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip() == INTERRUPTED
    FAULT_FIGURES["signals: commands interrupted in main()"] += 1


AT_EXIT = (
    "import atexit, os, signal, time\n"
    "from jaxcart import cli, plot, train\n"
    "atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(5)))\n"
)


@pytest.mark.parametrize(
    "call", ["cli.command_main(plot.main, ['--help'])", "train.cli_main(['--help'])"]
)
def test_a_signal_after_main_returned_ends_the_process_quietly(call):
    """Once ``main()`` has returned, SIGINT and SIGTERM take their default action: a Ctrl-C
    in an ``atexit`` callback ends the process at once, without a traceback."""
    done = subprocess.run(
        [sys.executable, "-c", AT_EXIT + call],
        env=TRAIN_ENV,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr
    assert done.returncode == -signal.SIGINT and "usage:" in done.stdout
    FAULT_FIGURES["signals: after main() returned, ending the process quietly"] += 1


# ---- signals at real moments ------------------------------------------------------------


def interrupt_at(argv: list[str], delay: float) -> subprocess.CompletedProcess:
    """Starts ``python -m ...argv``, sends SIGINT after ``delay`` seconds, waits."""
    proc = subprocess.Popen(
        [sys.executable, "-m", *argv],
        env=TRAIN_ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)


CLEAN_CODES = (0, 130, -signal.SIGINT)
"""Finished first; stopped (a training, or command_main's line); or ended by the default
action of a signal that came after ``main()`` returned."""

FRAME = re.compile(r'File "([^"]+)", line -?\d+, in (\S+)')


def check_interrupted(result: subprocess.CompletedProcess, out: Path | None = None) -> str:
    """Asserts what a signal at any moment may do, and says where it landed.

    No traceback ever goes through ``command_main`` (nor any thread's). ``"main"``: a clean
    end (:data:`CLEAN_CODES`, no traceback). ``"library"``: Python reported the
    ``KeyboardInterrupt`` as raised in a library's callback and went on, e.g. JAX's garbage
    collection callback (jax-ml/jax#18246), with no frame of jaxcart's. ``"before main"``:
    anything else (Python's own traceback, CPython's report, an import interrupted halfway),
    accepted only if nothing was printed and nothing written (``out`` does not exist)."""
    err = result.stderr
    frames = FRAME.findall(err)
    assert not any(function == "command_main" for _, function in frames), err
    assert "Exception in thread" not in err, err
    ours = any("jaxcart" in Path(path).parts[:-1] for path, _ in frames)
    tracebacks = err.count("Traceback (most recent call last)")
    if result.returncode in CLEAN_CODES and not tracebacks and "Fatal Python error" not in err:
        return "main"
    ignored = err.count("Exception ignored in")
    if result.returncode in (0, 130) and not ours and tracebacks == ignored:
        return "library"
    assert result.stdout == "", (result.returncode, result.stdout, err)
    assert out is None or not out.exists(), f"{out} was written before main() ran"
    return "before main"


def test_only_what_happens_before_main_is_left_to_python():
    def result(code: int, err: str, stdout: str = "") -> subprocess.CompletedProcess:
        return subprocess.CompletedProcess([], code, stdout, err)

    frozen = (
        "Traceback (most recent call last):\n"
        '  File "<frozen runpy>", line 189, in _run_module_as_main\n'
        '  File "/x/jaxcart/__init__.py", line 93, in <module>\n'
        '  File "/x/jaxcart/gym/__init__.py", line 18, in register\n'
        "KeyboardInterrupt\n"
    )
    through_main = frozen.replace(
        "KeyboardInterrupt",
        '  File "/x/jaxcart/cli.py", line 290, in command_main\nKeyboardInterrupt',
    )
    in_jax = (
        "Exception ignored in: <function _xla_gc_callback at 0x7f>\n"
        "Traceback (most recent call last):\n"
        '  File "/v/jax/_src/lib/__init__.py", line 132, in _xla_gc_callback\n'
        "KeyboardInterrupt: \n"
    )
    in_ours = in_jax.replace("/v/jax/_src/lib/__init__.py", "/x/jaxcart/rundir/lock.py")
    assert check_interrupted(result(-signal.SIGINT, frozen)) == "before main"
    assert check_interrupted(result(1, "Fatal Python error: init_import_site: x")) == "before main"
    assert check_interrupted(result(-signal.SIGSEGV, "")) == "before main"  # an import halfway
    assert check_interrupted(result(130, INTERRUPTED + "\n")) == "main"
    assert check_interrupted(result(0, "", "solved 1/1")) == "main"
    assert check_interrupted(result(-signal.SIGINT, "", "usage: ...")) == "main"
    assert check_interrupted(result(0, in_jax, "solved 1/1")) == "library"
    for failing in (
        result(-signal.SIGINT, through_main),
        result(-signal.SIGINT, frozen, "jaxcart PPO | preset sb3"),  # main() had printed
        result(1, "", "jaxcart PPO | preset sb3"),
        result(0, in_ours, "solved 1/1"),
    ):
        with pytest.raises(AssertionError):
            check_interrupted(failing)
    with pytest.raises(AssertionError, match="written before"):
        check_interrupted(result(-signal.SIGINT, frozen), Path(__file__))


TRAIN_ARGV = ["jaxcart.train", *tiny_args(256), "--no-compile-cache", "--quiet"]


LANDED = {
    "before main": "landed before main() (Python's own handling, nothing written)",
    "library": "reported and ignored by Python in JAX's gc callback (jax-ml/jax#18246)",
}


def check_counted(result: subprocess.CompletedProcess, out: Path | None = None) -> None:
    where = check_interrupted(result, out)
    if where != "main":
        FAULT_FIGURES[f"signals: {LANDED[where]}"] += 1
    FAULT_FIGURES["signals: timings"] += 1


@pytest.mark.slow
@pytest.mark.parametrize("delay", [0.05, 0.3, 0.8, 1.5])
def test_ctrl_c_while_train_starts_is_never_a_jaxcart_traceback(delay, tmp_path):
    out = tmp_path / "r"
    check_counted(interrupt_at([*TRAIN_ARGV, "--out", str(out)], delay), out)


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("signals") / "run"
    assert train.main([*TRAIN_ARGV[1:], "--out", str(out)]) == 0
    return out


@pytest.mark.slow
@pytest.mark.parametrize(("module", "delay"), [("plot", 1.0), ("compare", 1.0), ("evaluate", 0.6)])
def test_ctrl_c_in_the_analysis_commands_is_never_a_jaxcart_traceback(module, delay, finished_run):
    """Each signal lands after JAX's import, while the command works (they take 1 to 2 s)."""
    argv = [f"jaxcart.{module}", str(finished_run)]
    outputs = {"plot": "curves.png", "compare": "compare"}  # not into the working directory
    if module in outputs:
        argv += ["--out", str(finished_run.parent / outputs[module])]
    check_counted(interrupt_at(argv, delay))


@pytest.mark.slow
def test_ctrl_c_every_50_ms_over_the_first_1_5_s_of_train(tmp_path):
    for step in range(31):
        out = tmp_path / f"r{step}"
        check_counted(interrupt_at([*TRAIN_ARGV, "--out", str(out)], 0.05 * step), out)


# ---- the training's own handling ------------------------------------------------------------


def test_the_training_handler_is_installed_only_while_training(tmp_path, monkeypatch):
    seen: dict[str, tuple[object, object]] = {}

    def spy(label: str, owner: object, name: str) -> None:
        real = getattr(owner, name)

        def recording(*args, **kwargs):
            seen[label] = handlers()
            return real(*args, **kwargs)

        monkeypatch.setattr(owner, name, recording)

    spy("parsing", train, "build_parser")
    spy("creating the run", lifecycle, "create_run")
    before = handlers()
    assert train.main([*TRAIN_ARGV[1:], "--out", str(tmp_path / "r")]) == 0
    assert handlers() == before  # restored
    assert seen["parsing"] == before
    assert all(isinstance(h.__self__, signals.StopRequest) for h in seen["creating the run"])


def test_a_call_given_up_on_is_abandoned_work(monkeypatch):
    """A second signal leaves XLA's call running on the worker thread: ``command_main`` then
    ends the process without the interpreter's teardown."""
    release = threading.Event()
    previous = signal.signal(signal.SIGUSR1, signal.default_int_handler)
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGUSR1))
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            signals.wait_interruptibly(lambda: release.wait(30))
        assert signals.abandoned_work()
    finally:
        signal.signal(signal.SIGUSR1, previous)
        release.set()
    deadline = time.monotonic() + 10
    while signals.abandoned_work() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not signals.abandoned_work()
