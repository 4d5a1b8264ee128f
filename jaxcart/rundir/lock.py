"""One process at a time per run directory: an advisory ``flock`` on ``RUN_DIR/.lock``.

The lock is held for the whole run and released by the operating system when its holder
exits, however it exits (a SIGKILLed holder never leaves a stale lock). The file keeps the
holder's PID, so a refused process can say who holds it.
"""

from __future__ import annotations

import os
from pathlib import Path

from jaxcart.rundir.files import Dir, RunDirError, open_regular
from jaxcart.rundir.layout import LOCK_FILE


class RunInUse(RunDirError):
    """Another process holds the run directory's lock."""


class RunLock:
    """An exclusive lock on a run directory; :meth:`acquire` fails at once if it is held."""

    def __init__(self, run_dir: str | os.PathLike | Dir) -> None:
        self.dir = run_dir if isinstance(run_dir, Dir) else None
        self.path = (run_dir.path if isinstance(run_dir, Dir) else Path(run_dir)) / LOCK_FILE
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> RunLock:
        """Takes the lock, or raises :class:`RunInUse` naming the holder's PID."""
        import fcntl

        if self._fd is not None:
            return self
        # 0o666 less the umask, as every file of a run directory (jaxcart.rundir.files); a
        # link (symbolic or hard) is refused, not followed: truncating it would truncate
        # whatever it points to
        target = self.dir / LOCK_FILE if self.dir is not None else self.path
        fd = open_regular(target, os.O_RDWR | os.O_CREAT, 0o666, in_place=True)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise RunInUse(
                f"{self.path.parent} is in use by another jaxcart process (PID {holder}); "
                "wait for it to finish or stop it first"
            ) from None
        except BaseException:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases the flock
            self._fd = None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
