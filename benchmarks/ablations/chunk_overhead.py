"""Does reporting progress between chunks slow training? Train time of the same run compiled as
one chunk (no host round trips) and with the CLI's default chunking (about 20 reports).

    python -m benchmarks.ablations.chunk_overhead --preset sb3 --seeds 1 --repeats 5

Prints the median training time (compile excluded) of each and their ratio.
"""

from __future__ import annotations

import statistics

from benchmarks import lib
from jaxcart.core.config import preset
from jaxcart.engine.loop import default_chunk_size, train


def main() -> None:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--preset", default="sb3")
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    config = preset(args.preset)
    sizes = {
        "one chunk": config.num_iterations,
        "default chunks": default_chunk_size(config.num_iterations),
    }
    times: dict[str, list[float]] = {k: [] for k in sizes}
    for _ in range(args.repeats):  # interleaved, so drift affects both alike
        for name, size in sizes.items():
            times[name].append(train(config, args.seeds, 0, chunk_size=size).run_seconds)
    medians = {k: statistics.median(v) for k, v in times.items()}
    for name, size in sizes.items():
        print(
            f"{name:15s} chunk_size={size:3d}: median train {medians[name]:.3f} s over {args.repeats} runs"
        )
    print(f"default chunking / one chunk = {medians['default chunks'] / medians['one chunk']:.3f}")


if __name__ == "__main__":
    main()
