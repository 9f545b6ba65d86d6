"""A command whose output's reader has left (``cso-runtime runs | head -3``, ``--help | head -1``): how it ends.
Light on imports (no numpy), as ``cli.main`` enters it before any command, ``--help`` included."""

from __future__ import annotations

import contextlib
import os
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterator
    from typing import TextIO


def reader_is_gone() -> bool:
    """Whether stdout or stderr is a pipe whose reader has closed it (``runs | head -3``: head has its lines)."""
    import select  # noqa: PLC0415

    for stream in (sys.stdout, sys.stderr):
        try:
            poller = select.poll()
            poller.register(stream.fileno(), 0)  # POLLERR and POLLHUP are always reported: a widowed pipe's write end
            if poller.poll(0):
                return True
        except (OSError, ValueError, AttributeError):  # no file descriptor (a test's captured stream), or closed
            continue
    return False


def _is_broken_pipe(exc: BaseException) -> bool:
    """A ``BrokenPipeError``, or the ``SystemExit(1)`` that typer (its ``OSError`` handler) raises in its place."""
    return isinstance(exc, BrokenPipeError) or (isinstance(exc, SystemExit) and isinstance(exc.__context__, BrokenPipeError))


def _is_richs_broken_pipe_exit(exc: BaseException) -> bool:
    """Rich's ``SystemExit(1)`` from ``Console.on_broken_pipe``: its console (typer's help: ``--help | head -1``) met a
    reader that left, and it has already sent stdout to /dev/null, so ``reader_is_gone`` can no longer see it."""
    if not isinstance(exc, SystemExit) or not isinstance(exc.__context__, BrokenPipeError):
        return False
    frame = exc.__traceback__
    while frame is not None and frame.tb_next is not None:
        frame = frame.tb_next
    return frame is not None and frame.tb_frame.f_code.co_name == "on_broken_pipe"


@contextlib.contextmanager
def ends_quietly_when_its_reader_leaves() -> Iterator[None]:
    """A command whose output's reader leaves (``cso-runtime runs | head -3``, ``eval ... | head``, ``--help | head -1``)
    ends quietly with exit code 141 (EXIT_READER_GONE, as a shell tool killed by SIGPIPE), not rich's or typer's exit 1
    or a traceback. What it was doing when the pipe broke is over (its ``finally`` blocks ran: ``eval`` has written its
    results by its last table); stdout and stderr go to /dev/null so that nothing else fails at exit. A broken pipe
    that is not the reader's (another process's) is raised as it was, and so is what the command itself raised (an
    error's traceback, Ctrl-C, a non-zero exit code), the output it left unread dropped quietly. The tables are printed by
    ``console_that_survives_its_reader`` consoles, whose broken pipe is this ``BrokenPipeError`` rather than rich's
    ``SystemExit(1)``; typer's help is printed by rich's own console, whose ``SystemExit(1)`` is recognised here."""
    try:
        try:
            yield
        except BaseException as exc:
            if _ends_well(exc):
                sys.stdout.flush()  # as below
            elif not _is_broken_pipe(exc):  # an error, Ctrl-C, an exit code: the command's own outcome, which the
                _flush_or_let_go()  # reader gone must not replace (a traceback lost, exit 141 and no word)
            raise
        sys.stdout.flush()  # a last line still in Python's buffer would break at exit, after this block (and its exit code)
    except (BrokenPipeError, SystemExit) as exc:
        if not (_is_richs_broken_pipe_exit(exc) or (_is_broken_pipe(exc) and reader_is_gone())):
            raise
        _let_go((sys.stdout, sys.stderr))
        from cso_runtime.config import EXIT_READER_GONE  # noqa: PLC0415  (numpy: only once the reader has left)

        raise SystemExit(EXIT_READER_GONE) from None


def _ends_well(exc: BaseException) -> bool:
    """Click's end of a command that went well (``SystemExit(0)``): its output's reader gone is then all there is."""
    return isinstance(exc, SystemExit) and exc.code in (0, None)


def _flush_or_let_go() -> None:
    """Flush stdout; where its reader has gone, let it go (``_let_go``) instead of raising the broken pipe."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        _let_go((sys.stdout,))
    except (OSError, ValueError, AttributeError):  # closed, or no stream: nothing to flush
        pass


def _let_go(streams: tuple[TextIO, ...]) -> None:
    """Point ``streams`` at /dev/null, so that nothing written to them (Python's flush at exit) fails any more."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    for stream in streams:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            os.dup2(devnull, stream.fileno())
    os.close(devnull)
