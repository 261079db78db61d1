"""The committed recordings in bags/ decode (our reader and rosbags) and diagnose to their truth."""
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from eha_health.identification.diagnose import diagnose
from eha_health.io.bagrun import read_run

BAGS = sorted((Path(__file__).parent.parent / "bags").glob("*.mcap"))
# bags whose plant had an effect the monitor lacks, truth kept in tests/data/undeclared.yaml
UNDECLARED = [p for p in BAGS if p.stem.startswith("undeclared_")]
DECLARED = [p for p in BAGS if p not in UNDECLARED]


def test_the_documented_bags_are_there():
    names = {p.name for p in BAGS}
    assert {"healthy.mcap", "gm_0.6.mcap", "fsj_0.6.mcap", "bkl_0.6.mcap", "combined.mcap",
            "combined_noisy.mcap"} <= names
    readme = (Path(__file__).parent.parent / "bags" / "README.md").read_text()
    for n in names:
        assert f"`{n}`" in readme, f"{n} is not documented in bags/README.md"


@pytest.mark.parametrize("path", UNDECLARED, ids=lambda p: p.stem)
def test_undeclared_bags_do_not_declare(path):
    run = read_run(path)
    assert run.truth is None and not run.notes, run.notes


@pytest.mark.parametrize("path", DECLARED, ids=lambda p: p.stem)
def test_bag_diagnoses_to_its_truth(path):
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        assert sum(1 for _ in r.messages()) >= 4 * 3500 + 2
    run = read_run(path)
    assert run.truth is not None and not run.notes, run.notes
    d = diagnose(run.response)
    tol = 0.03 if "noisy" in path.stem else 0.01
    for k in ("k_gm", "k_fsj", "k_bkl"):
        assert abs(getattr(d.faults, k) - float(run.truth[k])) <= tol, (k, d.faults)
