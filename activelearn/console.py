"""The `activelearn` console script's entry point.

It imports nothing heavy itself, so it can catch a Ctrl-C while the command line is still importing
(pandas, MuJoCo: a command's first second) and end with the same one line and exit status as a Ctrl-C
later (`activelearn.cli.main`), not Python's traceback.
"""

from __future__ import annotations

from collections.abc import Sequence

from activelearn.terminal import interrupted


def main(argv: Sequence[str] | None = None) -> int:
    """`activelearn.cli.main`, once it has been imported."""
    try:
        from activelearn.cli import main as command_line
    except KeyboardInterrupt:
        return interrupted()
    return command_line(argv)
