"""The package's surface: the training function keeps its name whatever is imported, Python
can train on every host core as the command line does, ``python -m jaxcart`` lists the
commands, the version and install hints agree with the package and the docs."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import tomllib
import types
from importlib import metadata
from pathlib import Path

import pytest
from helpers import fresh_python

import jaxcart
from jaxcart.engine import devices
from jaxcart.run import loggers

ROOT = Path(__file__).resolve().parents[1]


def _python(code: str, **env: str) -> str:
    """Runs ``code`` in a fresh interpreter (no XLA_FLAGS unless given); its stdout."""
    environ = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    environ.update(PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu", **env)
    return fresh_python(code, environ)


def test_training_function_is_not_shadowed_by_the_cli_module():
    from jaxcart.engine import loop as trainer

    package = importlib.import_module("jaxcart")
    assert package.train_runs is trainer.train
    importlib.import_module("jaxcart.train")  # as `import jaxcart.train` does
    assert isinstance(package.train, types.ModuleType)
    assert package.train_runs is trainer.train and callable(package.train_runs)
    # In a fresh process, in either order: the name never changes meaning.
    out = _python(
        "import jaxcart\n"
        "try:\n    jaxcart.train\nexcept AttributeError as e:\n    print(e)\n"
        "f = jaxcart.train_runs\n"
        "import jaxcart.train\n"
        "print(jaxcart.train_runs is f, type(jaxcart.train).__name__)"
    )
    assert out.splitlines()[0].startswith("jaxcart.train is the command-line module")
    assert "jaxcart.train_runs" in out.splitlines()[0]
    assert out.splitlines()[1] == "True module"


def test_python_trains_on_every_host_core_after_one_call():
    cores = len(os.sched_getaffinity(0))
    code = (
        "import sys\n"
        "import jaxcart\n"
        "jaxcart.use_all_host_cores()\n"
        "print('jax' in sys.modules)\n"
        "import jax\n"
        "print(jax.device_count())"
    )
    assert _python(code).splitlines() == ["False", str(cores)]
    # with JAX already imported (no backend yet), JAX's own option takes the count
    loaded = "import jax, jaxcart\njaxcart.use_all_host_cores()\nprint(jax.device_count())"
    assert _python(loaded) == str(cores)
    # an explicit device count in XLA_FLAGS is the user's choice and stays
    pinned = _python(code, XLA_FLAGS="--xla_force_host_platform_device_count=1")
    assert pinned.splitlines()[1] == "1"
    # without the call, Python gets JAX's default of one CPU device
    assert _python("import jaxcart, jax; print(jax.device_count())") == "1"


def test_use_all_host_cores_too_late_says_so(monkeypatch):
    import jax

    jax.devices()  # JAX has started in this process
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    with pytest.warns(RuntimeWarning, match="too late"):
        devices.use_all_host_cores()
    assert "XLA_FLAGS" not in os.environ


def test_python_m_jaxcart_lists_the_commands(tmp_path, monkeypatch, capsys):
    from jaxcart.__main__ import COMMANDS, main

    monkeypatch.chdir(tmp_path)
    assert main([]) == 0
    out = capsys.readouterr().out
    for command in ("train", "evaluate", "plot", "compare", "env"):
        assert f"python -m jaxcart.{command} " in out and command in COMMANDS
    assert "jaxcart-train" in out
    assert list(tmp_path.iterdir()) == []  # nothing trained, nothing written
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"jaxcart {jaxcart.__version__}\n"
    assert main(["trian"]) == 2
    assert "did you mean train?" in capsys.readouterr().err
    assert main(["env"]) == 0 and "action space" in capsys.readouterr().out
    assert main(["plot", "--version"]) == 0
    assert main(["train", "--num_seeds", "2"]) == 2  # returns, as python -m jaxcart.train's main
    assert "did you mean --num-seeds?" in capsys.readouterr().err


def test_python_m_jaxcart_in_a_process(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "jaxcart"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0 and "python -m jaxcart.train" in done.stdout, done.stderr
    assert list(tmp_path.iterdir()) == []


def test_version_and_scripts_agree_with_pyproject():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert jaxcart.__version__ == project["version"] == metadata.version("jaxcart")
    for name, target in project["scripts"].items():
        module, attr = target.split(":")
        assert callable(getattr(importlib.import_module(module), attr)), name
    # both go through jaxcart.cli.command_main, as python -m jaxcart[.train] does
    assert project["scripts"] == {
        "jaxcart": "jaxcart.__main__:cli_main",
        "jaxcart-train": "jaxcart.train:cli_main",
    }


def test_missing_logger_hint_names_both_install_forms(monkeypatch):
    monkeypatch.setattr(loggers, "_installed", lambda module: False)
    with pytest.raises(loggers.LoggerUnavailable) as exc:
        loggers.check_available(["tensorboard"])
    for form in ("pip install 'jaxcart[tensorboard]'", "pip install -e '.[tensorboard]'"):
        assert form in str(exc.value)
