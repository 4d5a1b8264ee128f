"""The manifest of a run directory: ``manifest.json``, the digest of every finished file.

A run records each file's ``sha256:<hex>`` here before the file is renamed into place (the
manifest then lists the old and the new digest, so a crash between the two renames leaves a
file the manifest accepts) and keeps only the new one once it is. Every reader checks a file
against it before trusting anything in it (:func:`verify`): a file whose bytes are not the ones
the run wrote is refused in one line that names it. The checkpoint counts too; the metrics
stream, appended chunk by chunk, is covered by the digest its checkpoint records
(:mod:`jaxcart.rundir.stream`), and a finished wave's file by the digest it carries.

A digest proves integrity (nothing changed the bytes since the run wrote them), not
authorship: whoever rewrites a file and its manifest's line makes a consistent directory,
which the readers then check as they check any directory (bounds, shapes, finite values).

A directory whose ``config.json`` has no ``manifest`` flag was written before manifests: it is
read with a one-line :class:`UnverifiedRunWarning`; one whose ``config.json`` says it has a
manifest and has none is refused.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable

from jaxcart.rundir import files, layout
from jaxcart.rundir.files import RunDirError

FORMAT = 1
MAX_BYTES = 1 << 20
FLAG = "manifest"
"""Of ``config.json``: true in a run that keeps ``manifest.json``."""


class UnverifiedRunWarning(UserWarning):
    """A run directory from before manifests: its files cannot be checked against one."""


class Manifest:
    """The manifest a run writes in one of its directories (opened :class:`files.Dir`)."""

    def __init__(self, directory: files.Dir) -> None:
        self.dir = directory
        self.digests: dict[str, list[str]] = {}
        try:  # a resumed run keeps what it recorded; an unreadable manifest starts afresh
            self.digests = _parse(directory / layout.MANIFEST_FILE)
        except RunDirError:
            pass

    def staging(self, name: str) -> Callable[[str], None]:
        """The ``on_digest`` of a write of ``name``: records its new digest beside the old."""

        def stage(digest: str) -> None:
            self.digests[name] = [*self.digests.get(name, [])[-1:], digest]
            self._write()

        return stage

    def settle(self, name: str) -> None:
        """After ``name`` was renamed into place: only its new digest stays."""
        self.digests[name] = self.digests[name][-1:]
        self._write()

    def forget(self, *names: str) -> None:
        for name in names:
            self.digests.pop(name, None)
        self._write()

    def write(self, name: str, writer: Callable[[files.Entry, Callable[[str], None]], None]):
        """Writes ``name`` with ``writer(entry, on_digest)`` and records it."""
        writer(self.dir / name, self.staging(name))
        self.settle(name)

    def verify(self, name: str) -> None:
        """Refuses ``name`` unless its bytes are those recorded for it."""
        check_digest(self.dir / name, self.digests.get(name))

    def _write(self) -> None:
        data = {"format": FORMAT, "files": {k: v for k, v in sorted(self.digests.items())}}
        files.write_json(self.dir / layout.MANIFEST_FILE, data)
        self.dir.fsync()


class NoManifest:
    """What a run from before manifests (or a process that writes nothing) writes through:
    the files alone."""

    def __init__(self, directory: files.Dir | None = None) -> None:
        self.dir = directory

    def write(self, name: str, writer: Callable[[files.Entry, Callable[[str], None]], None]):
        writer(self.dir / name, None)

    def forget(self, *names: str) -> None:
        pass

    def verify(self, name: str) -> None:
        pass


def check_digest(path: files.Target, listed: list[str] | None) -> None:
    """Refuses the file at ``path`` unless its digest is one of ``listed``."""
    fd = files.open_regular(path)
    try:
        digest = files.fd_digest(fd)
    finally:
        os.close(fd)
    if not listed or digest not in listed:
        raise RunDirError(
            f"{path} is not the file the run wrote: its digest is not the one "
            f"{layout.MANIFEST_FILE} records"
        )


def _parse(path: files.Target) -> dict[str, list[str]]:
    data = json.loads(files.read_bytes(path, MAX_BYTES).decode(errors="replace") or "null")
    listed = data.get("files") if isinstance(data, dict) else None
    if (
        data.get("format") != FORMAT
        or not isinstance(listed, dict)
        or not all(
            isinstance(v, list) and all(isinstance(d, str) for d in v) for v in listed.values()
        )
    ):
        raise RunDirError(f"{path} is corrupted: not a jaxcart manifest")
    return listed


def read_manifest(run_dir: files.Where) -> dict[str, list[str]]:
    """The digests ``RUN_DIR/manifest.json`` lists, file name -> accepted digests.

    Raises:
        RunDirError: missing, a link, or not a manifest.
    """
    with files.opened(run_dir) as directory:
        path = directory / layout.MANIFEST_FILE
        try:
            return _parse(path)
        except ValueError as exc:  # JSON errors (RunDirError is one too, and passes as it is)
            if isinstance(exc, RunDirError):
                raise
            raise RunDirError(f"{path} is corrupted: {str(exc)[:120]}") from None


def verify(run_dir: files.Where, name: str, info: dict | None) -> None:
    """Refuses ``RUN_DIR/name`` unless its bytes are those its manifest records; ``info``
    (the run's ``config.json``, None while that file itself is checked) says whether the run
    keeps a manifest. A run from before manifests gets an :class:`UnverifiedRunWarning`.

    Raises:
        RunDirError: the manifest is missing or broken, or the file is not listed or differs.
    """
    with files.opened(run_dir) as directory:
        manifest_path = directory / layout.MANIFEST_FILE
        if info is not None and not info.get(FLAG) and not files.present(manifest_path):
            warnings.warn(
                f"{directory} was written before jaxcart kept a manifest: its files cannot be "
                "verified, only checked for sense",
                UnverifiedRunWarning,
                stacklevel=3,
            )
            return
        if not files.present(manifest_path):
            raise RunDirError(f"{manifest_path} is missing: the run's files cannot be verified")
        check_digest(directory / name, read_manifest(directory).get(name))
