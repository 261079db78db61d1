"""Independent fits in threads (identification/concurrency.py, the GIL-free model kernels).

* the discrepancy loop gives the same report, every float exactly, with 1 and 2 threads for its
  independent fits (screens, refits, retries), on a two-effect case that takes the retry path;
* with numba's built-in ``workqueue`` threading layer, which terminates the process when two
  threads launch a parallel batch at once, parallel batches from several threads still run and
  give what one thread gives (batches are then launched one at a time);
* results come back in the order of the inputs; a bad ``EHA_HEALTH_THREADS`` names itself.

Each thread setting runs in its own process: the environment is read there, as a user sets it.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eha_health.identification import concurrency
from eha_health.identification.concurrency import concurrently

ROOT = Path(__file__).resolve().parents[1]

LOOP = r"""
import json
from eha_health.bench.discrepancy import TWO_EFFECTS
from eha_health.discrepancy.loop import analyse_fdi_test
from eha_health.identification.concurrency import workers
from eha_health.physics.faults import Faults
from eha_health.physics.model import simulate
from eha_health.physics.params import load

names, make, alter = TWO_EFFECTS[1]          # a position skew with oil compressibility
faults = Faults(0.3, 0.4, 0.3)
r = alter(simulate(params=make(load("reference")).with_effect_names(["sensor_noise"]), faults=faults, seed=188))
d = analyse_fdi_test(r, max_effects=2, truth=faults.as_dict()).as_dict()
d.pop("wall_time_s")                         # the only thing allowed to differ
print("RESULT " + json.dumps({"workers": workers(), "report": d}, default=float))
"""

BATCHES = r"""
import json, threading
import numba, numpy as np
from eha_health.identification.concurrency import concurrently
from eha_health.physics.faults import Faults
from eha_health.physics.model import simulate_packed
from eha_health.physics.packing import pack
from eha_health.physics.params import load
from eha_health.physics.sequence import FDISequence

seq = FDISequence()
cmd = seq.command(seq.times(1000.0))
p = load("monitor")
rows = [np.stack([pack(p, Faults(0.1 * i, 0.05 * j, 0.02 * i)) for j in range(3)]) for i in range(6)]
serial = [simulate_packed(P, cmd) for P in rows]
threaded = concurrently(lambda P: simulate_packed(P, cmd), rows)
print("RESULT " + json.dumps({"layer": numba.threading_layer(),
                              "same": all(np.array_equal(a, b) for a, b in zip(serial, threaded))}))
"""


def _child(code: str, **env) -> dict:
    e = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]), **env)
    p = subprocess.run([sys.executable, "-c", code], env=e, capture_output=True, text=True, timeout=1800)
    assert p.returncode == 0, f"child exited {p.returncode}: {p.stderr[-3000:]}"
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def test_discrepancy_loop_same_report_with_one_and_two_threads():
    one = _child(LOOP, EHA_HEALTH_THREADS="1")
    two = _child(LOOP, EHA_HEALTH_THREADS="2")
    assert (one["workers"], two["workers"]) == (1, 2)
    # the case goes through screens, refits and the retry path of the second round
    assert two["report"]["selected"] == ["position_skew", "compressibility"]
    assert one["report"] == two["report"]


def test_parallel_batches_from_threads_under_the_workqueue_layer():
    res = _child(BATCHES, NUMBA_THREADING_LAYER="workqueue", EHA_HEALTH_THREADS="3")
    assert res["layer"] == "workqueue"
    assert res["same"]


def test_results_in_input_order():
    # later items finish first (smaller batches): the order is still the inputs'
    from eha_health.physics.faults import Faults
    from eha_health.physics.model import simulate_packed
    from eha_health.physics.packing import pack
    from eha_health.physics.params import load
    from eha_health.physics.sequence import FDISequence
    seq = FDISequence()
    cmd = seq.command(seq.times(1000.0))
    p = load("monitor")
    sizes = [6, 4, 1, 1, 2]
    rows = [np.stack([pack(p, Faults(0.1 * n, 0.02 * j, 0.0)) for j in range(n)]) for n in sizes]
    outs = concurrently(lambda P: simulate_packed(P, cmd), rows)
    assert [len(o) for o in outs] == sizes
    for P, o in zip(rows, outs):
        assert np.array_equal(o, simulate_packed(P, cmd))


@pytest.mark.parametrize("value", ["two", "0", "-1"])
def test_bad_thread_setting_is_named(monkeypatch, value):
    monkeypatch.setenv("EHA_HEALTH_THREADS", value)
    with pytest.raises(ValueError, match="EHA_HEALTH_THREADS"):
        concurrency.workers()
