"""Diagnoses of FDI tests that follow another one on the same reference plant.

    python tools/after_a_test.py [--noise] [--tests 2]

Per fault triple (5 fixed, 5 drawn with seed 5): one test from rest, then ``--tests`` more,
each after the command node's return to start and rest (``FDISequence.return_to_start``,
``settle``). Prints, for the later tests, the guard's outcome, the fit quality, the max abs
error, the monitor runs and the wall time. The figures of docs/results.md ("A test that
follows another") come from this script.
"""
import argparse

import numpy as np

from eha_health import FDISequence, Faults, load
from eha_health.identification.diagnose import diagnose
from eha_health.physics.model import Plant, response_from_rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--noise", action="store_true", help="the default sensor noise on the plant")
    ap.add_argument("--tests", type=int, default=2, help="later tests per fault triple")
    a = ap.parse_args()
    rng = np.random.default_rng(5)
    cases = [(0.3, 0.5, 0.2), (0, 0, 0), (0.1, 0.8, 0.5), (0.7, 0.2, 0.05), (0.5, 0.5, 0.9)]
    cases += [tuple(float(v) for v in np.round(rng.uniform(0, 1, 3), 3)) for _ in range(5)]
    params = load("reference").with_effect_names(["sensor_noise"] if a.noise else [])
    seq = FDISequence()
    errs, runs, times = [], [], []
    for case in cases:
        plant = Plant(params, Faults(*case), seed=1)
        t = seq.times(plant.sample_rate)
        u = seq.command(t)
        m = int(round(seq.settle / 2 * plant.sample_rate))
        for test in range(a.tests + 1):
            out = plant.step(u)
            if test:
                d = diagnose(response_from_rows(t, out, {}))
                e = float(np.abs(np.array(d.faults.as_tuple()) - case).max())
                errs.append(e), runs.append(d.evaluations), times.append(d.wall_time_s)
                print(f"{case} test {test + 1}: guard {d.guard}, fit quality {d.fit_quality:.2f}, max abs error "
                      f"{e:.4f}, {d.evaluations} runs, {d.wall_time_s:.2f} s", flush=True)
            plant.step(np.concatenate([seq.return_to_start(u[-1], m), np.full(m, u[0])]))
    print(f"later tests: max abs error {max(errs):.4f}, runs {min(runs)}-{max(runs)}, "
          f"wall time {min(times):.2f}-{max(times):.2f} s")


if __name__ == "__main__":
    main()
