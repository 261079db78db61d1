"""The discrepancy loop: what the monitor model lacks, found from the residual of a fit.

:mod:`.candidates` (the library of missing effects), :mod:`.evidence` (projection and
held-out refit of one candidate), :mod:`.loop` (the rounds, before and after),
:mod:`.report` (evidence, states, verdict), :mod:`.settings` (thresholds and floors),
:mod:`.rig` (a measured rig: calibrate the nominal loop first). Nothing here imports ROS.
"""
