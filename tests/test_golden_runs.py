"""Run directories stay bit-identical across refactors: the README's training commands (made
small where the README's own run would take minutes) are re-run and fingerprinted against
``tests/data/golden_runs.json``.

The fingerprints hash the files as written (every ``metrics.csv`` column but the wall-clock
``time/*`` ones, every ``params.npz`` array with its dtype and shape, every per-seed entry of
``evaluation.json``), so they read the run directory with nothing but ``csv``, ``json`` and
NumPy: no jaxcart reader stands between the files and the check.

The golden file was written by the code before the layered renovation (commit 5621831) with
``python -m tests.test_golden_runs --write OUTROOT`` after running :data:`COMMANDS` into
``OUTROOT/NAME``. XLA's CPU code generation can differ between CPU models, so on another kind of
machine the fingerprints may legitimately differ: regenerate them from a commit known to be good.
"""

from __future__ import annotations

import csv
import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxcart.train import main as train_main

GOLDEN = Path(__file__).parent / "data" / "golden_runs.json"
WALL_CLOCK = ("time/",)  # metrics.csv columns that measure time, not learning
EVAL_TIMING = ("compile_seconds", "train_seconds", "eval_seconds")

COMMANDS: dict[str, list[str]] = {
    "default": [],
    # the fast preset as it was (50k steps) when the golden file was written
    "fast8": "--preset fast --total-timesteps 50000 --num-seeds 8".split(),
    "sweep": "--num-seeds 4 --total-timesteps 8192 --sweep learning_rate=1e-4,3e-4 "
    "--sweep clip_coef=0.1,0.2".split(),
    "relu": "--learning-rate 1e-3 --no-bootstrap-truncation --activation relu "
    "--total-timesteps 20480 --num-seeds 3".split(),
}
"""``python -m jaxcart.train ARGS --out DIR --quiet`` for each fingerprinted run (2 CPU devices)."""


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


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_run_directory_is_bit_identical_to_the_golden_one(name, tmp_path, capsys):
    golden = json.loads(GOLDEN.read_text())[name]
    out = tmp_path / name
    assert train_main([*COMMANDS[name], "--out", str(out), "--quiet"]) == 0
    capsys.readouterr()
    found = fingerprint(out)
    assert sorted(found) == sorted(golden)
    for part, entries in golden.items():
        differ = sorted(k for k in entries if found[part].get(k) != entries[k])
        assert not differ, f"{name}/{part}: these differ from the golden run: {differ}"
        assert sorted(found[part]) == sorted(entries), f"{name}/{part}: other files or columns"


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


if __name__ == "__main__":  # python -m tests.test_golden_runs --write OUTROOT
    if sys.argv[1:2] != ["--write"] or len(sys.argv) != 3:
        raise SystemExit("usage: python -m tests.test_golden_runs --write OUTROOT")
    root = Path(sys.argv[2])
    GOLDEN.parent.mkdir(exist_ok=True)
    data = {name: fingerprint(root / name) for name in sorted(COMMANDS)}
    GOLDEN.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN}")
