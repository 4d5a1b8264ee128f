"""Animated GIFs of a policy balancing the pole in Gymnasium's own CartPole-v1.

Frames come from Gymnasium's renderer (``render_mode="rgb_array"``, which needs ``pygame``);
without pygame the env draws them itself (:attr:`jaxcart.core.envs.Env.draw_frame`: CartPole's
with Pillow, in the same geometry and colours). The episode itself always runs in Gymnasium's
env (``gymnasium.make("CartPole-v1")`` by default), so the GIF shows exactly what the
evaluation measures. Needs Pillow (``pip install pillow pygame``).

Example::

    import jaxcart
    from jaxcart.results.gif import render_gif

    render_gif(jaxcart.load_policy("runs/my-run"), "cartpole.gif")
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from jaxcart.core import envs
from jaxcart.core.cartpole import EnvParams
from jaxcart.gym.stock import make_cartpole, reset_options
from jaxcart.rundir.files import atomic_write_bytes

PALETTE_COLOURS = 64
"""Colours of the GIF's one palette, taken from its first frame: the scene's few colours and
the blends of their anti-aliased edges."""


class RenderedGif(NamedTuple):
    """What :func:`render_gif` wrote."""

    path: Path
    frames: int  # frames in the GIF (after frame skipping)
    steps: int  # environment steps taken
    episode_return: float
    backend: str  # "gymnasium" (pygame) or "pillow"


def pygame_available() -> bool:
    """Whether Gymnasium's own renderer (pygame) can be used; lets pygame render off-screen on
    a machine without a display, and quietly."""
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        # rgb_array rendering never opens a window; the dummy driver avoids SDL errors.
        os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
        os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
    try:
        import pygame  # noqa: F401
    except ImportError:
        return False
    return True


def _backend(backend: str) -> str:
    """``"gymnasium"`` or ``"pillow"``: ``backend``, with ``"auto"`` resolved and checked."""
    if backend not in ("auto", "gymnasium", "pillow"):
        raise ValueError(f"backend must be 'auto', 'gymnasium' or 'pillow', got {backend!r}")
    if backend != "pillow" and pygame_available():
        return "gymnasium"
    if backend == "gymnasium":
        raise ImportError(
            "backend='gymnasium' needs pygame: pip install pygame (or use backend='pillow')"
        )
    return "pillow"


def episode_frames(
    policy: Callable[[np.ndarray], int],
    seed: int = 0,
    max_steps: int = 500,
    backend: Literal["auto", "gymnasium", "pillow"] = "auto",
    env_id: str = "CartPole-v1",
    env_params: EnvParams | None = None,
) -> Iterator[tuple[np.ndarray, int, float]]:
    """Runs one greedy episode of ``policy`` in Gymnasium and yields ``(frame [400, 600, 3]
    uint8, steps, return so far)`` after the reset and after every step (``max_steps`` at
    most): frames from Gymnasium's renderer (``backend="gymnasium"``, pygame) or drawn by
    the env's :attr:`~jaxcart.core.envs.Env.draw_frame` (``"pillow"``); ``"auto"``: pygame
    when installed. ``env_params``: the physics (default CartPole-v1's). One at a time:
    500 steps' frames are 360 MB, so :func:`render_gif` streams them."""
    backend = _backend(backend)
    draw = envs.make(env_id).draw_frame if backend == "pillow" else None  # the env's own
    if backend == "pillow" and draw is None:
        raise ValueError(f"env {env_id} draws no frames with Pillow; use backend='gymnasium'")
    env = make_cartpole(env_params, env_id, render_mode=None if draw else "rgb_array")

    def frame() -> np.ndarray:
        return env.render() if draw is None else draw(np.asarray(env.unwrapped.state), env_params)

    try:
        obs, _ = env.reset(seed=seed, options=reset_options(env_params))
        total = 0.0
        yield frame(), 0, total
        for step in range(1, max_steps + 1):
            obs, reward, terminated, truncated, _ = env.step(int(policy(obs)))
            total += float(reward)
            yield frame(), step, total
            if terminated or truncated:
                break
    finally:
        env.close()


def _annotate(image, text: str) -> None:
    """Writes ``text`` in the top-left corner of a PIL image, in a font sized to the image
    (Pillow's bitmap default is 6 pixels wide a letter, unreadable in a 300x200 GIF)."""
    from PIL import ImageDraw, ImageFont

    size = max(10, round(image.height * 0.07))
    try:
        font = ImageFont.load_default(size=size)  # FreeType's scalable default font
    except (AttributeError, TypeError, ImportError):  # Pillow without FreeType
        font = ImageFont.load_default()
    ImageDraw.Draw(image).text((6, 4), text, fill=(60, 60, 60), font=font)


def render_gif(
    policy: Callable[[np.ndarray], int],
    path: str | os.PathLike,
    seed: int = 0,
    max_steps: int = 500,
    fps: float = 50,
    *,
    frame_skip: int = 2,
    scale: float = 0.5,
    annotate: bool = True,
    backend: Literal["auto", "gymnasium", "pillow"] = "auto",
    env_id: str = "CartPole-v1",
    env_params: EnvParams | None = None,
) -> RenderedGif:
    """Renders one greedy episode of ``policy`` in Gymnasium's CartPole-v1 to an animated GIF.

    Args:
        policy: maps a float32 observation ``(4,)`` to an action, e.g.
            ``jaxcart.load_policy(run_dir, seed_index)``.
        path: the ``.gif`` to write (its directory must exist).
        seed: the episode's ``env.reset(seed=seed)``.
        max_steps: at most this many environment steps (CartPole-v1 truncates at 500).
        fps: environment steps per second of animation; 50 is real time (CartPole's tau is
            0.02 s). The GIF keeps every ``frame_skip``-th frame, each shown ``frame_skip / fps``
            seconds, so the playback speed does not depend on ``frame_skip``.
        frame_skip: keep one frame in this many (the last frame is always kept); 2 halves the
            file size without visible jerkiness.
        scale: resize factor of Gymnasium's 600x400 frames (0.5 gives 300x200).
        annotate: write the step count and return in the corner.
        backend: ``"gymnasium"`` (pygame renderer), ``"pillow"`` (drawn here), or ``"auto"``.
        env_params: the physics the episode runs on (default CartPole-v1's), e.g. the
            ``env_params`` of a :func:`jaxcart.load_policy` policy.

    Returns:
        A :class:`RenderedGif` with the path, frame count, steps and episode return.
    """
    for name, value in (("max_steps", max_steps), ("frame_skip", frame_skip)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    if not 0 < scale <= 4:
        raise ValueError(f"scale must be in (0, 4], got {scale!r}")
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: directory {path.parent} does not exist")
    backend, images = _backend(backend), []
    episode = episode_frames(policy, seed, max_steps, backend, env_id, env_params)

    def add(frame: np.ndarray, steps: int, total: float) -> None:
        """The frame resized, captioned and mapped onto the GIF's palette (the first frame's)."""
        from PIL import Image

        image = Image.fromarray(np.asarray(frame, np.uint8))
        size = (max(1, round(image.width * scale)), max(1, round(image.height * scale)))
        image = image.resize(size, Image.Resampling.LANCZOS) if image.size != size else image
        if annotate:
            _annotate(image, f"step {steps}  return {total:.0f}")
        palette = images[0] if images else image.quantize(PALETTE_COLOURS)
        images.append(image.quantize(palette=palette, dither=Image.Dither.NONE))

    for i, last in enumerate(episode):  # at least the reset's frame
        if i % frame_skip == 0:
            add(*last)
    if i % frame_skip:  # always show how the episode ended
        add(*last)

    buf = io.BytesIO()
    duration = max(10, round(100 * frame_skip / fps) * 10)  # whole centiseconds, in ms
    frames = {"save_all": True, "append_images": images[1:], "duration": duration}
    images[0].save(buf, format="GIF", loop=0, optimize=False, disposal=1, **frames)
    atomic_write_bytes(path, buf.getvalue())
    return RenderedGif(path, len(images), last[1], last[2], backend)
