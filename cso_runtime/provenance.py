"""What software produced a results file (``software_provenance``): the one record that eval's ``summary.json``,
``up``'s run folder and ``train``'s ``<variant>.json`` keep, so that a table can be traced to the code that made it."""

from __future__ import annotations

import functools
import os
import platform
import shlex
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

PROVENANCE_PACKAGES = ("numpy", "torch", "mujoco")
"""The libraries whose versions a results file records (``software_provenance``): the arrays, the network, the physics."""

GIT_TIMEOUT_S = 5.0
"""How long a ``git`` call may take before the commit is left out (a results file is not worth a hang)."""

GIT_REPOSITORY_VARIABLES = ("GIT_DIR", "GIT_WORK_TREE", "GIT_INDEX_FILE", "GIT_COMMON_DIR", "GIT_OBJECT_DIRECTORY", "GIT_ALTERNATE_OBJECT_DIRECTORIES")
"""Variables that point git at another repository than the one ``-C`` names (a git hook or ``git rebase --exec`` sets
some): left out of the calls, which ask about the package's own checkout."""

_command_line: str | None = None
"""The command line this process runs (``record_command_line``); None where no command line started it (an API call)."""


def record_command_line(argv: Sequence[str]) -> None:
    """Remember ``argv`` (``cso-runtime`` and its arguments) as this process's command line: what a results file
    records as ``command_line`` (the ``cso-runtime`` script, ``python -m cso_runtime.cli`` and a detached launcher
    call it)."""
    global _command_line
    _command_line = shlex.join(argv)


def command_line() -> str | None:
    """This process's command line (``record_command_line``); None where none was recorded."""
    return _command_line


def installed_version(package: str) -> str | None:
    """The installed version of ``package`` (its distribution's metadata: nothing is imported); None when not installed."""
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415 - only when a record is written

    try:
        return version(package)
    except PackageNotFoundError:
        return None


def _git(root: Path, *args: str) -> str | None:
    """The output of ``git -C root ARGS``; None where git is missing, fails or takes too long. Read-only: without optional
    locks (``git status`` would refresh the user's index under ``.git/index.lock``, failing a ``git commit`` run
    meanwhile) and without the variables that name another repository (``GIT_REPOSITORY_VARIABLES``)."""
    env = {k: v for k, v in os.environ.items() if k not in GIT_REPOSITORY_VARIABLES} | {"GIT_OPTIONAL_LOCKS": "0"}
    try:
        done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=GIT_TIMEOUT_S, check=True, env=env)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout


@functools.cache
def git_checkout(root: Path | None = None) -> dict[str, Any] | None:
    """``git_commit`` (the checkout's HEAD) and ``git_modified`` (whether tracked files differ from it) of the source
    checkout this package runs from (``root``: the folder above the package); None where it runs from no checkout of
    its own (an installed wheel, even one in a virtual environment inside some repository), or git is absent or fails."""
    root = root or Path(__file__).resolve().parents[1]
    if not (root / ".git").exists():  # a folder in a worktree or a submodule has a .git file; site-packages has none
        return None
    top, commit = _git(root, "rev-parse", "--show-toplevel"), _git(root, "rev-parse", "HEAD")
    if top is None or commit is None or Path(top.strip()).resolve() != root.resolve():
        return None
    status = _git(root, "status", "--porcelain", "--untracked-files=no")
    return {"git_commit": commit.strip(), **({"git_modified": bool(status.strip())} if status is not None else {})}


def software_provenance() -> dict[str, Any]:
    """The software that produces a results file now: the package's ``version``, its checkout's ``git_commit`` and
    ``git_modified`` when it runs from one, the ``python`` version, the ``packages`` of ``PROVENANCE_PACKAGES``
    (null where not installed) and the ``command_line`` when a command line started the process."""
    from cso_runtime import __version__  # noqa: PLC0415 - looked up when first asked for

    record: dict[str, Any] = {"version": __version__, **(git_checkout() or {}), "python": platform.python_version()}
    record["packages"] = {name: installed_version(name) for name in PROVENANCE_PACKAGES}
    if (line := command_line()) is not None:
        record["command_line"] = line
    return record


def version_lines() -> str:
    """What ``cso-runtime --version`` prints: ``cso-runtime X.Y.Z`` (a contract: the first line stays so), then, run
    from a checkout, its commit (`` (modified)`` when tracked files differ from it)."""
    from cso_runtime import __version__  # noqa: PLC0415

    checkout = git_checkout()
    if checkout is None:
        return f"cso-runtime {__version__}"
    return f"cso-runtime {__version__}\ngit commit {checkout['git_commit']}{' (modified)' if checkout.get('git_modified') else ''}"
