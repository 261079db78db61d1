"""FDI sequence, CSV format and the command-line tool (run as a real subprocess)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eha_health import FDISequence, Response, simulate
from eha_health.signals.response import CSV_COLUMNS

BIN = Path(sys.executable).parent / "eha-health"
CLI = [str(BIN)] if BIN.exists() else [sys.executable, "-m", "eha_health.cli"]


def test_sequence_matches_paper():
    s = FDISequence()
    t = s.times(1000)
    x = s.command(t)
    assert len(t) == 3500
    assert x[500] == pytest.approx(2.5e-3)             # 5 mm/s ramp
    assert x[999] == pytest.approx(4.995e-3)
    assert np.all(x[1000:1500] == 0.01)                # 10 mm step at 1 s
    assert np.all(x[1500:1800] == 0.0)                 # back at 1.5 s
    low = s.mask("sine_low", t)
    assert np.abs(x[low]).max() == pytest.approx(5e-3, rel=1e-3)
    # phase-continuous at the 2.5 -> 4 Hz switch
    assert abs(x[2500] - x[2499]) < 2 * np.pi * 4 * 5e-3 * 1e-3 * 1.5
    assert set(s.segments()) >= {"ramp", "step", "return", "sine"}


def test_sequence_rejects_bad_times():
    with pytest.raises(ValueError):
        FDISequence(step_time=2.0, return_time=1.5)


def test_csv_round_trip(tmp_path):
    r = simulate(faults=__import__("eha_health").Faults(k_gm=0.3))
    f = tmp_path / "r.csv"
    r.to_csv(f)
    back = Response.from_csv(f)
    for c in CSV_COLUMNS:
        assert np.allclose(getattr(back, c), getattr(r, c), rtol=1e-9, atol=1e-15)
    # the same file saved by a spreadsheet as "CSV UTF-8" (a byte-order mark first)
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + f.read_bytes())
    assert np.array_equal(Response.from_csv(bom).position, back.position)


@pytest.mark.parametrize("content, match", [
    ("t,command,position\n0,0,0\n0.001,0,0\n", "missing column"),
    (",".join(CSV_COLUMNS) + "\n0,0,0,0,0,0,0\n0.001,0,nan,0,0,0,0\n", "NaN"),
    (",".join(CSV_COLUMNS) + "\n0,0,0,0,0,0,0\n0.002,0,0,0,0,0,0\n0.001,0,0,0,0,0,0\n", "not strictly increasing"),
])
def test_csv_bad_input(tmp_path, content, match):
    f = tmp_path / "bad.csv"
    f.write_text(content)
    with pytest.raises(ValueError, match=match):
        Response.from_csv(f)


def _cli(*args, **kw):
    return subprocess.run([*CLI, *args], capture_output=True, text=True, env=dict(os.environ), **kw)


def test_cli_simulate_writes_columns_and_plot(tmp_path):
    out, png = tmp_path / "run.csv", tmp_path / "run.png"
    p = _cli("simulate", "--faults", "gm=0.4,fsj=0.6,bkl=0.4", "--noise", "--seed", "3",
             "--out", str(out), "--plot", str(png))
    assert p.returncode == 0, p.stderr
    header = out.read_text().splitlines()[0].split(",")
    assert header == list(CSV_COLUMNS)
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    assert data.shape == (3500, 7) and np.isfinite(data).all()
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize("args, match", [
    (["simulate", "--faults", "gm=-1", "--out", "x.csv"], "k_gm"),
    (["simulate", "--faults", "zz=1", "--out", "x.csv"], "unknown fault"),
    (["simulate", "--effects", "warp", "--out", "x.csv"], "unknown effect"),
])
def test_cli_bad_input_exits_2_with_one_line(tmp_path, args, match):
    p = _cli(*args, cwd=tmp_path)
    assert p.returncode == 2
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and match in lines[0] and "Traceback" not in p.stderr


def test_cli_signatures_writes_paper_figures(tmp_path):
    p = _cli("signatures", "--out", str(tmp_path), "--quiet")
    assert p.returncode == 0, p.stderr
    pngs = sorted(tmp_path.glob("fig*.png"))
    assert len(pngs) == 4
    th = json.loads((tmp_path / "thresholds.json").read_text())
    assert set(th["thresholds"]) == {"gm", "fsj", "bkl"}


def test_cli_bench_speed_json():
    p = _cli("bench", "speed", "--json", "--no-compile")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    for k in ("reference_realtime_factor", "monitor_realtime_factor", "batch_speedup"):
        assert r[k] > 0
