"""The compiled kernels' on-disk cache follows every source they compile from (physics/compiled.py).

numba alone checks only the file that defines a function: an edited callee in another file
left ``kernel.run`` on its old machine code. These tests edit a copy of the package and run
it in fresh interpreters, as a user does after a ``git pull``.
"""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numba

import eha_health
from eha_health.physics.compiled import COMPILED, PACKAGE, source_digest

PROBE = """
import numba
from eha_health import Faults, load, simulate
r = simulate(params=load("monitor"), faults=Faults(0.3, 0.4, 0.3))
print(repr(float(r.position.sum())), numba.config.CACHE_DIR or "-")
"""


def test_every_cached_kernel_sits_in_a_subpackage_the_digest_covers():
    cached = [p for p in PACKAGE.rglob("*.py") if re.search(r"cache\s*=\s*True", p.read_text())]
    assert cached, "no cached kernel found: the scan is broken"
    outside = [str(p.relative_to(PACKAGE)) for p in cached if p.relative_to(PACKAGE).parts[0] not in COMPILED]
    assert not outside, f"cached numba code outside the digest's subpackages {COMPILED}: {outside}"


def test_the_package_uses_the_cache_of_its_current_sources():
    assert numba.config.CACHE_DIR, "the package did not point numba's cache anywhere"
    assert Path(numba.config.CACHE_DIR).name.endswith(source_digest())
    assert Path(eha_health.__file__).resolve().parent == PACKAGE


def _run(src: Path, cache_home: Path) -> tuple[float, str]:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(src)
    env["HOME"] = str(cache_home)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=900,
                         cwd=src)
    assert out.returncode == 0, out.stderr[-2000:]
    value, cache_dir = out.stdout.split()
    return float(value), cache_dir


def test_an_edited_callee_in_another_file_is_compiled_afresh(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(PACKAGE, src / "eha_health", ignore=shutil.ignore_patterns("__pycache__"))
    linkage = src / "eha_health" / "physics" / "linkage.py"
    original = linkage.read_text()
    before, dir_before = _run(src, tmp_path)
    # the linkage's spring force in contact halved (the probe has play): kernel.run, in kernel.py and
    # unchanged, calls it
    edited = original.replace("max(p[P_KLINK] * (d - half)", "max(0.5 * p[P_KLINK] * (d - half)")
    assert edited != original
    linkage.write_text(edited)
    after, dir_after = _run(src, tmp_path)
    assert after != before, "the edited linkage law did not reach the compiled kernel: stale cache"
    assert Path(dir_before).is_relative_to(src), "a writable copy keeps its cache inside itself"
    assert dir_after != dir_before
    assert not Path(dir_before).exists(), "the old sources' cache is left behind"
    # back to the original sources: the same result as the first run, from a fresh compile
    linkage.write_text(original)
    again, dir_again = _run(src, tmp_path)
    assert again == before and dir_again == dir_before
