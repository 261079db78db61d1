"""eha_health: health monitoring of electrohydraulic servo actuators.

Physics (reference and monitor EHA models), the FDI test sequence and the fault
signatures. Nothing here imports ROS: the same code runs in a notebook, a batch
job or a node.
"""
from .physics.faults import Faults
from .physics.model import Plant, simulate, simulate_batch
from .physics.params import ModelParams, load
from .physics.sequence import FDISequence
from .signals.response import Response

__all__ = ["Faults", "FDISequence", "ModelParams", "Plant", "Response", "diagnose", "load", "simulate",
           "simulate_batch"]
__version__ = "0.1.0"


def __getattr__(name):
    # identification pulls in scipy.optimize and pymoo: loaded on first use, not with the physics
    if name == "diagnose":
        from .identification.diagnose import diagnose
        return diagnose
    raise AttributeError(f"module 'eha_health' has no attribute {name!r}")
