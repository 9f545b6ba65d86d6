"""cso-runtime: active scene mapping with CSO (ACM MM 2024) on a LIMO robot."""

from __future__ import annotations

import sys

TYPE_CHECKING = False  # typing.TYPE_CHECKING, without importing typing before main's try
if TYPE_CHECKING:
    from typing import NoReturn


def __getattr__(name: str) -> str:
    """``__version__``, looked up when first asked for: ``importlib.metadata`` (and the email, calendar and re modules
    it imports) is not loaded by every ``import cso_runtime``, which each command, service and launcher does first,
    before any of its own code could handle a Ctrl-C (the traceback of a Ctrl-C in a command's first moments)."""
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415

    try:
        value = version("cso-runtime")
    except PackageNotFoundError:  # a source tree that was never installed
        value = "0+unknown"
    globals()["__version__"] = value
    return value


def exit_interrupted_early() -> NoReturn:
    """Ctrl-C in a command's first moments (Python importing the CLI, typer building the command), before any command
    handles it: one line and exit code 130 (``config.EXIT_INTERRUPTED``: config imports numpy, not loaded then), not a
    KeyboardInterrupt traceback."""
    sys.stderr.write("error: interrupted\n")
    raise SystemExit(130) from None


def main() -> None:
    """The ``cso-runtime`` script's entry point (``[project.scripts]``): ``cli.main``, once the CLI is imported. The
    script imports only this package (sys alone) before it calls this, so that a Ctrl-C while Python imports the CLI
    (typer, the commands' definitions: most of a command's first ~0.05 s) ends as one in the rest of the command does,
    ``exit_interrupted_early``, not in a KeyboardInterrupt traceback."""
    try:
        from cso_runtime.cli import main as cli_main  # noqa: PLC0415
    except KeyboardInterrupt:
        exit_interrupted_early()
    cli_main()
