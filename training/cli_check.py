"""``slew check PROBLEM.json``: validate a problem file and print what it describes."""
import json
import math
import sys


def add_arguments(p):
    p.add_argument("problem", help="problem JSON file (see README, 'Problem format')")


def describe(prob) -> list:
    """Summary lines of a valid problem: the slew, the rate limits and the keep-out cones."""
    lines = [repr(prob),
             f"slew angle: {math.degrees(prob.slew_angle):.6f} deg; characteristic time sqrt(J_max / u_max): "
             f"{prob.time_unit:.6g} (seconds for J in kg m² and torque in N m)"]
    if prob.rate_max is not None:
        lines.append("rate limit per axis: |ω_i| ≤ " + ", ".join(f"{math.degrees(r):.6g}" for r in prob.rate_max)
                     + " deg per unit of time (deg/s in SI units)")
    if prob.rate_norm_max is not None:
        lines.append(f"rate limit on the norm: ‖ω‖ ≤ {math.degrees(prob.rate_norm_max):.6g} deg per unit of time (deg/s in SI units)")
    for k, c in enumerate(prob.cones):
        start = math.degrees(math.acos(max(-1.0, min(1.0, float(prob.start_direction @ c.axis)))))
        end = math.degrees(math.acos(max(-1.0, min(1.0, float(prob.target_direction @ c.axis)))))
        lines.append(f"cone {k + 1}: half-angle {c.half_angle_deg:.6g} deg; the sensor starts {start - c.half_angle_deg:.6g} "
                     f"deg and ends {end - c.half_angle_deg:.6g} deg outside it")
    return lines


def run(args):
    from slew_env import SlewProblem
    prob = SlewProblem.load(args.problem)
    if prob.cones:
        # the check solve makes before any route: cones that separate start and target
        from solvers.cone_passability import check_cones_passable
        check_cones_passable(prob)
    try:
        print("\n".join(describe(prob)))
        print(json.dumps(prob.to_dict(), indent=2))
        # a pipe's stdout is block-buffered: the write that meets the closed pipe is this one,
        # not one at exit outside this try
        sys.stdout.flush()
    except BrokenPipeError:      # `slew check X.json | head`: the reader has what it wanted
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0
