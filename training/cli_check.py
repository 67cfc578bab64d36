"""``slew check PROBLEM.json``: validate a problem file and print what it describes."""
import json
import math


def add_arguments(p):
    p.add_argument("problem", help="problem JSON file (see README, 'Problem format')")


def run(args):
    from slew_env import SlewProblem
    prob = SlewProblem.load(args.problem)
    print(repr(prob))
    print(f"slew angle: {math.degrees(prob.slew_angle):.6f} deg, time unit: {prob.time_unit:.6g}")
    print(json.dumps(prob.to_dict(), indent=2))
    return 0
