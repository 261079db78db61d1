"""Where numba keeps the compiled kernels: a cache directory named by the sources they compile from.

numba's on-disk cache (``cache=True``) is checked against the file that defines each function
only. A kernel whose callee, or a constant it reads (``layout``'s indices, frozen into the
machine code), changed in another file loads its stale machine code. Measured: with
``linkage.link_force``'s spring force halved, ``kernel.run`` kept the old law (the same output
to the last bit) until ``__pycache__`` was cleared -- after a ``git pull`` that touches one
block, a user would have run the old model without a word. So the cache lives under a
directory named by a digest of every source file of the packages that hold compiled code
(:data:`COMPILED`): a change to any of them compiles afresh (~10 s once), and the old
directories of an in-tree cache are removed.

Where: ``$NUMBA_CACHE_DIR/eha_health-<digest>`` when the user chose a cache directory, else
``__pycache__/numba/<digest>`` inside the package when it is writable, else
``~/.cache/eha_health/numba/<digest>``.
"""
from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numba

PACKAGE = Path(__file__).resolve().parent.parent

#: The subpackages whose modules hold ``@njit(cache=True)`` code (a test checks that no other does).
COMPILED = ("physics", "prognostics")


def source_digest(package: Path = PACKAGE) -> str:
    """SHA-256 (first 16 hex digits) of every ``.py`` file of the :data:`COMPILED` subpackages of
    ``package``, names and contents, in a fixed order."""
    h = hashlib.sha256()
    for sub in COMPILED:
        for f in sorted((package / sub).glob("*.py")):
            h.update(f"{sub}/{f.name}\0".encode())
            h.update(f.read_bytes())
            h.update(b"\0")
    return h.hexdigest()[:16]


def _writable(d: Path) -> bool:
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(d, os.W_OK)


def use_keyed_cache(package: Path = PACKAGE) -> Path:
    """Point numba's cache (``numba.config.CACHE_DIR``) at the directory of the current sources
    and return it. Must run before the first ``@njit(cache=True)`` decorator of the package
    (``physics/__init__`` calls it)."""
    digest = source_digest(package)
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        d = Path(user) / f"eha_health-{digest}"
    else:
        base = package / "__pycache__" / "numba"
        if _writable(base):
            # one checkout, one set of sources at a time: older digests are dead weight
            for old in base.iterdir():
                if old.is_dir() and old.name != digest:
                    shutil.rmtree(old, ignore_errors=True)
        else:
            base = Path.home() / ".cache" / "eha_health" / "numba"
        d = base / digest
    numba.config.CACHE_DIR = str(d)
    return d
