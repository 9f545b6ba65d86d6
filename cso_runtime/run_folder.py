"""A run folder deleted while its run goes on: the files its processes still write are copied back.

The launcher and its services write their logs (``logs/<service>.log``, ``logs/launcher.log``) and a recording through
files they keep open: when the run folder (or its ``logs/``) is deleted mid-run, they go on writing to files that no
longer have a name, and everything they write is lost when they close them. On Linux each such file can still be read
through ``/proc/<pid>/fd/<fd>`` while a process holds it: ``RunFolderWatch`` finds them, copies each to the path it had
and keeps the copy up to date (``sync``, on the launcher's supervision rounds) until the run ends. Without ``/proc`` no
file is found: the launcher recreates the folder and says what is lost.
"""

from __future__ import annotations

import logging
import os
import stat
import time
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from cso_runtime.runs import LOG_DIR

log = logging.getLogger("cso.launcher")

DELETED_SUFFIX = " (deleted)"
"""What Linux appends to the target of ``/proc/<pid>/fd/<fd>`` when the file has no name any more."""

COPY_CHUNK_BYTES = 1 << 20


def nameless_files_under(folder: Path, pids: list[int]) -> dict[tuple[int, int], tuple[Path, str]]:
    """The regular files under ``folder`` (an absolute path) that the processes ``pids`` hold open and that have no name
    any more: (device, inode) -> (the path it had, a ``/proc`` path to open it by). None found without ``/proc``."""
    found: dict[tuple[int, int], tuple[Path, str]] = {}
    for pid in pids:
        fd_dir = f"/proc/{pid}/fd"
        try:
            fds = os.listdir(fd_dir)
        except OSError:  # gone, or no /proc
            continue
        for fd in fds:
            proc_path = f"{fd_dir}/{fd}"
            try:
                target = os.readlink(proc_path)
                if not target.endswith(DELETED_SUFFIX):
                    continue
                path = Path(target.removesuffix(DELETED_SUFFIX))
                if not path.is_relative_to(folder):
                    continue
                st = os.stat(proc_path)
            except OSError:  # closed meanwhile
                continue
            if stat.S_ISREG(st.st_mode):
                found.setdefault((st.st_dev, st.st_ino), (path, proc_path))
    return found


@dataclass
class RescuedFile:
    """A nameless file of the run, open for reading, and how much of it is copied to ``path``."""

    path: Path
    source: BinaryIO
    copied_bytes: int = 0


class RunFolderWatch:
    """Notices the run folder (or its ``logs/``) gone, and copies back the files the run's processes still write."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir.resolve()
        """Absolute: ``/proc`` names files by absolute paths."""
        self.rescued: dict[tuple[int, int], RescuedFile] = {}
        self.losses = 0
        """How many times the folder was found gone (``rescue``)."""
        self.read_files: list[Path] = []
        """Files of the folder that the run's processes read (its ``profile.yaml``, ``expect``): a folder deleted and
        made again by a service's start alone (its ``logs/``) is gone all the same without them."""
        self.made_again_s = -float("inf")
        """``time.monotonic()`` when the folder was last made again (``rescue``): a service started before then may
        have found no ``profile.yaml`` to read."""

    def expect(self, path: Path) -> None:
        """Count the folder as gone when ``path`` (a file the run's processes read from it) is."""
        if path not in self.read_files:
            self.read_files.append(path)

    def lost(self) -> bool:
        """Whether the run folder, its ``logs/`` or a file its processes read is gone (deleted, or moved away)."""
        return not (self.run_dir / LOG_DIR).is_dir() or not all(p.is_file() for p in self.read_files)

    def writes_nameless(self, pids: list[int]) -> bool:
        """Whether ``pids`` write a file under the folder that has no name any more: the folder was deleted after they
        opened it (a launcher's log, opened by ``up`` before the launcher ran), whatever is there now."""
        return bool(nameless_files_under(self.run_dir, pids))

    def rescue(self, pids: list[int]) -> list[Path]:
        """After the folder was found gone and made again: take each nameless file under it that ``pids`` still write,
        copy it whole to its path (earlier copies went with the folder) and keep it for ``sync``; their paths."""
        self.losses += 1
        self.made_again_s = time.monotonic()
        for key, (path, proc_path) in nameless_files_under(self.run_dir, pids).items():
            if key in self.rescued:
                continue
            try:
                source = open(proc_path, "rb")  # noqa: SIM115 - held open until ``close``: it keeps the file readable
            except OSError:
                continue
            self.rescued[key] = RescuedFile(path, source)
        for rescued in self.rescued.values():
            rescued.copied_bytes = 0
        self.sync()
        return sorted(r.path for r in self.rescued.values())

    def sync(self) -> None:
        """Copy what each rescued file got since the last copy to its path (the folders made again when gone)."""
        for rescued in self.rescued.values():
            try:
                rescued.source.seek(rescued.copied_bytes)
                chunk = rescued.source.read(COPY_CHUNK_BYTES)
                if not chunk and rescued.copied_bytes:
                    continue
                rescued.path.parent.mkdir(parents=True, exist_ok=True)
                with rescued.path.open("ab" if rescued.copied_bytes else "wb") as out:
                    while chunk:
                        out.write(chunk)
                        rescued.copied_bytes += len(chunk)
                        chunk = rescued.source.read(COPY_CHUNK_BYTES)
            except OSError as exc:  # a full disk, the folder deleted again: said, tried again on the next round
                log.warning("cannot copy back %s: %s", rescued.path, exc.strerror or exc)

    def close(self) -> None:
        """The last copies (once the run's processes have stopped), then let the nameless files go."""
        self.sync()
        for rescued in self.rescued.values():
            rescued.source.close()
        self.rescued.clear()
