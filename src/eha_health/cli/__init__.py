"""``eha-health``: the command-line entry point.

Commands by group: :mod:`.model` (simulate, calibrate, signatures), :mod:`.analysis`
(diagnose, discrepancy, import), :mod:`.graph` (demo, record, launch, replay),
:mod:`.prognostics` (history, prognose, thresholds), :mod:`.bench`, :mod:`.fleet` (fleet simulate,
fleet diagnose). Bad input exits with code 2 and one line that says what is wrong.
"""
from __future__ import annotations

import argparse
import os
import sqlite3
import sys

from . import analysis, bench, fleet, graph, model, prognostics
from .common import UsageError

GROUPS = (model, bench, analysis, graph, prognostics, fleet)


class OneLineParser(argparse.ArgumentParser):
    """An argument error is one line and exit code 2, as every other bad input (argparse prints
    the usage block first); ``--help`` still shows the usage. Subcommands inherit the class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (--help: usage)\n")


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="eha-health", description="Health monitor for electrohydraulic servo actuators")
    sub = ap.add_subparsers(dest="command", required=True)
    for g in GROUPS:
        g.register(sub)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    args.raw = list(argv) if argv is not None else sys.argv[1:]
    # the same prefix as argparse's own errors: "eha-health history repair: error: ..."
    prog = " ".join(["eha-health", args.command, *(getattr(args, f"{args.command}_command", None) or "",)]).strip()
    try:
        return args.func(args)
    except (UsageError, ValueError, FileNotFoundError) as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    except sqlite3.Error as e:   # a history file that fails under us (read-only, disk full): one line too
        print(f"{prog}: error: history database: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader stopped early (`history list | head`): nothing of ours failed, so no traceback;
        # stdout goes to devnull so that the interpreter's flush at exit does not raise again
        # (the recipe of the Python docs, "Note on SIGPIPE")
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1

