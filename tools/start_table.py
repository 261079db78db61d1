"""Write the shipped monitor's signature tables (src/eha_health/data/start_table.json).

    python tools/start_table.py

Re-run after a change to the monitor's parameters, the physics kernels or the FDI sequence:
``tests/test_identify.py::test_shipped_start_table_is_the_monitors`` fails until then (and a
stale file is only ignored, never used: its key no longer matches).
"""
import json
from pathlib import Path

from eha_health import FDISequence, load
from eha_health.identification.start import SHIPPED, StartTable, table_key

if __name__ == "__main__":
    params, seq = load("monitor"), FDISequence()
    out = Path(__file__).resolve().parents[1] / "src" / "eha_health" / "data" / SHIPPED
    out.write_text(json.dumps({"key": table_key(params, seq), **StartTable.build(params, seq).as_dict()}) + "\n")
    print(f"wrote {out}")
