"""A progress bar over a run's iterations, as lifecycle hooks.

``tqdm.auto`` picks the bar: a widget in Jupyter and Colab (with ``ipywidgets``), text on a
terminal. ``run_new(..., progress=True)`` uses :class:`ProgressBar`; the command line's
:class:`jaxcart.report.ConsoleReport` is one too, with the printing around it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from jaxcart.run.spec import Hooks

if TYPE_CHECKING:
    from jaxcart.engine.loop import Progress
    from jaxcart.run.spec import Run


class ProgressBar:
    """One bar for all of a run's iterations (every wave), with the env steps per seed and the
    mean ``rollout/ep_rew_mean`` over runs; it closes when training ends, so its time is the
    training's (the evaluation after it is not counted).

    Args:
        enabled: ``False`` draws nothing (the hooks still track the run).
    """

    def __init__(self, enabled: bool = True) -> None:
        self.progress_bar = enabled
        self.bar: Any = None
        self.run: Run | None = None
        self.wave_offset = 0
        self.total = 0

    def on_start(self, run: Run, device_count: int, backend: str) -> None:
        self.run = run

    def on_wave(self, wave: int, num_waves: int, runs: range) -> None:
        """Each wave's iterations continue the one bar."""
        self.wave_offset = wave * self.run.config.num_iterations
        if self.bar is not None:
            self.bar.set_description(f"training (wave {wave + 1}/{num_waves})")

    def on_compiled(self, seconds: float) -> None:
        if self.bar is not None or not self.progress_bar or self.total:
            return  # a later wave (its program is cached): the bar goes on
        self.total = self.run.config.num_iterations * self.run.plan.num_waves
        initial = self.wave_offset + (self.run.resumed_from or 0)
        self.bar = new_bar(self.total, "training", "it", initial)

    def on_chunk(self, progress: Progress) -> None:
        if self.bar is None:
            return
        ret = progress.metrics["rollout/ep_rew_mean"][-1]
        mean_ret = float(np.nanmean(ret)) if np.isfinite(ret).any() else float("nan")
        self.bar.set_postfix_str(
            f"env steps/seed {progress.env_steps:,} | ep_rew_mean {mean_ret:.1f}", refresh=False
        )
        self.bar.update(self.wave_offset + progress.iteration - self.bar.n)
        if self.bar.n >= self.total:
            self.close()

    def write(self, text: str) -> None:
        """A line above the bar (or on stderr without one)."""
        if self.bar is not None:
            self.bar.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr, flush=True)

    def hooks(self) -> Hooks:
        """These methods as the lifecycle's hooks."""
        return chain_hooks(None, self)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar = None


class SeedBars:
    """One bar per seed trained on its own (``python -m jaxcart.sb3``): env steps, their rate,
    the time left and the seed's latest ``rollout/ep_rew_mean``; seeds training at once get a
    bar each, one under the other.

    Args:
        total: env steps each seed trains.
    """

    def __init__(self, total: int) -> None:
        self.total = total
        self.bars: dict[int, Any] = {}

    def update(self, seed: int, env_steps: int, ep_rew_mean: float = float("nan")) -> None:
        """Seed ``seed`` has trained ``env_steps`` steps (its bar starts at the first call)."""
        if seed not in self.bars:
            self.bars[seed] = new_bar(self.total, f"seed {seed}", "step")
        bar = self.bars[seed]
        if ep_rew_mean == ep_rew_mean:  # not NaN: an episode has ended
            bar.set_postfix_str(f"ep_rew_mean {ep_rew_mean:.1f}", refresh=False)
        bar.update(env_steps - bar.n)

    def close(self, seed: int | None = None) -> None:
        """Closes seed ``seed``'s bar (None: every bar)."""
        for s in [seed] if seed is not None else list(self.bars):
            if (bar := self.bars.pop(s, None)) is not None:
                bar.close()

    def outside(self) -> contextlib.AbstractContextManager:
        """A context in which to print: the bars step aside and are drawn again after."""
        if not self.bars:
            return contextlib.nullcontext()
        return next(iter(self.bars.values())).external_write_mode(file=sys.stdout)


def new_bar(total: int, desc: str, unit: str, initial: int = 0):
    """A ``tqdm.auto`` bar of ``total`` ``unit`` on stderr."""
    from tqdm.auto import tqdm

    return tqdm(
        total=total,
        initial=initial,
        unit=unit,
        desc=desc,
        dynamic_ncols=True,
        file=sys.stderr,
    )


def chain_hooks(first: Hooks | None, then: object) -> Hooks:
    """Hooks that call ``first``'s hook for each event (if any), then ``then``'s: a
    :class:`~jaxcart.run.spec.Hooks` or any object with methods of the hooks' names (a
    :class:`ProgressBar`)."""
    first, chained = first or Hooks(), {}
    for name in (field.name for field in dataclasses.fields(Hooks)):
        one, two = getattr(first, name), getattr(then, name, None)
        chained[name] = functools.partial(_both, one, two) if one and two else one or two
    return Hooks(**chained)


def _both(first: Callable, second: Callable, *args: object) -> None:
    first(*args)
    second(*args)
