"""ROS parameters of the nodes: one table per node (name, default, unit, range or choices, doc).

The table is the one source of truth: :func:`declare` declares each parameter with its
range in the ``ParameterDescriptor`` (``floating_point_range`` / ``integer_range``), so rclpy
itself refuses an out-of-range or NaN value, at start (``--ros-args -p``) and through the
``set_parameters`` service alike; a parameter with ``choices`` is checked by a set-parameters
callback. At start a refused value raises ``ValueError`` (one line; the console script exits 2).
A ``start_only`` parameter (read once, when the node starts) is declared ``read_only``: rclpy
refuses a change through ``set_parameters``, naming it, where a change would be accepted and do nothing.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException

#: Largest integer parameter (ROS int64, kept to what every consumer handles).
INT_MAX = 2**31 - 1


@dataclass(frozen=True)
class Param:
    """One node parameter. ``lo``/``hi`` (inclusive) bound a number; ``choices`` a string."""
    name: str
    default: Any
    doc: str
    lo: float | int | None = None
    hi: float | int | None = None
    choices: tuple[str, ...] = ()
    start_only: bool = False

    @property
    def what(self) -> str:
        return self.doc + (" (start only)" if self.start_only else "")

    def descriptor(self) -> ParameterDescriptor:
        doc = self.what
        if self.choices:
            doc += " (one of: " + ", ".join(self.choices) + ")"
        d = ParameterDescriptor(description=doc, read_only=self.start_only)
        if self.lo is not None:
            if isinstance(self.default, bool) or not isinstance(self.default, (int, float)):
                raise TypeError(f"parameter {self.name}: a range needs a numeric default")
            if isinstance(self.default, int):
                d.integer_range = [IntegerRange(from_value=int(self.lo), to_value=int(self.hi), step=0)]
            else:
                d.floating_point_range = [FloatingPointRange(from_value=float(self.lo), to_value=float(self.hi),
                                                             step=0.0)]
        return d

    def check(self, value) -> str | None:
        """Why ``value`` is refused (choices only; ranges are rclpy's), or None."""
        if self.choices and value not in self.choices:
            return f"parameter {self.name}: {value!r} is not one of {', '.join(self.choices)}"
        return None


def declare(node, params: tuple[Param, ...]) -> None:
    """Declare ``params`` on ``node`` with their ranges; refuse bad values at start and on set."""
    table = {p.name: p for p in params}
    for p in params:
        try:
            node.declare_parameter(p.name, p.default, p.descriptor())
        except ParameterException as e:   # out of range or of the wrong type, given at start
            raise ValueError(f"{node.get_name()}: parameter {p.name}: {e}") from None
        why = p.check(node.get_parameter(p.name).value)
        if why:
            raise ValueError(f"{node.get_name()}: {why}")

    def on_set(changes) -> SetParametersResult:
        for c in changes:
            why = table[c.name].check(c.value) if c.name in table else None
            if why:
                return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)
    node.add_on_set_parameters_callback(on_set)


def markdown_table(params: tuple[Param, ...]) -> str:
    """The parameter table of docs/interfaces.md (tests check the docs hold it verbatim)."""
    rows = ["| parameter | default | range | what |", "|---|---|---|---|"]
    for p in params:
        rng = f"{p.lo:.10g} .. {p.hi:.10g}" if p.lo is not None else " / ".join(p.choices) or "–"
        rows.append(f"| `{p.name}` | {p.default!r} | {rng} | {p.what} |")
    return "\n".join(rows)
