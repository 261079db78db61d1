"""The layers, read from the code: imports only go down; the ROS-free layers import no ROS, MCAP or CLI.

docs/architecture.md draws the same table; this test keeps it true.
"""
import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "src" / "eha_health"
#: Layer rank of every package (and top-level module) of eha_health: a module may import its own
#: package and packages of a lower rank; peers of one rank do not import each other.
RANK = {"signals": 0, "physics": 1, "identification": 2, "discrepancy": 3, "prognostics": 3, "io": 4,
        "fleet": 5, "monitoring": 5, "ros": 6, "bench": 7, "plotting": 8, "cli": 9}
ROS_FREE = ("signals", "physics", "identification", "discrepancy", "prognostics", "monitoring")
#: Third-party roots the ROS-free layers must never import, even lazily: ROS client library and
#: message packages, the MCAP log format, and the topic contract.
FORBIDDEN = {"rclpy", "rcl_interfaces", "std_msgs", "sensor_msgs", "diagnostic_msgs", "std_srvs", "builtin_interfaces",
             "mcap", "mcap_ros2", "msg_bridge", "rosbags"}


def _modules():
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(PKG)
        yield p, rel.parts[0].removesuffix(".py") if len(rel.parts) > 1 or rel.name != "__init__.py" else ""


def _imports(path: Path):
    """(absolute module, line) of every import in the file, lazy ones included."""
    tree = ast.parse(path.read_text())
    here = ["eha_health", *path.relative_to(PKG).with_suffix("").parts]
    if here[-1] == "__init__":
        here = here[:-1]
        pkg = here
    else:
        pkg = here[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
                if not node.module:         # from . import x: x may be a module of the package
                    for a in node.names:
                        yield mod + "." + a.name, node.lineno
                    continue
                yield mod, node.lineno
            else:
                yield node.module, node.lineno


def _layer_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "eha_health" or len(parts) < 2:
        return None
    return parts[1] if parts[1] in RANK else None


def test_every_package_has_a_layer():
    tops = {p.name.removesuffix(".py") for p in PKG.iterdir()
            if (p.is_dir() and (p / "__init__.py").exists()) or (p.suffix == ".py" and p.name != "__init__.py")}
    assert tops <= set(RANK), f"not in a layer: {sorted(tops - set(RANK))}"
    flat = [p.name for p in PKG.glob("*.py") if p.name != "__init__.py"]
    assert len(flat) <= 3, f"modules left flat at the top: {flat}"


@pytest.mark.parametrize("path, layer", [(p, layer) for p, layer in _modules() if layer],
                         ids=lambda v: str(v.relative_to(PKG)) if isinstance(v, Path) else "")
def test_imports_only_go_down(path, layer):
    bad = []
    for mod, line in _imports(path):
        other = _layer_of(mod)
        if other is None or other == layer:
            continue
        if RANK[other] >= RANK[layer]:
            bad.append(f"line {line}: {layer} imports {mod} ({other}, rank {RANK[other]} >= {RANK[layer]})")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("path", [p for p, layer in _modules() if layer in ROS_FREE],
                         ids=lambda p: str(p.relative_to(PKG)))
def test_ros_free_layers_import_no_ros_mcap_or_contract(path):
    bad = [f"line {line}: {mod}" for mod, line in _imports(path) if mod.split(".")[0] in FORBIDDEN]
    assert not bad, "\n".join(bad)
