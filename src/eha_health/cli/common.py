"""What the commands share: the usage error, progress lines, shared options, run loading."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..identification.diagnose import DEFAULT_METHOD, METHODS
from ..identification.fitness import FITNESSES
from ..physics.params import EFFECT_NAMES, load


class UsageError(Exception):
    """Bad user input: reported in one line, exit code 2."""


def progress_line(msg: str) -> None:
    """Progress of long work, on stderr so --json output stays clean."""
    print("  " + msg, file=sys.stderr, flush=True)


def progress(args):
    """The progress printer, unless the output is JSON or --quiet."""
    return None if (getattr(args, "json", False) or getattr(args, "quiet", False)) else progress_line


def _parent() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(add_help=False)


def json_flag(help: str | None = None) -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--json", action="store_true", help=help)
    return p


def quiet_flag() -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--quiet", action="store_true")
    return p


def faults_option(default: str, help: str = "e.g. gm=0.4,fsj=0.6,bkl=0.4 (0 healthy, 1 limit)") -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--faults", default=default, help=help)
    return p


def effects_option(help: str = "plant effects: ") -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--effects", default="", help=help + ", ".join(EFFECT_NAMES))
    return p


def seed_option(default: int | None, help: str) -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--seed", type=int, default=default, help=help)
    return p


def method_option() -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD)
    return p


def fitness_option(help: str | None = None) -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--fitness", choices=tuple(FITNESSES), default="lsq", help=help)
    return p


def test_option(help: str) -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--test", type=int, help=help)
    return p


def domain_option(help: str) -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--domain-id", type=int, help=help)
    return p


def history_option() -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--history", metavar="DB", help="SQLite health history (default: $EHA_HEALTH_HISTORY, else "
                                                   "history.default_path of data/prognostics.yaml)")
    return p


def prognostics_settings_option() -> argparse.ArgumentParser:
    p = _parent()
    p.add_argument("--settings", metavar="YAML", help="prognostics settings merged over data/prognostics.yaml "
                   "(requirement limits, models, fleet prior: docs/prognostics.md section 6)")
    return p


def monitor_history_option(whose: str) -> argparse.ArgumentParser:
    """--history / --actuator of a command that runs a monitor node (none by default, unlike the
    history commands' --history)."""
    p = _parent()
    p.add_argument("--history", metavar="DB", help=f"SQLite health history {whose} appends each diagnosis to "
                                                   "(and publishes the RUL from); none by default")
    p.add_argument("--actuator", default="eha", help="actuator id of the diagnoses (history, /diagnostics)")
    p.add_argument("--settings", metavar="YAML", help="with --history: prognostics settings merged over "
                   "data/prognostics.yaml (docs/prognostics.md section 6)")
    p.add_argument("--operating-hours", type=float, metavar="H", help="with --history and one test: its operating "
                   "time in the history [h] (default: the test's simulated stamp in hours)")
    return p


def params_from(args, kind: str):
    """The parameter set of ``kind`` with --params and --effects (and --noise) applied."""
    p = load(kind, path=getattr(args, "params", None))
    effects = [e.strip() for e in (getattr(args, "effects", None) or "").split(",") if e.strip()]
    if getattr(args, "noise", False):
        effects.append("sensor_noise")
    return p.with_effect_names(effects)   # ValueError names an unknown effect


def load_test(path: Path, test_id: int | None):
    """:func:`load_run` of a test to diagnose: an MCAP bag's window (one without a measured channel's
    topic read as a record), a CSV's ``t`` and ``command`` and whichever measured columns it has (the
    diagnosis names those it lacks)."""
    return load_run(path, test_id, None if path.suffix.lower() == ".mcap" else ("t", "command"), partial=True)


def load_run(path: Path, test_id: int | None, required: tuple[str, ...] | None = None, partial: bool = False):
    """(response, truth or None, notes) from a CSV (columns ``required``, default all) or an MCAP bag
    (``partial``: :func:`~eha_health.io.bagrun.read_run`'s)."""
    from ..signals.response import Response
    if path.suffix.lower() == ".mcap":
        from ..io.bagrun import read_run, truth_values
        # fewer required channels: a measured record (e.g. a rig with command and position only)
        run = read_run(path, test_id, record=required is not None, partial=partial)
        return run.response, truth_values(run.truth), run.notes
    if test_id is not None:
        raise UsageError("--test applies to MCAP bags only")
    from ..identification.record import from_test_start
    # a logger started before the test: cut where the command shows the FDI sequence starting
    r, note = from_test_start(Response.from_csv(path, required) if required else Response.from_csv(path))
    return r, None, [note] if note else []
