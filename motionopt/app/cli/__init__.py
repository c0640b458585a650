"""The ``motionopt`` command: parses arguments and calls library code, nothing more.

Each command group lives in its own module with a ``register(subparsers)`` function
that adds its subcommands and sets ``func`` on them. Library errors are printed on
one line to stderr with a non-zero exit.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from ...bvh import BVHError

#: Modules that add subcommands; a module missing here is simply not offered.
COMMAND_MODULES = ("files", "prior", "tasks", "latent", "view", "demo", "batch")


class UserError(Exception):
    """A problem with what the user asked for, reported in one line."""


#: Errors of the user's input, printed in one line: a bad argument, file or checkpoint.
USER_ERRORS = (UserError, BVHError, FileExistsError, FileNotFoundError, KeyError, ValueError)


def frame_range(start: int, stop: int | None, n: int, path: str, min_frames: int = 1) -> slice:
    """The frames ``--start``/``--stop`` select from a clip of ``n`` frames (``path``)."""
    stop = n if stop is None else stop
    if not 0 <= start < n:
        raise UserError(f"--start {start} is outside {path}, whose frames are 0 to {n - 1}")
    if not start < stop <= n:
        raise UserError(f"--stop {stop} must be after --start {start} and at most {n} (the frame count of {path})")
    if stop - start < min_frames:
        raise UserError(f"--start and --stop leave fewer than {min_frames} frames")
    return slice(start, stop)


class _Parser(argparse.ArgumentParser):
    """Argument errors in one line on stderr (``motionopt CMD: error: ...``), exit 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="motionopt",
        description="Edit human motion by optimization, with learned motion priors.",
    )
    parser.add_argument("--version", action="version", version="motionopt 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as e:
            if e.name == f"{__name__}.{name}":
                continue
            raise
        module.register(sub)
    return parser


def add_common(p: argparse.ArgumentParser) -> None:
    """Options every command shares: --quiet and --verbose."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    g.add_argument("-v", "--verbose", action="store_true", help="print details of the work as it goes")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra and not getattr(args, "takes_task_options", False):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    if getattr(args, "takes_task_options", False):
        args.task_options = extra
    level = logging.ERROR if getattr(args, "quiet", False) else (
        logging.DEBUG if getattr(args, "verbose", False) else logging.WARNING)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    for name in ("motionopt", "priors", "problems"):
        logging.getLogger(name).setLevel(level)
    try:
        from tqdm.contrib.logging import logging_redirect_tqdm

        with logging_redirect_tqdm():  # warnings print above a progress bar, not onto its line
            return int(args.func(args) or 0)
    except USER_ERRORS as e:
        print(f"motionopt {args.command}: error: {error_message(e)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"motionopt {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into a command that stopped reading (e.g. head)
        sys.stderr.close()
        return 0


def error_message(e: Exception) -> str:
    """The one line a user error is reported with."""
    return e.args[0] if isinstance(e, KeyError) and e.args else str(e)


if __name__ == "__main__":
    sys.exit(main())
