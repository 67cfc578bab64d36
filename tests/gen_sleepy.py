"""A solve route for the signal tests of ``slew generate``: it sleeps, then returns a failure."""
import time


def solve(problem, **options):
    time.sleep(float(options.get("sleep", 60.0)))
    return {"success": False, "status": 1, "message": "slept"}
