#!/usr/bin/env bash
# Regenerate the committed recordings (run from the repository root: `make bags`).
# Each bag is the monitor's MCAP log of one FDI test through the in-process graph.
set -euo pipefail
R="${EHA:-.venv/bin/eha-health} record --quiet"
$R --out bags/healthy.mcap
$R --faults gm=0.6 --out bags/gm_0.6.mcap
$R --faults fsj=0.6 --out bags/fsj_0.6.mcap
$R --faults bkl=0.6 --out bags/bkl_0.6.mcap
$R --faults gm=0.4,fsj=0.6,bkl=0.4 --out bags/combined.mcap
$R --faults gm=0.4,fsj=0.6,bkl=0.4 --noise --seed 7 --out bags/combined_noisy.mcap
# Undeclared effects (issue 5): the plant had an effect the monitor lacks; the bag does not say so
# (--no-truth). Their truth lives with the tests: tests/data/undeclared.yaml.
$R --no-truth --faults gm=0.4,fsj=0.3 --effects compressibility,sensor_noise --seed 11 --out bags/undeclared_compressibility.mcap
$R --no-truth --effects sensor_delay,sensor_noise --seed 12 --out bags/undeclared_sensor_delay.mcap
$R --no-truth --faults gm=0.3,bkl=0.5 --params tests/data/null_bias.yaml --effects sensor_noise --seed 13 --out bags/undeclared_null_bias_bkl.mcap
