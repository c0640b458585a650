"""motionopt: edit human motion by optimization with learned motion priors."""
from .bvh import BVHError, load, save
from .motion import Motion
from .skeleton import Skeleton

__all__ = ["BVHError", "Motion", "Skeleton", "load", "save"]
__version__ = "0.1.0"
