"""Determinism (issue 18, item 6): the same recording and seed give bit-identical estimates with
1 and 2 compute threads (numba's parallel kernels), offline, in-process and over DDS.

Each thread count runs in its own process (numba fixes its thread pool at start): it diagnoses
the committed bag offline, replays it into a monitor in that process, and replays it over DDS
into a monitor process; every float is compared exactly (JSON round-trips a float exactly).
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.graph

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "bags" / "combined_noisy.mcap"

CHILD = r"""
import json, subprocess, sys
from pathlib import Path
import numba
from eha_health.identification.diagnose import diagnose
from eha_health.cli.common import load_run
from eha_health.io.bagrun import recorded_results
from eha_health.ros.replay import replay

bag, log = sys.argv[1], Path(sys.argv[2])

def same_keys(d):
    d = dict(d)
    d.pop("wall_time_s")          # the only thing allowed to differ
    return json.loads(json.dumps(d, default=float))

out = {"threads": numba.get_num_threads()}
r, _, _ = load_run(Path(bag), None)
out["offline"] = same_keys(diagnose(r, seed=0).as_dict())
out["in_process"] = same_keys(replay(bag, rate=0.0)["results"][0]["diagnosis"])
mon = subprocess.Popen([sys.executable, "-m", "eha_health.ros.monitor", "--ros-args",
                        "-p", "exit_after:=1", "-p", f"log_path:={log}"])
replay(bag, rate=0.0, with_monitor=False, wait_for_subscribers_s=600.0)   # the monitor may start slowly
mon.wait(timeout=900)
out["dds"] = same_keys(recorded_results(log)[0]["diagnosis"])
print("RESULT " + json.dumps(out))
"""


def _run(threads: int, tmp: Path) -> dict:
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads),
               OPENBLAS_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads),
               PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]))
    p = subprocess.run([sys.executable, "-c", CHILD, str(BAG), str(tmp / f"dds_{threads}.mcap")], env=env,
                       capture_output=True, text=True, timeout=1800)
    assert p.returncode == 0, p.stderr[-3000:]
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def test_same_recording_and_seed_give_bit_identical_estimates_with_1_and_2_threads(tmp_path):
    one, two = _run(1, tmp_path), _run(2, tmp_path)
    assert one["threads"] == 1 and two["threads"] == 2
    ref = one["offline"]
    assert ref["evaluations"] > 0
    for res in (one, two):
        for mode in ("offline", "in_process", "dds"):
            assert res[mode] == ref, f"{res['threads']} thread(s), {mode}: {res[mode]} != {ref}"
