"""Active learning of a surrogate model of Nigel's dynamics, a 1:14 car simulated in MuJoCo.

This package is the command-line interface, the only one that parses arguments or prints. Every
sub-command is a thin layer over the Python API, in a module of its own (`simulate`, `campaign`,
`compare`, `tune`, `predict`, `fidelity`, `identify`; what they share is `common`). User mistakes (bad
values, unknown names, malformed files, output paths that cannot be written) become one red line on
stderr and exit code 2; nothing is written in that case.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from activelearn.cli import campaign, compare, fidelity, identify, predict, simulate, tune
from activelearn.cli.common import EXIT_STOPPED, EXIT_USAGE, Handler, Parser, fail, one_line
from activelearn.errors import ActiveLearnError, CampaignStopped
from activelearn.terminal import interrupted
from simulator.errors import SimulatorError

__all__ = ["EXIT_STOPPED", "EXIT_USAGE", "build_parser", "fail", "main", "one_line"]

# The sub-commands in the order `activelearn --help` lists them.
COMMANDS = (simulate, campaign, compare, tune, predict, fidelity, identify)


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with every sub-command registered."""
    parser = Parser(prog="activelearn", description=__doc__.splitlines()[0],
                    epilog="`activelearn COMMAND --help` describes each command.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser, metavar="COMMAND",
                                title="commands")
    for command in COMMANDS:
        command.register(sub)
    return parser


def _nearest_key(exc: Exception) -> str:
    """'; did you mean KEY?' for a config key that does not exist but is close to one that does."""
    import difflib
    import typing

    from activelearn.errors import ConfigError

    if not isinstance(exc, ConfigError) or not exc.reason.startswith("Extra inputs"):
        return ""
    from pydantic import BaseModel

    from activelearn.config import CampaignConfig

    *sections, key = exc.field.split(".")
    schema: type[BaseModel] = CampaignConfig
    for section in sections:
        field = schema.model_fields.get(section)
        # a section's type, or the model of an optional one (`PriorConfig | None`)
        kinds = [field.annotation, *typing.get_args(field.annotation)] if field is not None else []
        models = [k for k in kinds if isinstance(k, type) and issubclass(k, BaseModel)]
        if not models:
            return ""
        schema = models[0]
    found = difflib.get_close_matches(key, list(schema.model_fields), n=1)
    return f"; did you mean {'.'.join([*sections, found[0]])}?" if found else ""


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `activelearn` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    try:
        return handler(args)
    except CampaignStopped as exc:
        fail(str(exc))
        return EXIT_STOPPED
    except (ActiveLearnError, SimulatorError) as exc:
        return fail(str(exc) + _nearest_key(exc))
    except KeyboardInterrupt:  # outside a campaign's rounds (they say what they kept): one line
        return interrupted()
