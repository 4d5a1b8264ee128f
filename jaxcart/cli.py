"""What every ``python -m jaxcart.*`` command shares: one parser (one-line errors with exit
code 2, no abbreviations, "did you mean" hints, ``--version``, one default per option in
``--help``), and plain-text tables."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import decimal
import difflib
import functools
import inspect
import os
import re
import signal
import subprocess
import sys
import textwrap
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

if TYPE_CHECKING:
    from jaxcart.analysis.summary import Score


EXIT_USAGE = 2


def _refuse(message: str) -> NoReturn:
    """``error: MESSAGE`` on stderr, then exit code 2."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(EXIT_USAGE)


def check_not_shadowed() -> None:
    """Refuses, in one line, a ``jaxcart`` that is a folder rather than this package: a folder
    named ``jaxcart`` in the current directory (a clone of the repository, seen from its
    parent) comes first on ``sys.path`` and imports as an empty namespace package, which
    would otherwise fail later with ``cannot import name '__version__'``. Run as a command
    (``python -m jaxcart...``): the line on stderr and exit code 2; imported: ImportError."""
    import jaxcart

    if getattr(jaxcart, "__file__", None) is not None:
        return
    folder = next(iter(getattr(jaxcart, "__path__", [])), "jaxcart")
    message = (
        f"the folder {folder} shadows the installed jaxcart package (a jaxcart/ folder in the "
        "current directory is imported first); run from another directory"
    )
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is not None and spec.name.startswith("jaxcart."):
        _refuse(message)
    raise ImportError(message)


check_not_shadowed()  # before the first name taken from the package

from jaxcart import __version__  # noqa: E402
from jaxcart.core.errors import ConfigError  # noqa: E402
from jaxcart.engine import devices, signals  # noqa: E402
from jaxcart.rundir.files import RunDirError  # noqa: E402

VERSION_TEXT = f"jaxcart {__version__}"


# ---- the environment variables JAX reads, checked before any command runs: a value JAX or XLA
# cannot use becomes one line on stderr and exit code 2 (JAX raises a traceback, XLA aborts the
# process with a fatal log line). import_jax() imports JAX and turns a value JAX refuses at
# import (JAX_ENABLE_X64=junk, ...) into that line: every command calls it before its first
# import of JAX, once its command line is parsed (Parser.parse_args; --help imports no JAX) or,
# in a command whose own module imports JAX, before that import. check_backend() does the same
# for what JAX reads when it starts its backend (JAX_PLATFORMS, XLA_FLAGS); command_main calls
# it before the command's main.


def import_jax() -> None:
    """Imports JAX; a JAX_* value it refuses becomes one line and exit code 2."""
    try:
        import jax  # noqa: F401  (it reads JAX_* variables as it is imported)
    except ValueError as exc:  # JAX's message names the variable or its flag
        _refuse(f"{str(exc).splitlines()[0]}; fix or unset that environment variable")


def _probe_backend() -> str | None:
    """Starts JAX's backend in a child process (XLA aborts the whole process on an unknown
    flag, and a backend started here could not be given ``jax.distributed`` any more): its
    last line on failure, None when it starts."""
    proc = subprocess.run(
        [sys.executable, "-c", "import jax; jax.devices()"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    if proc.returncode == 0:
        return None
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    return lines[-1][-300:] if lines else f"exit code {proc.returncode}"


def check_backend() -> None:
    """Refuses, in one line (exit 2), ``XLA_FLAGS`` or ``JAX_PLATFORMS`` values the backend
    cannot start with. Starts nothing in this process; probes in a child only when a value
    is one jaxcart does not set itself (flags other than the device count, a platform other
    than ``cpu``)."""
    flags, platforms = os.environ.get("XLA_FLAGS", ""), os.environ.get("JAX_PLATFORMS", "")
    for token in flags.split():  # XLA reads a token that is not a --flag as a file of flags
        if not token.startswith("--"):
            _refuse(
                f"XLA_FLAGS holds {token!r}, which is not a --flag (XLA would read it as a "
                "file of flags and abort); fix or unset XLA_FLAGS"
            )
    if not all(t.startswith(devices.DEVICE_COUNT_FLAG) for t in flags.split()):
        if (failure := _probe_backend()) is not None:
            _refuse(f"XLA cannot start with XLA_FLAGS={flags!r}: {failure}")
    if {p.strip() for p in platforms.split(",") if p.strip()} - {"cpu"}:
        failure = _probe_backend()
        if failure is not None and failure.isidentifier():  # a bare exception: no plugin
            _refuse(
                f"JAX_PLATFORMS={platforms!r}: this JAX cannot start that backend (it says only "
                f"{failure}); install JAX for it (cuda: pip install -U 'jax[cuda12]') or unset "
                "JAX_PLATFORMS to run on the CPU"
            )
        if failure is not None:
            _refuse(f"JAX_PLATFORMS={platforms!r}: {failure}; fix or unset JAX_PLATFORMS")


class UsageError(Exception):
    """A mistake a user made on the command line; printed as one line, exit code 2."""


class ParserExit(SystemExit):
    """``--help`` or ``--version`` was answered: :func:`command` returns the code, so
    ``main(argv)`` returns instead of exiting (uncaught, it exits as argparse would)."""


class HelpFormatter(argparse.HelpFormatter):
    """At most one ``(default: X)`` per option: added from the option's default unless its
    help states one already or there is none worth showing (``None``, ``False``, ``[]``)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text, default = action.help or "", action.default
        unshown = any(default is v for v in (None, False, argparse.SUPPRESS)) or default == []
        if "(default" in text or not action.option_strings or unshown:
            return text
        return f"{text} (default: %(default)s)"


# Other libraries' names for jaxcart's options (Stable-Baselines3, CleanRL, PureJaxRL, rl-zoo):
# a hint by meaning comes before one by spelling, so that ``--lr`` suggests ``--learning-rate``
# rather than ``--anneal-lr``. Each name lists candidates in order; the first that the command
# has is suggested (``--episodes`` is ``--eval-episodes`` in train, ``--episodes`` in evaluate).
ALIASES_OF: dict[str, str] = {
    "--learning-rate": "lr step-size",
    "--anneal-lr": "lr-schedule lr-decay linear-lr anneal",
    "--gamma": "discount discount-factor",
    "--gae-lambda": "lambda lam gae lmbda gae-lam",
    "--num-steps": "n-steps nsteps rollout-length horizon n-step",
    "--num-envs": "n-envs nenvs envs num-env num-workers",
    "--num-seeds": "seeds n-seeds nseeds num-seed",
    "--ent-coef": "ent entropy entropy-coef ent-coeff",
    "--vf-coef": "vf value-coef vf-coeff value-loss-coef",
    "--minibatch-size": "batch-size minibatch mini-batch-size num-minibatches nminibatches",
    "--update-epochs": "epochs n-epochs num-epochs ppo-epochs noptepochs",
    "--total-timesteps": "total-steps timesteps n-timesteps num-timesteps total-env-steps",
    "--clip-coef": "clip-range clip clip-param clip-eps cliprange",
    "--max-grad-norm": "grad-clip max-norm clip-grad-norm grad-norm",
    "--adam-eps": "eps epsilon adam-epsilon",
    "--norm-adv": "normalize-advantage normalize-advantages norm-advantage",
    "--hidden-sizes": "net-arch hidden hidden-size layers",
    "--activation": "activation-fn act",
    "--out": "output output-dir outdir log-dir logdir save-dir save-path run-dir",
    "--eval-episodes --episodes": "n-eval-episodes num-episodes n-episodes eval-episodes episodes",
    "--resume": "continue restore resume-from load",
    "--checkpoint-every": "save-freq checkpoint-freq checkpoint-interval save-every",
    "--preset": "algo config hyperparams",
    "--logger": "track wandb tensorboard tensorboard-log",
    "--gif": "video render save-gif gif-path",
}
"""Each option (or, where commands differ, the options in order: the first a command has) and
the other libraries' names for it, space-separated."""
ALIASES: dict[str, tuple[str, ...]] = {
    alias: tuple(options.split())
    for options, names in ALIASES_OF.items()
    for alias in names.split()
}
"""Each other library's name -> the options it may mean, in order."""


def suggestion(token: str, options: Sequence[str]) -> str | None:
    """The option an unknown ``token`` probably meant: by meaning (:data:`ALIASES`: ``--lr``
    -> ``--learning-rate``, ``--n-envs`` -> ``--num-envs``), else by spelling
    (``--num_seeds`` -> ``--num-seeds``, ``--learn`` -> ``--learning-rate``,
    ``--lerning-rate`` -> ``--learning-rate``)."""
    name = token.split("=", 1)[0]
    if not name.startswith("-") or name == "-":
        return None
    longs = [o for o in options if o.startswith("--")]
    wanted = "--" + name.lstrip("-").replace("_", "-").lower()
    if wanted in longs:
        return wanted
    meant = [o for o in ALIASES.get(wanted[2:], ()) if o in longs]
    if meant:
        return meant[0]
    # a prefix (--learn), a last part (--epochs: --update-epochs), else a near spelling
    bare = wanted[2:]
    for found in (
        [o for o in longs if o.startswith(wanted)],
        [o for o in longs if bare and o.endswith("-" + bare)],
        difflib.get_close_matches(wanted, longs, n=1, cutoff=0.75),
    ):
        if found:
            return found[0] if len(found) == 1 else f"one of {', '.join(found[:5])}"
    return None


MAX_COUNT = 2**63 - 1
"""The largest count :func:`count` accepts (a 64-bit integer)."""


def count(text: str, maximum: int = MAX_COUNT, minimum: int = 1) -> int:
    """A positive integer as a user writes one: ``100000``, ``100_000``, ``1e5`` or ``1.5e5``
    (an argparse ``type``; :func:`bounded_count` gives one with another ``maximum``, and
    ``minimum=0`` one that may be 0, as ``--eval-every 0`` turns the evaluations off).

    Raises:
        argparse.ArgumentTypeError: not a number, not whole (``1.5e0``), under ``minimum``,
            or over ``maximum``.
    """
    try:
        value = decimal.Decimal(text.strip())
    except decimal.InvalidOperation:
        value = None
    if value is None or not value.is_finite() or value != value.to_integral_value():
        raise argparse.ArgumentTypeError(
            f"expected a whole number (such as 4, 100_000 or 1e5), got {text!r}"
        )
    if value < minimum:
        least = "a positive integer" if minimum == 1 else f"an integer of at least {minimum}"
        raise argparse.ArgumentTypeError(f"must be {least}, got {text}")
    if value > maximum:  # int() of 1e999999999 would take the memory of a billion digits
        shown = f"{maximum:.3g}" if maximum == MAX_COUNT else f"{maximum:,}"
        raise argparse.ArgumentTypeError(f"must be at most {shown}, got {text}")
    return int(value)


def bounded_count(maximum: int = MAX_COUNT, minimum: int = 1) -> Callable[[str], int]:
    """An argparse ``type``: :func:`count`, in ``[minimum, maximum]``."""
    return functools.partial(count, maximum=maximum, minimum=minimum)


seed = bounded_count(2**32 - 1, minimum=0)
"""A seed for ``env.reset``: a whole number in [0, 2**32) (an argparse ``type``)."""


def score_steps(text: str) -> int:
    """STEPS of ``--score return-at:STEPS``: ``100000``, ``100_000`` or ``1e5``."""
    try:
        return count(text)
    except argparse.ArgumentTypeError as exc:
        raise ValueError(f"return-at:{text}: STEPS {exc}") from None


def score(text: str) -> Score:
    """``--score``'s type (compare, ``train --sweep``): ``eval``, ``auc`` or
    ``return-at:STEPS``; an unknown or malformed score is argparse's one-line error."""
    from jaxcart.analysis.summary import Score

    try:
        return Score.parse(text, score_steps)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


KERNEL_FILESYSTEMS = ("/proc", "/sys", "/dev")
"""Where no output directory can be: the kernel's own filesystems."""


def out_dir(text: str) -> Path:
    """A directory to write into (an argparse ``type``): not empty (``Path('')`` would be
    the current directory) and not under the kernel's filesystems."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty; name a directory")
    resolved = os.path.realpath(text)
    if any(resolved == k or resolved.startswith(k + "/") for k in KERNEL_FILESYSTEMS):
        raise argparse.ArgumentTypeError(
            f"{text} is under {resolved.split('/')[1]!r}, the kernel's own filesystem; choose a directory on disk"
        )
    return Path(text)


MAX_EPISODES = 100_000
"""The most evaluation episodes per seed (a run directory declaring more is refused too)."""


MAX_REPS = 100_000
"""The most bootstrap resamples ``compare --reps`` takes."""
MAX_DPI = 1000
"""The highest PNG resolution plot and compare draw at (a 15 x 11 inch figure: 165 MP)."""


SCRIPTS = {"jaxcart-train": "jaxcart.train"}
"""The installed scripts that run one command (``jaxcart`` runs any: ``jaxcart COMMAND``)."""


def prog_name(module: str, argv0: str | None = None) -> str:
    """What a command's usage line calls it: as it was started, when through an installed
    script (``jaxcart-train``, ``jaxcart evaluate``), else ``python -m jaxcart.COMMAND``.
    ``argv0`` defaults to ``sys.argv[0]``."""
    argv0 = sys.argv[0] if argv0 is None and sys.argv else argv0 or ""
    script = os.path.basename(argv0).removesuffix(".exe")
    if SCRIPTS.get(script) == module:
        return script
    if script == "jaxcart":
        return f"jaxcart {module.removeprefix('jaxcart.')}"
    return f"python -m {module}"


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` for every jaxcart command: errors raise :class:`UsageError` (one
    line, no usage dump) instead of exiting, so ``main(argv)`` can be called in-process;
    options must be spelled out (no abbreviations) and an unknown one gets a "did you mean"
    hint; ``--version`` prints ``jaxcart X.Y.Z``."""

    def __init__(self, *args, **kwargs) -> None:
        if str(kwargs.get("prog", "")).startswith("python -m jaxcart."):
            kwargs["prog"] = prog_name(kwargs["prog"][len("python -m ") :])
        kwargs.setdefault("allow_abbrev", False)
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self.add_argument(
            "--version", action="version", version=VERSION_TEXT, help="print the version and exit"
        )

    def error(self, message: str):
        # "argument --num-seeds: must be ..." reads as the other checks do: "--num-seeds must be"
        named = re.fullmatch(r"argument (--[\w-]+): (must .*)", message, re.DOTALL)
        if named:
            message = f"{named[1]} {named[2]}"
        raise UsageError(f"{message} (see {self.prog} --help)")

    def exit(self, status: int = 0, message: str | None = None):
        if message:
            self._print_message(message, sys.stderr)
        raise ParserExit(status)

    def parse_args(self, args=None, namespace=None):  # type: ignore[override]
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            argv = sys.argv[1:] if args is None else list(args)
            self.error(self.unrecognized_text(extras, argv))
        # The command runs: JAX now (JAX_* checked), not for --help or a usage error.
        import_jax()
        return namespace

    def unrecognized_text(self, extras: list[str], argv: Sequence[str] = ()) -> str:
        """``unrecognized arguments: --num_seeds 3 (did you mean --num-seeds?)``; a list
        option given space-separated values (``--hidden-sizes 64 64``) gets its form."""
        options = list(self._option_string_actions)
        hints = [(t, s) for t in extras if (s := suggestion(t, options))]
        text = f"unrecognized arguments: {' '.join(extras)}"
        for i, token in enumerate(argv[:-2]):
            list_option = getattr(self._option_string_actions.get(token), "metavar", None) == "N,N"
            # "--hidden-sizes 64 64": the value, then the first unrecognized token
            if list_option and argv[i + 2] == extras[0]:
                values = ",".join([argv[i + 1], *(t for t in extras if t.isdigit())])
                return f"{text} ({token} takes one comma-separated list: {token} {values})"
        if len(hints) == 1:
            return f"{text} (did you mean {hints[0][1]}?)"
        if hints:
            return text + "".join(f"; {t}: did you mean {s}?" for t, s in hints)
        return text


def field_docs(cls: type) -> dict[str, str]:
    """Attribute docstrings of a dataclass, read from its source (they serve as CLI help)."""
    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body
    docs: dict[str, str] = {}
    for node, nxt in zip(body, body[1:]):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
            and isinstance(nxt.value.value, str)
        ):
            docs[node.target.id] = " ".join(nxt.value.value.split())
    return docs


def option(default: Any = None, **kwargs: Any) -> Any:
    """A field of a command's options dataclass that is the command-line option ``--name``,
    declared once: its default, ``kwargs`` for ``add_argument`` (``group``: the help section,
    else :func:`add_options`' ``title``) and its docstring as the help."""
    return dataclasses.field(default=default, metadata={"option": kwargs})


def add_options(
    parser: argparse._ActionsContainer, cls: type, title: str, names: tuple[str, ...] = ()
) -> dict[str, Any]:
    """One option per :func:`option` field of the dataclass ``cls`` (those of ``names`` only,
    when given), in declaration order; returns the argument groups by title (``""``: the
    options go into ``parser`` itself)."""
    docs, groups = field_docs(cls), {}
    for f in dataclasses.fields(cls):
        if "option" not in f.metadata or (names and f.name not in names):
            continue
        kwargs = dict(f.metadata["option"])
        where = kwargs.pop("group", title)
        if where not in groups:
            groups[where] = parser.add_argument_group(where) if where else parser
        kwargs.setdefault("help", docs.get(f.name, "").replace("%", "%%"))
        default = [] if kwargs.get("action") == "append" else f.default
        flag = "--" + f.name.replace("_", "-")
        groups[where].add_argument(flag, dest=f.name, default=default, **kwargs)
    return groups


def options_from(cls: type, args: argparse.Namespace, **given: Any) -> Any:
    """The options dataclass ``cls`` from parsed ``args`` whose names are its fields (a
    repeated option's list becomes a tuple), then ``given``."""
    own = {f.name for f in dataclasses.fields(cls)} - set(given)
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in vars(args).items()}
    return cls(**{k: v for k, v in values.items() if k in own}, **given)


@dataclasses.dataclass(frozen=True)
class SharedOptions:
    """The options several commands take, each declared once as an :func:`option` field:
    a command adds those it takes with :func:`add_options` (``--logger`` and ``--logger-dir``:
    train, sb3; ``--trust-code``: train, evaluate)."""

    logger: tuple[str, ...] = option(
        (), action="append", choices=("tensorboard", "swanlab", "wandb")
    )
    """also log metrics (under SB3's names) to TensorBoard event files, SwanLab (offline) or
    Weights & Biases (offline unless WANDB_MODE is set; WANDB_PROJECT, WANDB_ENTITY and
    WANDB_DIR are honoured; one W&B run per seed, grouped by the run directory); repeatable"""
    logger_dir: Path | None = option(type=Path, metavar="DIR")
    """one folder the loggers write into, shared by several runs so that one dashboard shows
    them together (default: SwanLab's SWANLAB_LOG_DIR or ./swanlog; W&B's WANDB_DIR or the run
    directory; TensorBoard's RUN_DIR/tensorboard)"""
    trust_code: bool = option(False, action="store_true")
    """import and run the code the run directory names (its own network class and metric
    functions, from its config.json): only for runs you trust; without it such a run is
    refused, and the rest of jaxcart never imports a run's code"""


def spelled(value: object) -> str:
    """A value as the command line spells it: ``64,64``, ``on``/``off``, ``none``, a float
    exactly (its ``repr``, ``0.0003``); what ``--help`` shows and a config file becomes.

    Raises:
        UsageError: a list in a list (``[[1, 2], [3]]``): no option takes one, and flattening
            it would train something the file did not say.
    """
    if isinstance(value, (list, tuple)):
        if any(isinstance(v, (list, tuple, dict)) for v in value):
            raise UsageError(f"a list of lists is no option value, got {value!r}")
        return ",".join(spelled(v) for v in value)
    if isinstance(value, bool) or value is None:
        return {True: "on", False: "off", None: "none"}[value]
    return repr(value) if isinstance(value, float) else str(value)


def join_negative_values(argv: list[str]) -> list[str]:
    """``["--learning-rate", "-3e-4"]`` -> ``["--learning-rate=-3e-4"]``: argparse reads a
    value like ``-3e-4`` as an unknown option, which would hide the real problem (a negative
    value) behind "expected one argument"."""
    out: list[str] = []
    for token in argv:
        if (
            out
            and out[-1].startswith("--")
            and "=" not in out[-1]
            and re.fullmatch(r"-(\d|\.\d|inf|nan).*", token)
        ):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


TABLE_WIDTH = 100  # a terminal's width, with room for a prompt


def format_table(rows: list[list], header: list[str], width: int | None = None) -> str:
    """Right-aligned plain-text table.

    With ``width``, columns that would not fit go into further tables below, each beginning
    with the first column again (the row's name), so that no line is wider than ``width``
    unless one column alone is.
    """
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    groups: list[list[int]] = [[0]]
    for i in range(1, len(header)):
        used = sum(widths[j] + 2 for j in groups[-1])
        if width is not None and len(groups[-1]) > 1 and used + widths[i] > width:
            groups.append([0])
        groups[-1].append(i)
    tables = []
    for columns in groups:
        lines = ["  ".join(str(header[i]).rjust(widths[i]) for i in columns)]
        lines.append("  ".join("-" * widths[i] for i in columns))
        lines += ["  ".join(str(r[i]).rjust(widths[i]) for i in columns) for r in rows]
        tables.append("\n".join(lines))
    return "\n\n".join(tables)


def wrap(text: str, width: int = TABLE_WIDTH) -> str:
    """``text`` wrapped to ``width`` columns, later lines indented by two spaces."""
    return "\n".join(
        textwrap.fill(line, width, subsequent_indent="  ", break_on_hyphens=False)
        for line in text.splitlines()
    )


def command_main(
    main: Callable[[list[str] | None], int], argv: list[str] | None = None, all_cores: bool = False
) -> NoReturn:
    """The process entry of every command, and the one place a command meets Ctrl-C:
    ``python -m jaxcart`` and ``python -m jaxcart.COMMAND``, and the ``jaxcart`` and
    ``jaxcart-train`` scripts, all call ``main(argv)`` through it and exit with its code.

    Ctrl-C (:class:`KeyboardInterrupt`), and SIGTERM, which it reads as one while ``main``
    runs, end the command with one line on stderr and exit code 130, never a traceback. The
    training handles its own signals inside that (a checkpoint, then 128 + the signal:
    :meth:`jaxcart.engine.signals.StopRequest.installed`). Once ``main`` has returned, SIGINT
    and SIGTERM take their default action, so that one during the interpreter's teardown
    (``atexit``) ends the process without a traceback; and when a second signal left XLA
    working on a thread (:func:`jaxcart.engine.signals.abandoned_work`), the process ends
    without that teardown. ``all_cores`` (train, tune): ``main`` runs on one CPU device per
    core (:func:`jaxcart.engine.devices.use_all_host_cores`).
    """
    try:
        try:
            signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM as Ctrl-C
            devices.check_device_count_flag(os.environ.get("XLA_FLAGS", ""))
            check_backend()  # JAX_PLATFORMS, XLA_FLAGS: one line, not an abort
            if all_cores:
                devices.use_all_host_cores()
            code = main(argv)
        finally:
            for sig in signals.SIGNALS:
                signal.signal(sig, signal.SIG_DFL)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = EXIT_USAGE
    except KeyboardInterrupt:
        print("error: interrupted; nothing more was written", file=sys.stderr, flush=True)
        code = 130
    if signals.abandoned_work():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    raise SystemExit(code)


def _note_line(shown: Callable, message, category, *args, **kwargs) -> None:
    """A run that cannot be verified is one ``note:`` line, not a warning with its source."""
    from jaxcart.rundir.files import UnverifiedRunWarning

    if issubclass(category, UnverifiedRunWarning):
        print(f"note: {message}", file=sys.stderr)
    else:
        shown(message, category, *args, **kwargs)


def command(*also: type[Exception]) -> Callable[[Callable[..., int]], Callable[..., int]]:
    """Decorates a command's ``main(argv=None)``: a user's mistake (bad option, bad config,
    unusable run directory, unwritable path, or one of the exception types in ``also``)
    becomes ``error: ...`` on stderr and exit code 2, and ``--help``/``--version`` return
    their code."""

    def decorate(body: Callable[..., int]) -> Callable[..., int]:
        @functools.wraps(body)
        def main(argv: list[str] | None = None) -> int:
            try:
                with warnings.catch_warnings():  # restores showwarning afterwards
                    shown = warnings.showwarning
                    warnings.showwarning = functools.partial(_note_line, shown)
                    return body(argv)
            except ParserExit as exc:  # --help, --version
                return int(exc.code or 0)
            except ConfigError as exc:
                message, option = str(exc), exc.option
                if option and message.startswith(option):  # named as the command line does
                    message = "--" + option.replace("_", "-") + message[len(option) :]
                print(f"error: {message}", file=sys.stderr)
            except (UsageError, RunDirError, *also) as exc:
                print(f"error: {exc}", file=sys.stderr)
            except OSError as exc:
                where = f": {exc.filename}" if exc.filename else ""
                print(f"error: {exc.strerror or exc}{where}", file=sys.stderr)
            return EXIT_USAGE

        return main

    return decorate
