"""The console scripts' first module (``annotate``, ``annotator``): a Ctrl-C while the command's
modules are still being imported ends the command at once with exit code 130 and one line, instead
of a traceback; once :mod:`annotator.cli` is imported it handles interrupts itself (exit 130)."""

from __future__ import annotations

import os
import signal
import sys
from types import FrameType

EXIT_INTERRUPTED = 130  # 128 + SIGINT, as annotator.cli documents


def _interrupted_while_loading(signum: int, frame: FrameType | None) -> None:
    """Nothing has been read or written yet: say so in one line and end now."""
    sys.stderr.write("interrupted\n")
    sys.stderr.flush()
    os._exit(EXIT_INTERRUPTED)


def _run(command: str) -> object:
    try:
        signal.signal(signal.SIGINT, _interrupted_while_loading)
        from annotator import cli

        signal.signal(signal.SIGINT, signal.default_int_handler)  # the command's own handling from here
    except KeyboardInterrupt:  # it came while the handler was being put in place (Python's raised it)
        _interrupted_while_loading(signal.SIGINT, None)
    return getattr(cli, command)()


def annotate_main() -> object:
    """``annotate``: the same as ``annotator annotate``."""
    return _run("annotate_main")


def main() -> object:
    """``annotator``: every command."""
    return _run("main")
