"""The ``creference`` command: the parser, the error handling and the shared helpers.

Sub-commands register themselves: each module named in :data:`COMMAND_MODULES` has a
``register(subparsers)`` that adds its parser and sets ``func`` (a callable taking the parsed
arguments and returning an exit status). Invalid input exits with status 2 and a one-line message
on standard error, without a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import sys
import warnings
from importlib import resources
from pathlib import Path

from .. import __version__
from ..io.scene import SceneError, SceneWarning

__all__ = ["main", "build_parser", "example_scene_path", "seed_value", "check_output_file", "require",
           "usage_errors", "UsageError", "EXIT_INVALID", "advanced_group", "ADVANCED", "MAX_MAIN_OPTIONS"]

#: Modules that add sub-commands, in the order of the help text.
COMMAND_MODULES: list[str] = ["creference_bayes.cli.estimate", "creference_bayes.cli.plot",
                              "creference_bayes.cli.imports", "creference_bayes.cli.bench",
                              "creference_bayes.cli.batch", "creference_bayes.cli.labels",
                              "creference_bayes.cli.advise",
                              "creference_bayes.cli.confidence", "creference_bayes.cli.evaluate",
                              "creference_bayes.cli.serve"]

EXIT_INVALID = 2

#: The title of every command's second section of options: research and comparison switches and
#: settings rarely changed, listed after the everyday options in ``--help``.
ADVANCED = "advanced options"
#: At most this many options (``-h`` counted) outside the advanced section of any command's help.
MAX_MAIN_OPTIONS = 12


def advanced_group(parser: argparse.ArgumentParser, what: str = "") -> argparse._ArgumentGroup:
    """The parser's section of advanced options (created once): switches for comparisons and
    research, and settings rarely changed; ``what``: the section's description, when it is created."""
    for group in parser._action_groups:
        if group.title == ADVANCED:
            return group
    return parser.add_argument_group(ADVANCED, what or "for comparisons and research, or settings rarely "
                                                      "changed; the defaults suit most data")


class UsageError(Exception):
    """A problem with what the user asked for; reported in one line with exit status 2."""


def example_scene_path() -> Path:
    """Path of the example scene shipped with the package."""
    return Path(str(resources.files("creference_bayes") / "data" / "example_scene.json"))


def seed_value(text: str) -> int:
    """``--seed``: a non-negative integer (NumPy's seeds), else argparse's one-line error naming
    the option (exit 2)."""
    try:
        seed = int(text)
    except ValueError:
        seed = -1
    if seed < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return seed


def require(ok: bool, option: str, expected: str, value) -> None:
    """Unless ``ok``, the one-line usage error ``OPTION: expected EXPECTED, got VALUE`` (its repr)."""
    if not ok:
        raise UsageError(f"{option}: expected {expected}, got {value!r}")


@contextlib.contextmanager
def usage_errors(prefix: str = "", types=(ValueError,), one_line: bool = False):
    """The library's ``types`` errors raised in the block as usage errors: ``prefix`` and the message
    (``one_line``: its lines joined by single spaces)."""
    try:
        yield
    except types as exc:
        raise UsageError(prefix + (" ".join(str(exc).split()) if one_line else str(exc))) from None


def check_output_file(option: str, value) -> None:
    """An option naming a file to write (``--out RESULT.json``, ``--netcdf PATH``): refused,
    before any work, when it names an existing folder."""
    if value is not None and Path(value).is_dir():
        raise UsageError(f"{option}: {value} is a folder; give a file name, e.g. "
                         f"{Path(value) / ('post.nc' if option == '--netcdf' else 'result.json')}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="creference",
        description="3D locations of the annotated objects of one photo from crowd annotations "
                    "(C-Reference), with credible intervals. Start with `creference demo`; the "
                    "user guide is docs/user_guide.md.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                help="one of the commands below; `creference COMMAND --help` for its options")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from ..inference.threads import single_threaded_blas

    try:
        with warnings.catch_warnings(), single_threaded_blas():  # tiny arrays: BLAS threads only cost
            warnings.simplefilter("ignore", SceneWarning)  # reported through scene.warnings
            return int(args.func(args) or 0)
    except (SceneError, UsageError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    except BrokenPipeError:  # the output's reader went away (`creference … | head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except FileNotFoundError as exc:  # the library's own reason ("not a batch folder …") when it gave one
        reason = exc.strerror if exc.strerror and exc.strerror != os.strerror(errno.ENOENT) else "no such file"
        print(f"error: {exc.filename}: {reason}", file=sys.stderr)
        return EXIT_INVALID
    except IsADirectoryError as exc:
        print(f"error: {exc.filename}: is a folder, expected a file", file=sys.stderr)
        return EXIT_INVALID
    except OSError as exc:  # a directory, no permission, …: the user's input, not a bug
        print(f"error: {exc.filename}: {exc.strerror or exc}" if exc.filename else f"error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
