"""solvers: time-optimal slew solvers (indirect shooting, multiple shooting, continuation).

Entry point: ``solvers.solve(problem, method=..., guess=..., **options) -> SlewSolution``.
"""
from .api import METHODS, check_options, solve
from .guesses import Guess, eigenaxis_guess
from .solution import STATUS_MESSAGES, SlewSolution
from .eigenaxis import eigenaxis_slew, EigenaxisSlew
from .kernel_loading import load_kernels

__all__ = ["solve", "check_options", "METHODS", "Guess", "eigenaxis_guess", "SlewSolution", "STATUS_MESSAGES",
           "eigenaxis_slew", "EigenaxisSlew", "load_kernels"]
