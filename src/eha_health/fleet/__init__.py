"""Fleet scale: diagnose many recorded tests on a Dask cluster into the health history.

:mod:`.recordings` (which files, whose tests: bag metadata or a manifest), :mod:`.worker`
(the once-per-worker setup and the one-recording task), :mod:`.batch` (the client: plan,
submit, write the store in time order, failures, summary). CLI: ``eha-health fleet``.
"""
from .batch import diagnose_fleet, failures_path, format_summary
from .recordings import FleetError, Recording, find_recordings, read_manifest, write_manifest

__all__ = ["FleetError", "Recording", "diagnose_fleet", "failures_path", "find_recordings", "format_summary",
           "read_manifest", "write_manifest"]
