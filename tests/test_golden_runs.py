"""Run directories stay bit-identical across refactors: the README's training commands (made
small where the README's own run would take minutes) are re-run and fingerprinted against
``tests/data/golden_runs.json``.

The fingerprints hash the files as written (every ``metrics.csv`` column but the wall-clock
``time/*`` ones, every ``params.npz`` array with its dtype and shape, every per-seed entry of
``evaluation.json``), so they read the run directory with nothing but ``csv``, ``json`` and
NumPy: no jaxcart reader stands between the files and the check.

Why the runs are pinned to AVX: left to itself, XLA:CPU compiles for the host's newest
instruction set (AVX-512 on the Xeon these were recorded on, AVX2 on an AMD EPYC), and oneDNN,
linked into jaxlib, picks its kernels by the host's instruction set at run time (capping it with
``ONEDNN_MAX_CPU_ISA`` changes the bits, so the training uses it: most of its matrix products
are not XLA-generated kernels); other instructions round floats otherwise, so a new user's EPYC
failed all four runs. So each run is a fresh ``python -m jaxcart.train`` process
(:data:`PINNED`) whose environment caps both at AVX, the instruction set jaxlib itself requires
of an x86-64 CPU:
``--xla_cpu_max_isa=AVX`` in ``XLA_FLAGS`` and ``ONEDNN_MAX_CPU_ISA=AVX``. Capping XLA alone is
not enough: with it, oneDNN capped at AVX2 or at SSE4.1 still gave other fingerprints. The outer
environment's ``XLA_*``, ``JAX_*``, ``ONEDNN_*`` and ``DNNL_*`` variables are dropped first, so
the fingerprints do not depend on how the tests were started.

The cap does not make the bits the same on every CPU: an AMD EPYC (AVX2, no AVX-512) gave
other fingerprints than the Xeon under the same cap, from the first training metrics on (and
still with XNNPACK, oneDNN or Eigen's threads off, strict dot math or 128-bit vectors). So the
pinned fingerprints are recorded per CPU, each file naming its host (model name and SIMD
flags, :func:`host_cpu`): ``golden_runs.json`` (the Xeon that runs CI) and
``golden_runs_pinned_*.json``. A host that one names must give its bits; on another host the
run must give the bits of one of them, and where it gives none the test skips, naming the
command that records this CPU's.

The native path (nothing capped: what a user's own run computes) keeps its check:
``tests/data/golden_runs_native.json`` holds the fingerprints written by the code before the
layered renovation (commit 5621831) on the 2-core Xeon (AVX-512, AMX) that runs CI, with that
CPU's model name and SIMD flags; they are checked where the host's are the same, else skipped.

To re-record after a change that is meant to change the numbers (from a commit known to be
good): ``python -m tests.test_golden_runs --write pinned`` on each CPU a pinned file names
(``--write pinned NAME`` writes ``golden_runs_pinned_NAME.json`` for a new one), and
``--write native`` on the machine the native file names (or on a new reference machine, which
it then names).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).parent / "data"
GOLDEN = DATA / "golden_runs.json"
"""The pinned fingerprints of the Xeon that runs CI; ``golden_runs_pinned_*.json``: other CPUs'."""
GOLDEN_NATIVE = DATA / "golden_runs_native.json"
WALL_CLOCK = ("time/",)  # metrics.csv columns that measure time, not learning
EVAL_TIMING = ("compile_seconds", "train_seconds", "eval_seconds")

COMMANDS: dict[str, list[str]] = {
    "default": [],
    # the fast preset as it was when the golden file was written (50k steps, no entropy
    # bonus, no periodic evaluation, a 64-64 network)
    "fast8": "--preset fast --total-timesteps 50000 --ent-coef 0 --eval-every 0 --no-keep-best "
    "--hidden-sizes 64,64 --num-seeds 8".split(),
    "sweep": "--num-seeds 4 --total-timesteps 8192 --sweep learning_rate=1e-4,3e-4 "
    "--sweep clip_coef=0.1,0.2".split(),
    "relu": "--learning-rate 1e-3 --no-bootstrap-truncation --activation relu "
    "--total-timesteps 20480 --num-seeds 3".split(),
}
"""``python -m jaxcart.train ARGS --out DIR --quiet`` for each fingerprinted run (2 CPU devices)."""

TWO_DEVICES = "--xla_force_host_platform_device_count=2"
PINNED = {"XLA_FLAGS": f"{TWO_DEVICES} --xla_cpu_max_isa=AVX", "ONEDNN_MAX_CPU_ISA": "AVX"}
"""The environment of a pinned run: XLA's generated code and oneDNN's kernels at most AVX."""
NATIVE = {"XLA_FLAGS": TWO_DEVICES}
"""The environment of a native run: whatever the host's CPU offers."""
DROPPED = ("XLA_", "JAX_", "ONEDNN_", "DNNL_")
"""Prefixes of the outer environment's variables a golden run does not inherit."""
SIMD_FLAG = re.compile(r"(sse|ssse|avx|fma|f16c|amx|bmi|adx|aes|pclmul|vaes|vpclmul|gfni|sha|xop)")


def _digest(*parts: bytes) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(len(part).to_bytes(8, "little"))
        h.update(part)
    return h.hexdigest()


def fingerprint_run(run_dir: Path) -> dict[str, str]:
    """``{"metrics.csv:COLUMN": sha256, "params.npz:KEY": sha256, "evaluation.json:...": ...}``
    of one (non-sweep) run directory."""
    out: dict[str, str] = {}
    with open(run_dir / "metrics.csv", newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    for i, name in enumerate(header):
        if not name.startswith(WALL_CLOCK):
            out[f"metrics.csv:{name}"] = _digest(*(row[i].encode() for row in body))
    with np.load(run_dir / "params.npz", allow_pickle=False) as params:
        for key in sorted(params.files):
            a = params[key]
            out[f"params.npz:{key}"] = _digest(
                str(a.dtype).encode(), str(a.shape).encode(), a.tobytes()
            )
    evaluation = json.loads((run_dir / "evaluation.json").read_text())
    for key in sorted(evaluation):
        if key not in EVAL_TIMING:
            out[f"evaluation.json:{key}"] = _digest(
                json.dumps(evaluation[key], sort_keys=True).encode()
            )
    return out


def fingerprint(out_dir: Path) -> dict[str, dict[str, str]]:
    """A run directory's fingerprints; a sweep's, one per ``combo-NNN/``."""
    combos = sorted(p for p in out_dir.glob("combo-*") if p.is_dir())
    if combos:
        return {p.name: fingerprint_run(p) for p in combos}
    return {".": fingerprint_run(out_dir)}


def golden_env(pins: dict[str, str]) -> dict[str, str]:
    """The outer environment without :data:`DROPPED` variables, with ``pins`` set."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(DROPPED)}
    return {**env, **pins}


def train_golden(name: str, out: Path, pins: dict[str, str]) -> dict[str, dict[str, str]]:
    """Runs ``COMMANDS[name]`` into ``out`` in a fresh process with ``pins``; its fingerprints."""
    done = subprocess.run(
        [sys.executable, "-m", "jaxcart.train", *COMMANDS[name], "--out", str(out), "--quiet"],
        env=golden_env(pins),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-4000:]
    return fingerprint(out)


def host_cpu() -> dict[str, object] | None:
    """The host CPU's model name and SIMD flags (from /proc/cpuinfo), or None where unknown."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None
    fields = dict(
        (key.strip(), value.strip())
        for key, _, value in (line.partition(":") for line in text.split("\n\n")[0].splitlines())
    )
    if "flags" not in fields:
        return None
    flags = sorted(f for f in fields["flags"].split() if SIMD_FLAG.match(f))
    return {"machine": platform.machine(), "model name": fields.get("model name"), "flags": flags}


def assert_same_as_golden(name: str, found: dict, golden: dict) -> None:
    assert sorted(found) == sorted(golden)
    for part, entries in golden.items():
        differ = sorted(k for k in entries if found[part].get(k) != entries[k])
        assert not differ, f"{name}/{part}: these differ from the golden run: {differ}"
        assert sorted(found[part]) == sorted(entries), f"{name}/{part}: other files or columns"


def pinned_goldens() -> list[dict]:
    """Every CPU's pinned fingerprints: ``{"env", "host", "runs"}``, the CI Xeon's first."""
    paths = [GOLDEN, *sorted(DATA.glob("golden_runs_pinned_*.json"))]
    return [json.loads(path.read_text()) for path in paths]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_run_directory_is_bit_identical_to_the_golden_one(name, tmp_path):
    """On a CPU a pinned file names: the run, capped at AVX, gives that CPU's recorded bits.
    On another x86-64 CPU: the bits of one of them, or a skip that says how to record its own."""
    if platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("the pinned fingerprints are of x86-64 code (AVX)")
    goldens = pinned_goldens()
    for golden in goldens:
        assert golden["env"] == PINNED, "the pin changed: re-record (see the module's docstring)"
    found = train_golden(name, tmp_path / name, PINNED)
    host = host_cpu()
    ours = [golden for golden in goldens if golden["host"] == host]
    if ours:
        assert_same_as_golden(name, found, ours[0]["runs"][name])
    elif all(found != golden["runs"][name] for golden in goldens):
        pytest.skip(
            f"no pinned fingerprints of this CPU ({host and host['model name']}), and its bits "
            "are none of the recorded CPUs': record them with python -m "
            "tests.test_golden_runs --write pinned NAME"
        )


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_native_run_directory_is_bit_identical_on_the_reference_cpu(name, tmp_path):
    """On the CPU the native fingerprints were written on: the run as a user starts it, with
    nothing capped, gives the recorded bits (and other bits than the pinned run: the pin is
    needed there)."""
    native = json.loads(GOLDEN_NATIVE.read_text())
    host = host_cpu()
    if host != native["host"]:
        pytest.skip(f"the native fingerprints are of another CPU ({native['host']['model name']})")
    assert native["env"] == NATIVE
    found = train_golden(name, tmp_path / name, NATIVE)
    assert_same_as_golden(name, found, native["runs"][name])
    assert all(found != golden["runs"][name] for golden in pinned_goldens())


def test_the_fingerprint_sees_a_changed_bit(tmp_path):
    (tmp_path / "metrics.csv").write_text("a,time/elapsed\n1.0,2\n")
    np.savez(tmp_path / "params.npz", w=np.zeros(3, np.float32))
    (tmp_path / "evaluation.json").write_text('{"seeds": [1], "train_seconds": 3}')
    before = fingerprint(tmp_path)
    np.savez(tmp_path / "params.npz", w=np.array([0, 0, np.float32(1e-45)], np.float32))
    assert fingerprint(tmp_path)["."]["params.npz:w"] != before["."]["params.npz:w"]
    (tmp_path / "metrics.csv").write_text("a,time/elapsed\n1.0,9\n")  # wall clock only
    assert fingerprint(tmp_path)["."]["metrics.csv:a"] == before["."]["metrics.csv:a"]
    assert "metrics.csv:time/elapsed" not in before["."]
    assert "evaluation.json:train_seconds" not in before["."]


def test_a_golden_run_inherits_no_xla_jax_or_onednn_setting(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_max_isa=AVX512 --xla_cpu_enable_fast_math=true")
    monkeypatch.setenv("JAX_ENABLE_X64", "1")
    monkeypatch.setenv("DNNL_MAX_CPU_ISA", "AVX512_CORE")
    monkeypatch.setenv("ONEDNN_VERBOSE", "1")
    monkeypatch.setenv("KEEP_ME", "1")
    env = golden_env(PINNED)
    assert {k: env[k] for k in env if k.startswith(DROPPED)} == PINNED
    assert env["KEEP_ME"] == "1"


def test_the_host_cpu_is_read_from_proc_cpuinfo():
    host = host_cpu()
    if host is None:
        pytest.skip("no /proc/cpuinfo here")
    assert host["flags"] == sorted(host["flags"]) and all(SIMD_FLAG.match(f) for f in host["flags"])
    if host["machine"] == "x86_64":
        assert "sse2" in host["flags"]


if __name__ == "__main__":  # python -m tests.test_golden_runs --write pinned [NAME]|native
    usage = "usage: python -m tests.test_golden_runs --write pinned [NAME] | --write native"
    if sys.argv[1:2] != ["--write"] or sys.argv[2:3] not in (["pinned"], ["native"]):
        raise SystemExit(usage)
    native = sys.argv[2] == "native"
    pins, path = (NATIVE, GOLDEN_NATIVE) if native else (PINNED, GOLDEN)
    if not native:  # the file of this CPU: the one naming it, else a new one named NAME
        named = [
            p
            for p in [GOLDEN, *DATA.glob("golden_runs_pinned_*.json")]
            if json.loads(p.read_text()).get("host") == host_cpu()
        ]
        if named:
            path = named[0]
        elif sys.argv[3:]:
            path = DATA / f"golden_runs_pinned_{sys.argv[3]}.json"
        else:
            raise SystemExit(f"no pinned file names this CPU: give it a NAME. {usage}")
    root = Path(tempfile.mkdtemp(prefix="jaxcart-golden-"))
    runs = {name: train_golden(name, root / name, pins) for name in sorted(COMMANDS)}
    data = {"env": pins, "runs": runs, "host": host_cpu()}
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    print(f"wrote {path}")
