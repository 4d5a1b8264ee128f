#!/usr/bin/env bash
# Creates the three virtualenvs the benchmarks run in (from the repository root or anywhere):
#
#   benchmarks/.venv-bench  jaxcart + gymnax 1.x, EnvPool, Gymnasium, Stable-Baselines3 (PyTorch,
#                           CPU build), rl-zoo3, matplotlib: runs benchmarks.env.throughput and
#                           benchmarks.train_speed, and rl-zoo3 for benchmarks.tune.
#   benchmarks/.venv-rejax  jaxcart + rejax 0.1.3, which needs gymnax 0.0.x (gymnax 1.x changed
#                           step() to return terminated and truncated separately):
#                           benchmarks.train_speed starts its rejax contenders with it.
#   benchmarks/.venv-sbx    jaxcart + sbx (sbx-rl, Stable-Baselines3's JAX port, with the same
#                           torch CPU pin because it installs Stable-Baselines3 too):
#                           benchmarks.train_speed starts its sbx contenders with it.
#
# PyTorch's CPU build is installed first, as PyTorch's instructions say
# (pip install torch --index-url https://download.pytorch.org/whl/cpu), so that
# Stable-Baselines3's "torch" requirement is already met: left to itself pip would fetch the
# newest CUDA build (several GB). Override with TORCH_SPEC and TORCH_PIP_ARGS (e.g.
# TORCH_SPEC="torch==2.13.0" TORCH_PIP_ARGS="" on a machine that has that CPU wheel at hand).
#
# The package lists mirror the "bench", "rejax" and "sbx" extras of pyproject.toml; when those
# extras exist they are used.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
TORCH_SPEC=${TORCH_SPEC:-torch}
TORCH_PIP_ARGS=${TORCH_PIP_ARGS---index-url https://download.pytorch.org/whl/cpu}

BENCH_PKGS=(
  "gymnax>=1.0.1,<2"
  "envpool>=1.2; sys_platform == 'linux'"
  "gymnasium>=1.0"
  "stable-baselines3>=2.3"
  "rl_zoo3[plots]>=2.6"
  "matplotlib>=3.8"
)
SBX_PKGS=(
  "sbx-rl>=0.20"
)
REJAX_PKGS=(
  "rejax==0.1.3"
  "gymnax==0.0.9"
)

has_extra() { grep -Eq "^[[:space:]]*$1[[:space:]]*=" pyproject.toml; }

make_venv() {
  local dir=$1
  if [ ! -x "$dir/bin/python" ]; then
    "$PYTHON" -m venv "$dir"
  fi
  "$dir/bin/python" -m pip install --quiet --upgrade pip
}

echo "== benchmarks/.venv-bench"
make_venv benchmarks/.venv-bench
benchmarks/.venv-bench/bin/pip install "$TORCH_SPEC" $TORCH_PIP_ARGS
if has_extra bench; then
  benchmarks/.venv-bench/bin/pip install -e '.[bench]'
else
  benchmarks/.venv-bench/bin/pip install -e . "${BENCH_PKGS[@]}"
fi

echo "== benchmarks/.venv-rejax"
make_venv benchmarks/.venv-rejax
if has_extra rejax; then
  benchmarks/.venv-rejax/bin/pip install -e '.[rejax]'
else
  benchmarks/.venv-rejax/bin/pip install -e . "${REJAX_PKGS[@]}"
fi

echo "== benchmarks/.venv-sbx"
make_venv benchmarks/.venv-sbx
benchmarks/.venv-sbx/bin/pip install "$TORCH_SPEC" $TORCH_PIP_ARGS
if has_extra sbx; then
  benchmarks/.venv-sbx/bin/pip install -e '.[sbx]'
else
  benchmarks/.venv-sbx/bin/pip install -e . "${SBX_PKGS[@]}"
fi

echo
echo "Done. Run, from the repository root:"
echo "  benchmarks/.venv-bench/bin/python -m benchmarks.env.throughput"
echo "  benchmarks/.venv-bench/bin/python -m benchmarks.train_speed"
echo "  benchmarks/.venv-bench/bin/python -m benchmarks.train_speed --time-to-solve --seeds 1"
