"""A run directory never runs code: the network class and metric functions a ``config.json``
names are data to every reader, and code only when the user passes it or says
``--trust-code`` (docs/reliability.md, "The run directory as a trust boundary").

Each payload is crafted into a finished (or interrupted) tiny run, with its manifest
rewritten to match (an attacker who recomputes digests) or deleted with its key; then every
command and ``load_policy`` reads it. A payload that ran leaves a trace: a file written,
truncated or deleted, or a module imported. None may.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from custom_networks import ReluMLP
from helpers import TINY, seal, stopped_run

from jaxcart import compare, evaluate, export, plot, train
from jaxcart.core.config import ConfigError, RebuildError, RecordedCode
from jaxcart.run import lifecycle
from jaxcart.run.spec import RunOptions, RunSpec
from jaxcart.rundir import files, layout, policy

SMALL = dataclasses.replace(TINY, total_timesteps=256, anneal_lr=False)  # 2 iterations
OPTIONS = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=1)
PRECIOUS = "a file outside the run directory\n"
EVIL_MODULE = """
import pathlib
pathlib.Path({marker!r}).write_text("imported")


class Net:
    pass


def metric(rollout, batch, losses):
    return 0.0
"""


@pytest.fixture(scope="module")
def bases(tmp_path_factory) -> dict[str, Path]:
    """A finished and an interrupted run of the built-in network, trained once."""
    root = tmp_path_factory.mktemp("code-bases")
    lifecycle.run_new(RunSpec(SMALL, num_seeds=1), root / "finished", OPTIONS)
    longer = RunSpec(dataclasses.replace(SMALL, total_timesteps=512), num_seeds=1)
    stopped_run(longer, root / "interrupted", OPTIONS, chunks=1)[0].close()
    return {"finished": root / "finished", "interrupted": root / "interrupted"}


def payloads(outside: Path) -> dict[str, dict]:
    """``config.json`` entries naming code that leaves a trace under ``outside`` if run."""
    return {
        "os-system": {
            "network": {"class": "os:system", "fields": {"command": f"touch {outside}/ran"}}
        },
        "popen": {
            "network": {
                "class": "subprocess:Popen",
                "fields": {"args": f"touch {outside}/ran", "shell": True},
            }
        },
        "open-truncates": {
            "network": {"class": "builtins:open", "fields": {"file": f"{outside}/precious"}},
        },
        "rmtree": {"network": {"class": "shutil:rmtree", "fields": {"path": f"{outside}/keep"}}},
        "module-in-cwd": {"network": {"class": "evilcwd:Net", "fields": {}}},
        "module-in-run": {"network": {"class": "evilrun:Net", "fields": {}}},
        "metric-in-cwd": {"metrics": {"custom/m": "evilcwd:metric"}},
    }


def craft(run: Path, entry: dict, sealed: bool) -> None:
    """Writes ``entry`` into the run's config (its digest recomputed); ``sealed`` rewrites
    the manifest to match, else deletes it and its key."""
    path = run / layout.CONFIG_FILE
    data = json.loads(path.read_text())
    data["config"].update(entry)
    if not sealed:
        data.pop(files.MANIFEST_FLAG, None)
    data.pop(layout.DIGEST_KEY)
    data[layout.DIGEST_KEY] = files.json_digest(data)
    path.write_text(json.dumps(data))
    if sealed:
        seal(run)
    else:
        (run / layout.MANIFEST_FILE).unlink()


def traces(outside: Path, cwd: Path, run: Path) -> list[str]:
    """What a payload that ran would have left."""
    found = [str(p) for p in (outside / "ran", cwd / "imported", run / "imported") if p.exists()]
    if (outside / "precious").read_text() != PRECIOUS:
        found.append("precious truncated")
    if not (outside / "keep").is_dir():
        found.append("keep deleted")
    found += [m for m in ("evilcwd", "evilrun") if m in sys.modules]
    return found


@pytest.fixture
def place(tmp_path, monkeypatch):
    """A place to craft runs in: ``outside`` (what payloads would touch) and a current folder
    holding a malicious module, first on ``sys.path`` as ``python -m`` puts it."""
    outside, cwd = tmp_path / "outside", tmp_path / "cwd"
    (outside / "keep").mkdir(parents=True)
    (outside / "precious").write_text(PRECIOUS)
    cwd.mkdir()
    (cwd / "evilcwd.py").write_text(EVIL_MODULE.format(marker=str(cwd / "imported")))
    monkeypatch.chdir(cwd)
    monkeypatch.syspath_prepend(str(cwd))
    yield outside, cwd
    for name in ("evilcwd", "evilrun"):
        sys.modules.pop(name, None)


def copy_run(bases: dict[str, Path], base: str, to: Path) -> Path:
    shutil.copytree(bases[base], to)
    (to / "evilrun.py").write_text(EVIL_MODULE.format(marker=str(to / "imported")))
    return to


@pytest.mark.slow
@pytest.mark.parametrize("sealed", [True, False], ids=["manifest-rewritten", "no-manifest"])
def test_no_command_runs_the_code_a_run_directory_names(
    sealed, bases, place, tmp_path, monkeypatch, capsys
):
    """Every payload, through every command and ``load_policy``; one figure for all of them
    (plot and compare read several runs at once)."""
    outside, cwd = place
    finished, interrupted = [], []
    for name, entry in payloads(outside).items():
        run = copy_run(bases, "finished", tmp_path / name)
        part = copy_run(bases, "interrupted", tmp_path / f"{name}-part")
        for directory in (run, part):
            craft(directory, entry, sealed)
            monkeypatch.syspath_prepend(str(directory))  # `cd RUN && python -m ...`
        finished.append(run)
        interrupted.append((part, "network" in entry))

    # readers of metrics and evaluations need no code: they work, and import nothing
    every = [str(r) for r in finished]
    assert plot.main([*every, "--out", str(tmp_path / "curves.png")]) == 0
    assert compare.main([*every, "--out", str(tmp_path / "compare.png")]) == 0
    parts = [str(p) for p, network in interrupted if network]  # a metric's stream: see below
    assert plot.main([*parts, "--out", str(tmp_path / "parts.png")]) == 0
    capsys.readouterr()
    # what runs the policy or trains refuses in one line, naming both ways in
    for run, (part, network) in zip(finished, interrupted):
        commands = [
            (evaluate.main, [str(run), "--episodes", "1"]),
            (train.main, ["--resume", str(part), "--quiet"]),
        ]
        if network:  # export takes the built-in MLP only, whatever the network names
            zipped = str(tmp_path / "a.zip")
            commands.append((export.main, [str(run), "--to", "sb3", "--out", zipped]))
            with pytest.raises(ConfigError, match="trust_code=True"):
                policy.load_policy(run)
        else:  # a metric added to an interrupted run's config no longer fits its stream
            commands.append((plot.main, [str(part), "--out", str(tmp_path / "p.png")]))
        for main, argv in commands:
            assert main(argv) == 2, (run.name, main.__module__)
            err = capsys.readouterr().err
            assert "Traceback" not in err, err
            (err,) = [line for line in err.splitlines() if not line.startswith("note:")]
            if main in (evaluate.main, train.main) and network:
                assert "--trust-code" in err and "network=" in err, err
    assert traces(outside, cwd, finished[0]) == []
    assert not any((r / "imported").exists() for r in finished)
    assert not (tmp_path / "a.zip").exists()


@pytest.mark.parametrize("payload", ["os-system", "popen", "open-truncates", "rmtree"])
def test_trusting_code_builds_only_a_flax_module(payload, bases, place, tmp_path):
    """With ``trust_code`` the recorded name is imported, but what is not a flax module
    subclass is refused before it is called."""
    outside, cwd = place
    run = copy_run(bases, "finished", tmp_path / "run")
    craft(run, payloads(outside)[payload], sealed=True)
    with pytest.raises(ConfigError, match=r"is not a flax\.linen\.Module subclass"):
        policy.load_policy(run, trust_code=True)
    assert evaluate.main([str(run), "--episodes", "1", "--trust-code"]) == 2
    assert traces(outside, cwd, run) == []


@pytest.mark.parametrize("path", ["os.system", "subprocess.getoutput"])
def test_trusted_code_is_only_a_recorded_module_colon_name(path):
    """Even trusted, a recorded name is ``module:Name``: a dotted name without the colon is
    not walked down module by module to whatever it reaches (``os.system``)."""
    with pytest.raises(RebuildError, match="ModuleNotFoundError"):
        RecordedCode(path).build()


@pytest.mark.slow
def test_a_custom_network_plots_and_compares_where_its_module_is_missing(tmp_path):
    """Trained with a network of tests/custom_networks.py, read by a process that cannot
    import it: plot and compare work; evaluate says in one line what to pass."""
    config = dataclasses.replace(SMALL, network=ReluMLP(width=8))
    lifecycle.run_new(RunSpec(config, num_seeds=1), tmp_path / "relu", OPTIONS)
    shutil.copytree(tmp_path / "relu", tmp_path / "relu2")
    code = (
        "import sys\n"
        "from jaxcart import compare, evaluate, plot\n"
        f"run = {str(tmp_path / 'relu')!r}\n"
        "assert plot.main([run]) == 0\n"
        f"assert compare.main([run, run + '2', '--out', {str(tmp_path / 'c.png')!r}]) == 0\n"
        "assert evaluate.main([run, '--episodes', '1']) == 2\n"
        "assert 'custom_networks' not in sys.modules\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    (line,) = [x for x in done.stderr.splitlines() if x.startswith("error:")]
    assert "custom_networks:ReluMLP" in line and "--trust-code" in line
    assert (tmp_path / "relu" / "curves.png").is_file()
    # passing the class needs no import of the recorded name
    loaded = policy.load_policy(tmp_path / "relu", network=ReluMLP)
    assert loaded.env_id == "CartPole-v1"


def test_config_of_a_run_directory_is_read_without_following_a_link(bases, tmp_path, capsys):
    """``train --config RUN_DIR`` reads its config.json as every reader does: a link out of
    the run, or a FIFO, is refused in one line (never planned from, never waited on)."""
    import os

    run = copy_run(bases, "finished", tmp_path / "run")
    outside = tmp_path / "elsewhere.json"
    outside.write_text((run / layout.CONFIG_FILE).read_text())
    (run / layout.CONFIG_FILE).unlink()
    (run / layout.CONFIG_FILE).symlink_to(outside)
    argv = ["--config", str(run), "--dry-run", "--out", str(tmp_path / "new")]
    assert train.main(argv) == 2
    assert "symbolic link" in capsys.readouterr().err
    (run / layout.CONFIG_FILE).unlink()
    os.mkfifo(run / layout.CONFIG_FILE)
    assert train.main(argv) == 2
    assert "not a regular file" in capsys.readouterr().err
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    assert train.main(["--config", str(fifo), "--dry-run"]) == 2
    assert "not a regular file" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
