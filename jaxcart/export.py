"""``python -m jaxcart.export RUN --to sb3|onnx [--out FILE]``: one seed's trained policy as a
Stable-Baselines3 ``PPO`` zip (``stable_baselines3.PPO.load`` opens it: rl-zoo3,
``huggingface_sb3`` and ``evaluate_policy`` take it from there) or as an ONNX model
(``onnxruntime`` runs it), by default into the run directory (``RUN/policy-seed0.zip``:
:func:`jaxcart.rundir.layout.export_file`). Neither needs PyTorch; ONNX needs the ``onnx``
package (``pip install -e '.[export]'``)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from jaxcart import cli
from jaxcart.rundir import layout

FORMATS = {"sb3": ".zip", "onnx": ".onnx"}
"""Each export format and the suffix its file takes."""


@dataclasses.dataclass(frozen=True)
class ExportOptions:
    """Everything the command line said: nothing past :func:`main` sees argparse. Each
    :func:`~jaxcart.cli.option` field is the option ``--name``, its docstring the help."""

    run_dir: Path
    to: str = cli.option(required=True, choices=list(FORMATS))
    """the format"""
    out: Path | None = cli.option(type=Path)
    """the file to write (.zip for sb3, .onnx for onnx; default: in RUN_DIR, policy-seed0.zip
    for seed 0, policy-best-seed0.zip for --policy best, policy-combo003-seed0.zip for
    --combination 3)"""
    seed_index: int = cli.option(0, type=int)
    """which seed of the run"""
    combination: int | None = cli.option(type=int, metavar="C")
    """a sweep's combination"""
    policy: str = cli.option("final", choices=list(layout.POLICY_FILES))
    """final: the parameters at the end of training (the last checkpoint's for a run that did
    not finish); best: the best evaluated policy, where the run kept one"""


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m jaxcart.export`` command line."""
    parser = cli.Parser(
        prog="python -m jaxcart.export",
        description="Export one seed's trained policy: --to sb3 writes a zip that "
        "stable_baselines3.PPO.load opens (no PyTorch needed to write it); --to onnx writes an "
        "ONNX model (input obs [N, 4] float32, outputs logits [N, 2] and action [N] int64) "
        "built with the onnx package.",
    )
    parser.add_argument(
        "run_dir", type=Path, metavar="RUN_DIR", help="a jaxcart run (or sweep) directory"
    )
    cli.add_options(parser, ExportOptions, "")
    return parser


def export(opts: ExportOptions) -> str:
    """Writes the export ``opts`` asks for; returns what to print."""
    import sys

    from jaxcart.core import networks
    from jaxcart.rundir.files import atomic_write_bytes
    from jaxcart.rundir.policy import has_physics, run_params, seed_params
    from jaxcart.rundir.reader import read_run_config

    suffix = FORMATS[opts.to]
    out = opts.out or layout.export_file(
        opts.run_dir, suffix, opts.seed_index, opts.combination, opts.policy
    )
    if out.suffix.lower() != suffix:
        raise cli.UsageError(f"--out {out} must end in {suffix} for --to {opts.to}")
    if opts.out is not None and not out.parent.is_dir():  # RUN_DIR: run_params checks
        raise cli.UsageError(f"--out {out}: directory {out.parent} does not exist")
    config = read_run_config(opts.run_dir)["config"]  # refused before any params are read:
    if config.network is not None:
        raise cli.UsageError(
            f"{opts.run_dir} trained its own network ({config.network.path}); "
            f"--to {opts.to} exports the built-in SB3 MLP only"
        )
    if not has_physics(config.env):  # the zip declares CartPole's spaces, ONNX its obs [N, 4]
        raise cli.UsageError(
            f"--to {opts.to} exports CartPole-v1 policies only; {opts.run_dir} trained {config.env}"
        )
    trained = run_params(opts.run_dir, opts.combination, opts.policy)
    if trained.note:
        print(f"note: {opts.run_dir}: parameters {trained.note}", file=sys.stderr)
    params = seed_params(trained, opts.seed_index, "--seed-index")
    if opts.to == "sb3":
        from jaxcart.results.sb3_zip import ACTIVATION_CLASSES, net_arch, sb3_zip_bytes

        data = sb3_zip_bytes(params, trained.config)
        arch = net_arch(trained.config)
        text = (
            f"SB3 PPO (MlpPolicy, net_arch pi={arch['pi']} vf={arch['vf']}, "
            f"{ACTIVATION_CLASSES[config.activation]}); stable_baselines3.PPO.load({str(out)!r}) "
            "opens it"
        )
    else:
        try:
            from jaxcart.results.onnx_policy import onnx_model_bytes

            data = onnx_model_bytes(networks.actor_params(params), config.activation)
        except ImportError as exc:
            raise cli.UsageError(
                f"--to onnx needs the onnx package ({exc.name} is missing): "
                "pip install 'jaxcart[export]' (or pip install onnx)"
            ) from None
        text = "ONNX (input obs [N, 4] float32; outputs logits [N, 2], action [N] int64)"
    atomic_write_bytes(out, data)
    best = " (its best policy)" if opts.policy == "best" else ""
    return f"wrote {out}: seed {opts.seed_index} of {opts.run_dir}{best} as {text}"


@cli.command()
def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 written, 2 a user's mistake)."""
    print(export(cli.options_from(ExportOptions, build_parser().parse_args(argv))))
    return 0


if __name__ == "__main__":
    cli.command_main(main)
