"""Stopping a run cleanly on SIGINT or SIGTERM while it trains.

Inside :meth:`StopRequest.installed` (a context manager: the training, nothing else), the
first signal sets a flag that the run checks at its safe points (between initialisation
batches, after compiling, between chunks, before evaluation); a second SIGINT or SIGTERM
raises :class:`KeyboardInterrupt` at once. Long calls into XLA (compiling, waiting for a
chunk) run on a worker thread while the main thread waits in short steps, so a signal is
handled (and its message printed) when it arrives, not when the call returns; a call given up
on that way leaves its worker running (:func:`abandoned_work`).

Outside training, signals are Python's: :func:`jaxcart.cli.command_main` turns the
``KeyboardInterrupt`` into one line and exit code 130.
"""

from __future__ import annotations

import atexit
import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from concurrent import futures
from concurrent.futures import Future
from typing import TypeVar

SIGNALS = (signal.SIGINT, signal.SIGTERM)
T = TypeVar("T")


class Stopped(Exception):
    """Raised at a safe point after a stop was requested."""


class StopRequest:
    """Set by the first SIGINT/SIGTERM (``on_signal`` is told which); a second one raises
    :class:`KeyboardInterrupt`. Calling it says whether a stop was requested."""

    def __init__(self, on_signal: Callable[[int], None] | None = None) -> None:
        self.signum: int | None = None
        self.on_signal = on_signal
        self._installed = 0

    def __call__(self) -> bool:
        return self.signum is not None

    def check(self) -> None:
        """Raises :class:`Stopped` when a stop was requested."""
        if self.signum is not None:
            raise Stopped(signal.Signals(self.signum).name)

    def request(self, signum: int, frame: object = None) -> None:
        """The signal handler; callable directly (tests, notebooks)."""
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum
        if self.on_signal:
            self.on_signal(signum)

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopRequest]:
        """Handles SIGINT and SIGTERM inside the block (nested use is a no-op; outside the
        main thread signals cannot be handled and the block runs without)."""
        outermost = self._installed == 0
        self._installed += 1
        try:
            with handling(self.request) if outermost else contextlib.nullcontext():
                yield self
        finally:
            self._installed -= 1


@contextlib.contextmanager
def handling(handler: Callable[[int, object], None]) -> Iterator[None]:
    """``handler`` handles SIGINT and SIGTERM inside the block; the previous handlers are back
    after it. Outside the main thread, where Python cannot handle signals, the block runs
    without."""
    previous = {}
    try:
        for sig in SIGNALS:
            previous[sig] = signal.signal(sig, handler)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def wait_interruptibly(fn: Callable[[], T]) -> T:
    """``fn()`` on a worker thread while this thread waits in short steps (0.1 s), so that signal
    handlers run promptly (Python runs them only between bytecodes of the main thread).

    Exceptions of ``fn`` are re-raised here; a :class:`KeyboardInterrupt` raised by a handler
    while waiting propagates at once (the worker is a daemon and is abandoned).
    """
    if threading.current_thread() is not threading.main_thread():
        return fn()
    future: Future = Future()
    in_background(fn, future, background=False)
    while not future.done():
        futures.wait([future], 0.1)
    return future.result()


_running: set[threading.Thread] = set()
"""The workers of :func:`in_background` (:func:`wait_interruptibly`'s too) whose call has not
returned. (Not ``Thread.is_alive``: a ``join`` interrupted by a signal marks the thread
stopped.)"""
_background: set[threading.Thread] = set()
"""The threads of :func:`in_background` whose work has not returned."""
_background_seen: list = []


def in_background(work: Callable[[], T], future: Future, background: bool = True) -> None:
    """``work()`` on a daemon thread, its result or exception set on ``future``. Until it
    returns, :func:`abandoned_work` is true, so a command stopped meanwhile (a signal) ends
    without the interpreter's teardown instead of waiting for it or freeing what it uses; a
    program that simply ends waits for it first (:func:`_finish_background`), unless
    ``background`` is False (:func:`wait_interruptibly`'s worker, which its caller waits for).

    The thread is listed in :data:`_running` (and, ``background``, in :data:`_background`)
    until ``work`` returns."""

    def target() -> None:
        try:
            future.set_result(work())
        except BaseException as error:  # the caller sees it in future.result()
            future.set_exception(error)
        finally:
            _running.discard(worker)
            _background.discard(worker)

    name = "jaxcart-background" if background else "jaxcart-wait"
    worker = threading.Thread(target=target, name=name, daemon=True)
    _running.add(worker)
    if background:
        if not _background_seen:  # registered after JAX's own exit handlers, so it runs first
            _background_seen.append(atexit.register(_finish_background))
        _background.add(worker)
    worker.start()


def _finish_background() -> None:
    """At the interpreter's exit, waits for background work (an XLA compile of a few
    seconds at most) so that teardown never frees what it is using."""
    for worker in list(_background):
        worker.join()


def abandoned_work() -> bool:
    """Whether a call that :func:`wait_interruptibly` gave up on (a second signal), or one
    started :func:`in_background`, still runs on its thread: XLA may still be compiling there,
    so the process should end without the interpreter's teardown (``os._exit``), which would
    free what that call is using."""
    return bool(_running)
