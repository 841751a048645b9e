"""What the CLI's command modules share: exit codes, :class:`CliError` and argument helpers.

Below ``pliant/cli/__init__.py`` (the parser and ``main``, which import the command modules when a command
runs) and the command modules (``_run``, ``_fit``, ...), so that no command module imports the package that
imports it. Imports nothing but the standard library: ``pliant --help`` stays fast.
"""

from __future__ import annotations

import argparse

EXIT_OK, EXIT_USER, EXIT_DIVERGED, EXIT_INTERRUPTED = 0, 1, 2, 130


class CliError(Exception):
    """A user error the CLI reports as one line (``exit_code`` defaults to 1)."""

    def __init__(self, message: str, exit_code: int = EXIT_USER) -> None:
        super().__init__(message)
        self.exit_code = exit_code


def _examples(*lines: str) -> str:
    """An epilog of usage examples (shown verbatim by the raw formatter)."""
    return "examples:\n" + "\n".join(f"  {line}" for line in lines)


#: What ``ArgumentParser.add_subparsers`` returns (the command modules add their parsers to it).
Subparsers = argparse._SubParsersAction


def _sub(sub: Subparsers, name: str, help: str, *examples: str) -> argparse.ArgumentParser:
    return sub.add_parser(
        name,
        help=help,
        description=help[0].upper() + help[1:] + ".",
        epilog=_examples(*examples),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {v}")
    return v


def _workers(text: str) -> int | str:
    """``--workers``: ``auto`` or a number of processes >= 1."""
    if text == "auto":
        return text
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto or a number of processes, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected auto or a number of processes >= 1, got {v}")
    return v


WORKERS_HELP = (
    "processes evaluating each CMA-ES generation on the CPU (auto: the cores, where the fit is long enough "
    "to pay their few seconds' start; 1 on a GPU); the same results whatever the count"
)


def add_ray(parser: argparse.ArgumentParser) -> None:
    """``--ray`` and ``--address``: the CMA-ES generations on Ray actors (:mod:`pliant.fit._ray`)."""
    parser.add_argument(
        "--ray",
        action="store_true",
        help="evaluate each CMA-ES generation on Ray actors, one CPU each (pliant[ray]; --workers counts "
        "them, auto: one per CPU of the cluster); the same results",
    )
    parser.add_argument(
        "--address", help="an existing Ray cluster's address (with --ray; default: a local one)"
    )


def check_ray(args: argparse.Namespace) -> None:
    """``--address`` without ``--ray``, or ``--ray`` without Ray installed: CliError, before any work."""
    from .._extras import missing_ray

    if args.address and not args.ray:
        raise CliError("--address goes with --ray")
    why = missing_ray() if args.ray else None
    if why:
        raise CliError(why)


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return v


def add_force(parser: argparse.ArgumentParser, also: str = "") -> None:
    """``--force``: build a scene that needs more memory than is available (or more particles than the
    budget) anyway; ``also``: what else the command's ``--force`` lets through (appended to the help)."""
    parser.add_argument(
        "--force",
        action="store_true",
        help="build the scene even when its estimated memory exceeds the machine's available memory "
        "(see `pliant info SCENE`) or its particles exceed PLIANT_MAX_PARTICLES" + also,
    )
