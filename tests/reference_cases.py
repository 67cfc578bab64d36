"""Problems of ../shared/REFERENCE_CASES.md, and others, shared by several test files."""
import json
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


# pointing-cones family, seed [0, 3]: three cones, the optimal path touches the first once
TOUCH = SlewProblem.from_dict(json.loads("""{"inertia": [0.9369836444739033, 0.9162486620649626, 0.592824893402508],
 "q0": [-0.212179620021578, 0.7874395993965867, -0.2511260017789171, -0.5213966027700767],
 "sensor_target": [0.27136277312428053, -0.1059744793465666, 0.9566251382278873],
 "cones": [{"axis": [0.7353572616426709, -0.4117251266523518, -0.5382677009003024], "half_angle": 0.3879313425796854},
           {"axis": [0.8629894045386329, -0.4510996520342433, -0.22750470673953233], "half_angle": 0.2827254380309789},
           {"axis": [-0.26472544369114387, -0.021596704770949784, 0.9640819580334254], "half_angle": 0.41200134858165927}]}"""))
