"""Packaging conventions a user's tools rely on: the XDG cache directory, usage lines that name
the script as it was started, PEP 561's ``py.typed``, and one line when a ``jaxcart/`` folder
in the current directory shadows the package."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from jaxcart import cli
from jaxcart.engine.devices import compilation_cache_dir

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.quick
@pytest.mark.parametrize(
    ("env", "expected"),
    [
        ({}, "{home}/.cache/jaxcart/jax"),
        ({"XDG_CACHE_HOME": "/xdg"}, "/xdg/jaxcart/jax"),
        ({"XDG_CACHE_HOME": "relative"}, "{home}/.cache/jaxcart/jax"),  # the spec says ignore
        ({"XDG_CACHE_HOME": ""}, "{home}/.cache/jaxcart/jax"),
        ({"XDG_CACHE_HOME": "/xdg", "JAXCART_CACHE_DIR": "/mine"}, "/mine"),
    ],
)
def test_compilation_cache_dir_honours_xdg(monkeypatch, tmp_path, env, expected):
    monkeypatch.setenv("HOME", str(tmp_path))
    for name in ("XDG_CACHE_HOME", "JAXCART_CACHE_DIR"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert compilation_cache_dir() == Path(expected.format(home=tmp_path))


@pytest.mark.quick
@pytest.mark.parametrize(
    ("argv0", "module", "expected"),
    [
        ("/venv/bin/jaxcart-train", "jaxcart.train", "jaxcart-train"),
        (
            "C:\\venv\\Scripts\\jaxcart-train.exe".replace("\\", "/"),
            "jaxcart.train",
            "jaxcart-train",
        ),
        ("/venv/bin/jaxcart", "jaxcart.evaluate", "jaxcart evaluate"),
        ("/repo/jaxcart/train.py", "jaxcart.train", "python -m jaxcart.train"),
        ("/venv/bin/pytest", "jaxcart.train", "python -m jaxcart.train"),
        ("/venv/bin/jaxcart-train", "jaxcart.plot", "python -m jaxcart.plot"),
    ],
)
def test_usage_names_the_script_as_started(argv0, module, expected):
    assert cli.prog_name(module, argv0) == expected


def test_installed_script_help_names_itself():
    script = Path(sys.executable).parent / "jaxcart-train"
    if not script.exists():
        pytest.skip("jaxcart-train is not installed beside this interpreter")
    out = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.startswith("usage: jaxcart-train ")


@pytest.mark.quick
def test_py_typed_ships_with_the_package():
    import tomllib

    assert (REPO / "jaxcart" / "py.typed").is_file()
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert "py.typed" in pyproject["tool"]["setuptools"]["package-data"]["jaxcart"]


@pytest.mark.parametrize(
    ("args", "stream"),
    [(["-m", "jaxcart.train", "--help"], "stderr"), (["-c", "import jaxcart.cli"], "stderr")],
)
def test_a_jaxcart_folder_in_the_working_directory_is_one_line(tmp_path, args, stream):
    import jaxcart

    if not Path(jaxcart.__file__).is_relative_to(REPO):
        pytest.skip("an installed (not editable) jaxcart is found after the folder, and wins")
    (tmp_path / "jaxcart").symlink_to(REPO)  # a clone of the repository, seen from its parent
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run(
        [sys.executable, *args], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    last = getattr(out, stream).strip().splitlines()[-1]
    assert f"the folder {tmp_path / 'jaxcart'} shadows the installed jaxcart package" in last
    if args[0] == "-m":  # a command: that one line, exit code 2
        assert out.returncode == 2 and out.stderr.count("\n") == 1 and not out.stdout


@pytest.mark.parametrize("where", ["/proc/jaxcart-cache", "FILE"])
def test_an_unusable_jaxcart_cache_dir_is_one_line_and_exit_2(tmp_path, where, monkeypatch, capsys):
    """The command, run in this process with the variable set (what it reads is the
    environment of the process it runs in)."""
    from jaxcart.train import main

    if where == "FILE":
        where = str(tmp_path / "a-file")
        Path(where).write_text("not a directory")
    out = tmp_path / "run"
    monkeypatch.setenv("JAXCART_CACHE_DIR", where)
    argv = ["--total-timesteps", "256", "--num-envs", "4", "--num-steps", "32"]
    assert main([*argv, "--minibatch-size", "64", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "JAXCART_CACHE_DIR" in lines[0] and "Traceback" not in err
    assert not out.exists()


@pytest.mark.quick
def test_no_tracked_file_holds_a_merge_conflict_marker():
    """A merge left half-resolved would ship its markers: every tracked text file is checked."""
    listed = subprocess.run(
        ["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=False
    ).stdout.split(b"\0")
    if not listed[0]:
        pytest.skip("not a git checkout")
    markers = (b"<<<<<<< ", b">>>>>>> ")
    found = []
    for name in filter(None, listed):
        path = REPO / name.decode()
        if not path.is_file() or path.suffix in {".png", ".gif", ".npz", ".zip", ".onnx"}:
            continue
        for number, line in enumerate(path.read_bytes().splitlines(), 1):
            if line.startswith(markers) or line == b"=======":
                found.append(f"{name.decode()}:{number}")
    assert not found, found
