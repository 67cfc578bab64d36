"""slew_env: rigid-body slew physics, the problem specification and the Gymnasium environment."""
from .problem import SlewProblem, Cone

__all__ = ["SlewProblem", "Cone"]
__version__ = "0.1.0"
