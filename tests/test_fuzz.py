"""Fuzzing of every reader of untrusted input (issue 18, item 5): a bounded number of
property-based cases per target here; thousands with ``eha-health bench fuzz``.

Each case is handled or refused with the reader's documented one-line error; never another
exception, a case over 5 s or a memory blow-up (see :mod:`eha_health.bench.fuzz`). Other seeds:
``EHA_FUZZ_SEED=7 pytest tests/test_fuzz.py``; a failure names the seed and the command to replay.
"""
import os

import pytest

pytest.importorskip("hypothesis")

from eha_health.bench.fuzz import TARGETS, fuzz_target  # noqa: E402

SEED = int(os.environ.get("EHA_FUZZ_SEED", "0"))
EXAMPLES = int(os.environ.get("EHA_FUZZ_EXAMPLES", "60"))


@pytest.mark.parametrize("target", list(TARGETS))
def test_fuzzed_inputs_are_handled_or_refused_with_the_documented_error(target):
    res = fuzz_target(target, EXAMPLES, SEED)
    assert res["failure"] is None, f"{res['failure']}\nor: EHA_FUZZ_SEED={SEED} pytest tests/test_fuzz.py -k {target}"
    assert res["cases"] == EXAMPLES
    assert res["refused"] > 0 or target == "messages"       # the generators do reach the refusals
    assert res["handled"] > 0                                # ... and inputs that are taken in


def test_a_failing_case_names_its_seed_and_the_command_to_replay(monkeypatch):
    from eha_health.bench import fuzz
    monkeypatch.setattr(fuzz.CsvTarget, "check", lambda self, case, tally: (_ for _ in ()).throw(
        AssertionError("planted failure")))
    res = fuzz_target("csv", 5, 1234)
    assert "planted failure" in res["failure"]
    assert "--target csv --seed 1234" in res["failure"]
