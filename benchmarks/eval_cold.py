"""Cold ``CrossCheck.evaluate`` of a finished run directory, in a fresh process: the final
evaluation's wall seconds (Gymnasium's episodes and the JAX cross-check, compile included),
then the two means::

    python -m jaxcart.train --preset fast --num-seeds 64 --out /tmp/fast64
    for i in 1 2 3; do python benchmarks/eval_cold.py /tmp/fast64; done

With ``--ahead``, the cross-check's program is compiled first and not timed, as training
compiles it beside its chunks (``run.greedy.CrossCheck``): the seconds are then what the
evaluation at the end of a training takes. With ``--gymnasium``, only the Gymnasium episodes
are timed (:func:`~jaxcart.run.greedy.evaluate_params`): what ``python -m jaxcart.evaluate RUN``
runs, in NumPy with no program to compile, so a fresh process is as cold as it gets. With
``--stages``, the cold cross-check is split into building it, lowering, XLA's compile and the
run (``--stages '{"xla_backend_optimization_level": 0}'`` compiles with other XLA options).
"""

import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

from jaxcart.run.greedy import FAST_COMPILE, CrossCheck, evaluate_params
from jaxcart.rundir.policy import run_params
from jaxcart.rundir.reader import read_run_config

run = Path(sys.argv[1])
rp = run_params(run)
seed = read_run_config(run)["seed"]  # through the store's reader, as evaluate reads it
ahead = "--ahead" in sys.argv[2:]
if "--stages" in sys.argv[2:]:
    after = sys.argv[sys.argv.index("--stages") + 1 :]  # XLA options, when a JSON object follows
    options = json.loads(after[0]) if after and not after[0].startswith("--") else {}
    t = [time.perf_counter()]
    check = CrossCheck(rp.config, seed, np.arange(rp.num_seeds), 20, rp.env_params)
    t.append(time.perf_counter())
    program = jax.jit(jax.vmap(check._one_run))
    shapes = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), rp.params)
    lowered = program.lower(shapes, check._keys, check._per_run)
    t.append(time.perf_counter())
    compiled = lowered.compile(options or FAST_COMPILE)
    t.append(time.perf_counter())
    returns = np.asarray(compiled(rp.params, check._keys, check._per_run))
    t.append(time.perf_counter())
    build, lower, xla, run_s = np.diff(t)
    print(f"build {build:.3f} lower {lower:.3f} compile {xla:.3f} run {run_s:.3f} {returns.mean()}")
    sys.exit(0)
if "--gymnasium" in sys.argv[2:]:
    t = time.perf_counter()
    g = evaluate_params(rp, 20)
    print(f"{time.perf_counter() - t:.3f} {g.mean():.6f}")
    sys.exit(0)
if ahead:
    check = CrossCheck(rp.config, seed, np.arange(rp.num_seeds), 20, rp.env_params)
    check.compile_for(rp.params).result()  # compiled, as it is by the end of a training
t = time.perf_counter()
if not ahead:  # cold: the cross-check is made, compiled and run within the timing
    check = CrossCheck(rp.config, seed, np.arange(rp.num_seeds), 20, rp.env_params)
g, j = check.evaluate(rp.params)
print(f"{time.perf_counter() - t:.3f} {g.mean():.6f} {np.asarray(j).mean():.6f}")
