"""Helpers of the CLI tests: ``solvers.solve`` replaced by a quick failure, and the one-line error
a CLI error must be."""
import contextlib


@contextlib.contextmanager
def stub_solve(calls, message="No candidate converged. (stub)"):
    """``solvers.solve`` replaced by a quick failure that records each problem in ``calls`` (not
    the ``monkeypatch`` fixture: this project's loads every kind of compiled kernel first)."""
    import solvers
    from solvers import SlewSolution

    def solve(problem, method="auto", **options):
        calls.append(problem)
        return SlewSolution(False, 1, message, nit=0, nfev=0, wall_time=0.0, method="indirect", problem=problem)

    old = solvers.solve
    solvers.solve = solve
    try:
        yield
    finally:
        solvers.solve = old


def one_line(err):
    """The single non-blank line of ``err`` (stderr), with no traceback."""
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]
