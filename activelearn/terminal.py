"""What a terminal sees of a command besides its output: its exit statuses and its red error lines.
Imports nothing heavy: the console script's entry point (`activelearn.console`) uses it before the
command line has loaded."""

from __future__ import annotations

import sys

EXIT_USAGE = 2
EXIT_STOPPED = 75  # EX_TEMPFAIL: a campaign stopped for a cause outside it; --resume continues it
EXIT_INTERRUPTED = 130  # Ctrl-C, as a shell reports a process ended by SIGINT


def red(text: str) -> str:
    return f"\033[31m{text}\033[0m" if sys.stderr.isatty() else text


def interrupted() -> int:
    """A Ctrl-C where nothing was running that could say what it kept: one red line; the exit status."""
    print(red("interrupted"), file=sys.stderr)
    return EXIT_INTERRUPTED
