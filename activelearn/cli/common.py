"""What every command shares: one red error line and exit code 2, output paths checked before any work,
the config options of the campaign commands, and the yellow notices of a running campaign."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from activelearn.terminal import EXIT_INTERRUPTED as EXIT_INTERRUPTED
from activelearn.terminal import EXIT_STOPPED as EXIT_STOPPED
from activelearn.terminal import EXIT_USAGE as EXIT_USAGE
from activelearn.terminal import red as red

Handler = Callable[[argparse.Namespace], int]


def one_line(text: str) -> str:
    """`text` with every non-printable character escaped (line breaks and terminal controls included)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def yellow(text: str) -> str:
    return f"\033[33m{text}\033[0m" if sys.stderr.isatty() else text


def fail(message: str) -> int:
    """Print one red error line on stderr and return the usage exit code.

    Messages can quote what the user typed (a config key, a file's bytes): escaping it keeps the
    line one line and the terminal's state untouched.
    """
    print(red(f"error: {one_line(message)}"), file=sys.stderr)
    return EXIT_USAGE


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one red line and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        for action in self._actions:  # a missing sub-command: name the choices
            if isinstance(action, argparse._SubParsersAction) and message.endswith(f": {action.metavar}"):
                message += f" (one of {', '.join(action.choices)})"
        fail(message)
        raise SystemExit(EXIT_USAGE)


def output_path(
    option: str, value: str | Path, *, folder: bool = False, suffixes: Sequence[str] = ()
) -> Path:
    """`value` as the path of an output file (or `folder`), checked before any work is done.

    Rejects a wrong suffix, a file where a folder must be (the path itself or any folder above it), a
    folder where a file must be, and a place this process cannot write to.
    """
    import os

    from activelearn.errors import InputError

    path = Path(value)
    if suffixes and path.suffix.lower() not in suffixes:
        raise InputError(option, str(value), f"must end in {', '.join(suffixes)}")
    if path.exists() and path.is_dir() != folder:
        raise InputError(option, str(value), "is a folder" if path.is_dir() else "is a file, not a folder")
    parent = path if folder else path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(option, str(value), f"{parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(option, str(value), f"cannot write in {parent}")
    return path


def print_table(
    header: Sequence[str], lines: Sequence[Sequence[str]], *, left: int = 0, indent: str = ""
) -> None:
    """Columns right-aligned under their headers (the first `left` columns left-aligned), two spaces apart."""
    widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(header)]
    for line in (header, *lines):
        print(indent + "  ".join(c.ljust(w) if i < left else c.rjust(w)
                                 for i, (c, w) in enumerate(zip(line, widths, strict=True))))  # fmt: skip


PLOT_SUFFIXES = (".png", ".pdf", ".svg")
CACHE_NOTE = ("simulated maneuvers are cached in the config's output_dir/cache (default ./runs/cache), "
              "whatever --out says, or in $ACTIVELEARN_CACHE_DIR when set")


def add_config_options(p: argparse.ArgumentParser, out_default: str) -> None:
    p.add_argument("config", metavar="CONFIG",
                   help="campaign config (TOML), e.g. experiments/configs/skidpad.toml")
    p.add_argument("--tracking-uri", default=None, metavar="URI",
                   help="MLflow tracking URI (default: the config's, sqlite:///mlruns/mlflow.db)")
    p.add_argument("--no-tracking", action="store_true", help="do not log to MLflow")
    p.add_argument("--params", default=None, metavar="TOML",
                   help="[model]/[training] overrides, e.g. runs/tuning/<study>/best.toml written by "
                        "`activelearn tune`")
    p.add_argument("--out", default=None, metavar="DIR",
                   help=f"output directory (default {out_default}, <output_dir> being the config's, "
                        f"default runs); {CACHE_NOTE}")
    p.add_argument("--resume", action="store_true",
                   help="continue the stopped run in --out (an error if it holds none)")
    add_wait(p)


def add_wait(p: argparse.ArgumentParser) -> None:
    p.add_argument("--wait", type=float, default=120.0, metavar="S",
                   help="seconds to wait while another command writes the same campaign (default 120)")


def notice(event: dict) -> bool:
    """Print a campaign's notices (another writer holds its lock; the tracking server went away or is
    back) as one yellow line on stderr; False for any other event."""
    if event["event"] == "lock_wait":
        text = (f"{event['directory']} is being written by {event['holder']}; "
                f"waiting up to {event['wait']:g} s")
    elif event["event"] in ("tracking_down", "tracking_back"):
        text = event["message"]
    else:
        return False
    print(yellow(f"warning: {one_line(text)}"), file=sys.stderr)
    return True


def ui_hint(uri: str) -> str:
    """Where to look at the runs: a tracking server's own address, else `mlflow ui` on the store."""
    if uri.startswith(("http://", "https://")):
        return f"open {uri} in a browser"
    return f"mlflow ui --backend-store-uri {uri}"


def load_campaign_config(args: argparse.Namespace, **overrides: object):
    from activelearn.config import load_config

    if args.tracking_uri is not None:
        overrides["tracking"] = {"uri": args.tracking_uri}
    return load_config(args.config, params=args.params, overrides=overrides)

