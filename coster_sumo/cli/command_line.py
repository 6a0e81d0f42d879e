"""The ``coster-sumo`` command line: thin parsing, then a call into the library.

Every module in :mod:`coster_sumo.cli.commands` exposes ``register(cli: CommandLine)``, which adds its
subcommand(s) with ``set_defaults(func=...)``; ``func(args) -> int`` returns the exit code.
Nested groups (``train prior``, ``eval rollout``) come from :meth:`CommandLine.group`.

Exit codes (docs/method.md, Contracts): 0 success; 1 the work ran but some inputs failed; 2 usage or input
error before any work. Errors print as one line ``coster-sumo: error: ...``; ``--debug`` shows the
traceback.
"""

from __future__ import annotations

import argparse
import copy
import importlib
import pkgutil
import re
import sys
from collections.abc import Sequence

from coster_sumo.errors import CosterError, one_line
from coster_sumo.infra.outdir import version

# old spellings of -o/--out that still parse but are not shown (`simulate --output`, `eval prior --json`)
HIDDEN_ALIASES = ("--output", "--json")


def plain_text(text: str) -> str:
    """Help text without the reST markup of the docstrings it comes from: ``x`` -> x,
    :func:`~a.b.c` -> c, :mod:`a.b` -> a.b, a closing :: -> :."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1]
                  if m.group(0).split("`")[1].startswith("~") else m.group(1), text)
    text = re.sub(r"``([^`]+)``", r"\1", text)
    return re.sub(r"::(\s|$)", r":\1", text)


class HelpFormatter(argparse.HelpFormatter):
    """Every command's help: plain text (no reST), the hidden aliases of -o/--out left out."""

    def _format_action_invocation(self, action: argparse.Action) -> str:
        if action.option_strings:
            action = copy.copy(action)
            action.option_strings = [o for o in action.option_strings if o not in HIDDEN_ALIASES]
        return super()._format_action_invocation(action)

    def _format_text(self, text: str) -> str:
        return super()._format_text(plain_text(text))

    def _expand_help(self, action: argparse.Action) -> str:
        return plain_text(super()._expand_help(action))


class CommandLine:
    """Holds the top-level parser and lazily created command groups."""

    def __init__(self) -> None:
        self.parser = argparse.ArgumentParser(
            prog="coster-sumo", formatter_class=HelpFormatter,
            description="COSTER safety-critical scenario generation for SUMO.")
        self.parser.add_argument("--version", action="version", version=f"coster-sumo {version()}")
        _global_options(self.parser, default=False)
        self.commands = self.parser.add_subparsers(dest="command", metavar="COMMAND")
        self._groups: dict[str, argparse._SubParsersAction] = {}

    @staticmethod
    def run(argv: Sequence[str]) -> int:
        """Run one whole command line, as ``coster-sumo ARGV...`` would (a server's fork does)."""
        return main(argv)

    def group(self, name: str, help: str) -> argparse._SubParsersAction:
        """Subcommands under ``coster-sumo NAME ...`` (created on first use)."""
        if name not in self._groups:
            p = self.commands.add_parser(name, help=help)
            self._groups[name] = p.add_subparsers(dest=f"{name}_command", metavar="WHAT", required=True)
        return self._groups[name]

    def training(self, name: str, help: str, description: str, out: str, what: str) -> argparse.ArgumentParser:
        """``coster-sumo train NAME``: its parser, with the options every training takes: ``--data``
        (the dataset) and ``-o``/``--out`` (the ``what`` it writes, default ``out``)."""
        p = self.group("train", help="train a model").add_parser(name, help=help, description=description)
        p.add_argument("--data", required=True, help="dataset folder (DATASET/scenes/*.npz) or folder of .npz")
        p.add_argument("-o", "--out", "--output", dest="out", default=out, help=f"{what} to write (%(default)s)")
        return p


def _global_options(parser: argparse.ArgumentParser, default: object) -> None:
    """``--debug`` and ``--quiet``: on the top-level parser (``default`` False) and on every
    subcommand (``default`` SUPPRESS, so that ``coster-sumo run CFG --quiet`` works as well as
    ``coster-sumo --quiet run CFG`` and a subcommand does not reset what the top level set)."""
    parser.add_argument("--debug", action="store_true", default=default, help="show tracebacks")
    parser.add_argument("--quiet", "-q", action="store_true", default=default,
                        help="no progress bars (the one-line results stay)")


def _subcommands(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """Every subcommand parser under ``parser``, nested groups included."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # aliases share a parser
                found += [sub, *_subcommands(sub)]
    return found


def build_parser() -> argparse.ArgumentParser:
    import coster_sumo.cli.commands as commands

    cli = CommandLine()
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"coster_sumo.cli.commands.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(cli)
    for sub in _subcommands(cli.parser):
        _global_options(sub, default=argparse.SUPPRESS)
        sub.formatter_class = HelpFormatter
    return cli.parser


def main(argv: Sequence[str] | None = None) -> int:
    from coster_sumo.infra.procs import passive_openmp_waits

    passive_openmp_waits()  # before any command loads torch
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except CosterError as exc:
        if args.debug:
            raise
        print(f"coster-sumo: error: {one_line(str(exc))}", file=sys.stderr)
        return exc.exit_code
    except OSError as exc:  # the machine said no: a full disk, a read-only folder, a file that vanished
        if args.debug:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"coster-sumo: error: {one_line(where + (exc.strerror or str(exc)))}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("coster-sumo: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
