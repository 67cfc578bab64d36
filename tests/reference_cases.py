"""Problems of ../shared/REFERENCE_CASES.md shared by several test files."""
import math

import numpy as np

from slew_env import Cone, SlewProblem


def melton(alpha_deg, theta_deg, cone=True):
    """R4: sensor e1 starts on the cone boundary; target e1 turned by θ about the cone axis."""
    al, th = math.radians(alpha_deg), math.radians(theta_deg)
    a = np.array([math.cos(al), math.sin(al), 0.0])
    e1 = np.array([1.0, 0.0, 0.0])
    b = e1 * math.cos(th) - np.cross(e1, a) * math.sin(th) + (e1 @ a) * a * (1 - math.cos(th))
    return SlewProblem([1, 1, 1], q0=[1, 0, 0, 0], sensor_target=b, cones=[Cone(a, al)] if cone else [])
