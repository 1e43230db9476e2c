"""Ctrl-C during ``lpvflow design``: one outcome whenever it comes.

Python turns SIGINT into a KeyboardInterrupt at the next bytecode of the main thread, wherever that is.
Where Python cannot pass an exception on — a ctypes callback (measured: llvmlite's object-cache callback
while numba compiles), a finalizer (``__del__``) — it prints "Exception ignored …" with a traceback and
the run goes on; inside a C extension's import the KeyboardInterrupt becomes an ImportError. So a plain
KeyboardInterrupt can be lost or disguised. :func:`recorded` therefore also records the request (and
keeps such a dropped one off the screen); the design runner asks :func:`raise_if_requested` after every
stage and takes any exception after a request (:func:`requested`) as the interrupt: an interrupt is
never lost, the stage it came in is undone (its files removed) and the run exits with 130.
:func:`settled` ends the window before the verdict is printed: from then on Ctrl-C is ignored, so a
printed verdict always comes with the exit status it states.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


class _Request:
    """Whether SIGINT came since :func:`recorded` was entered."""

    seen = False


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    if _Request.seen:  # a second Ctrl-C while the first is being handled changes nothing
        return
    _Request.seen = True
    raise KeyboardInterrupt


@contextmanager
def recorded() -> Iterator[None]:
    """While inside, SIGINT raises KeyboardInterrupt as usual (once) and is recorded. Leaving restores the
    previous SIGINT handler and unraisable hook (in-process use, e.g. tests calling the CLI, is unaffected)
    unless a Ctrl-C came: then the process is ending with 130, a signal still pending must not raise once
    more outside, and finalizers the interrupt broke must not print tracebacks at exit."""
    previous, hook = signal.signal(signal.SIGINT, _on_sigint), sys.unraisablehook

    def quiet(unraisable: sys.UnraisableHookArgs) -> None:
        """Where Python drops an exception (a ctypes callback, a finalizer) it prints it with a traceback.
        Once a Ctrl-C came, every such exception is its consequence — our KeyboardInterrupt itself (it is
        recorded, not lost) or the finalizer of an object the interrupt left half-built (pyparsing's
        ``Forward.__del__`` after an interrupted import: "'Forward' object has no attribute 'expr'") —
        and the run is ending with 130, so it is dropped silently."""
        if not _Request.seen:
            hook(unraisable)

    _Request.seen = False
    sys.unraisablehook = quiet
    try:
        yield
    finally:
        if not _Request.seen:
            sys.unraisablehook = hook
            signal.signal(signal.SIGINT, previous)


def requested() -> bool:
    """Whether SIGINT came since :func:`recorded` was last entered: then any exception is its aftermath
    (a KeyboardInterrupt inside a C extension's import comes back as "ImportError: initialization
    failed")."""
    return _Request.seen


def raise_if_requested() -> None:
    """KeyboardInterrupt if SIGINT came since :func:`recorded` was entered (even if something swallowed
    the first one)."""
    if _Request.seen:
        raise KeyboardInterrupt


def settled() -> None:
    """The run's work is done: ignore SIGINT from now on (until :func:`recorded` exits), then raise the
    interrupt that came before, if any."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise_if_requested()
