"""solvers.plotting: the five-panel figure of a SlewSolution and the Hamiltonian along it."""
import json
from pathlib import Path

import numpy as np
import pytest

from slew_env import SlewProblem

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture(scope="module")
def r3_solution():
    from solvers import solve
    prob = SlewProblem.from_dict(json.loads((EXAMPLES / "r3_seed_report_per_axis.json").read_text()))
    sol = solve(prob)
    assert sol.success, sol.message
    return sol


def test_hamiltonian_is_minus_one_along_r3(r3_solution):
    from solvers.plotting import hamiltonian_along
    H = hamiltonian_along(r3_solution)
    assert H.shape == r3_solution.t.shape
    assert np.max(np.abs(H + 1.0)) < 1e-6


def test_switching_functions_match_the_torques(r3_solution):
    """u_i = -u_max sign(S_i) wherever S_i is clearly away from zero (per-axis bound)."""
    from solvers.plotting import switching_functions
    S = switching_functions(r3_solution)
    u = r3_solution.u
    away = np.abs(S) > 1e-6 * np.max(np.abs(S))
    assert np.all(np.sign(u[away]) == -np.sign(S[away]))


def test_plot_has_five_panels_and_is_saved(r3_solution, tmp_path):
    import matplotlib.pyplot as plt
    from solvers.plotting import PANEL_TITLES, hamiltonian_along, plot_solution
    before = plt.get_fignums()
    path = tmp_path / "r3.png"
    fig = plot_solution(r3_solution, path)
    assert plt.get_fignums() == before          # saving never goes through pyplot
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    axes = fig.axes
    assert len(axes) == 5
    for ax, title in zip(axes, PANEL_TITLES):
        assert ax.get_title(loc="left").startswith(title)
    # torques panel: 3 torque curves + one vertical line per switch (5 for R3 per-axis)
    ax_u = axes[2]
    assert len(ax_u.get_lines()) == 3 + r3_solution.n_switches == 8
    # switching-function panel: 3 curves + the zero line
    assert len(axes[3].get_lines()) == 4
    # Hamiltonian panel: H and the -1 reference
    h_line = axes[4].get_lines()[0]
    np.testing.assert_allclose(h_line.get_ydata(), hamiltonian_along(r3_solution), rtol=0, atol=0)
    np.testing.assert_allclose(h_line.get_ydata(), -1.0, atol=1e-6)
    title = fig._suptitle.get_text()
    assert "tf = 2.354017" in title and "indirect" in title and "True" in title


def test_plot_without_path_uses_pyplot(r3_solution):
    import matplotlib.pyplot as plt
    from solvers.plotting import plot_solution
    fig = plot_solution(r3_solution)
    try:
        assert fig.number in plt.get_fignums()
        assert len(fig.axes) == 5
    finally:
        plt.close(fig)


def test_plot_of_a_solution_without_trajectory_is_a_value_error():
    from solvers import SlewSolution
    from solvers.plotting import plot_solution
    sol = SlewSolution(False, 1, "No candidate converged.", nit=0, nfev=0, wall_time=0.0)
    with pytest.raises(ValueError, match="no trajectory"):
        plot_solution(sol)


def test_importing_solvers_does_not_import_pyplot():
    import subprocess
    import sys
    code = "import sys, solvers; print('matplotlib.pyplot' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_sensor_path_plot_with_cones_and_its_margins(tmp_path, capsys):
    """R4 BP2 by collocation: the margins drawn are the cone's clearance (0 at the start,
    which lies on the boundary; never below the certified minimum), and ``slew solve --plot``
    writes the sensor figure next to the main one."""
    from reference_cases import melton
    from solvers import solve
    from solvers.clearance import margins
    from solvers.plotting import cone_margins_along, plot_sensor_path
    from training.cli import main

    p = melton(23.0, -70.0)
    sol = solve(p, method="collocation")
    m = cone_margins_along(sol)
    assert m.shape == (sol.t.shape[0], 1)
    assert np.allclose(m[:, 0], margins(p, sol.q))
    assert abs(m[0, 0]) < 1e-9 and m.min() >= -1e-6
    fig = plot_sensor_path(sol, tmp_path / "s.png")
    assert len(fig.axes) == 2 and (tmp_path / "s.png").read_bytes()[:4] == b"\x89PNG"
    prob_file = tmp_path / "bp2.json"
    prob_file.write_text(json.dumps(p.to_dict()))
    code = main(["solve", str(prob_file), "--method", "collocation", "--plot", str(tmp_path / "f.png")])
    assert code == 0
    assert (tmp_path / "f-sensor.png").read_bytes()[:4] == b"\x89PNG"
    assert "f-sensor.png" in capsys.readouterr().out


def test_plot_of_an_answer_without_costates(r3_solution, tmp_path):
    """A switch-time answer with cones has NaN costates (not an extremal): the figure is still
    drawn, with a note instead of switching functions and Hamiltonian (it raised before)."""
    import copy
    from solvers.plotting import plot_solution
    sol = copy.copy(r3_solution)
    sol.costate = np.full_like(r3_solution.costate, np.nan)
    sol.method = "switch-time"
    path = tmp_path / "no-costates.png"
    fig = plot_solution(sol, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert any("no costates" in t.get_text() for t in fig.axes[4].texts)
    assert len(fig.axes[4].get_lines()) == 1           # the -1 reference alone


def test_a_sampled_control_shows_sign_changes_and_the_rate_limits(tmp_path):
    """Collocation's control is its samples: the torque panel names their sign changes, not
    switches, and the rate panel draws the problem's limits (a user review, on A1)."""
    from solvers import solve
    from solvers.plotting import plot_solution
    prob = SlewProblem.from_dict(json.loads((EXAMPLES / "r3_seed_report_per_axis.json").read_text())).replace(
        rate_max=0.9, rate_norm_max=1.2)
    sol = solve(prob, method="collocation")
    assert sol.success and sol.control_law == "quadratic-samples"
    fig = plot_solution(sol, tmp_path / "c.png")
    ax_w, ax_u = fig.axes[1], fig.axes[2]
    assert "sign changes of the sampled torque" in ax_u.get_title(loc="left")
    assert "switches" not in ax_u.get_title(loc="left")
    labels = [ln.get_label() for ln in ax_w.get_lines()]
    assert {"rate_max x", "rate_max y", "rate_max z", "‖ω‖", "rate_norm_max"} <= set(labels)
    limits = [ln for ln in ax_w.get_lines() if ln.get_label() == "rate_max x"]
    assert float(np.asarray(limits[0].get_ydata())[0]) == pytest.approx(0.9)


def test_the_eigenaxis_answer_shows_the_sign_changes_of_its_samples(tmp_path):
    """The eigenaxis answer lists no switch instants: its torque panel counts the sign changes of
    its samples (a review had '0 sign changes' under a torque that reverses on every axis)."""
    from solvers import solve
    from solvers.plotting import plot_solution, sampled_sign_changes
    prob = SlewProblem.from_dict(json.loads((EXAMPLES / "r3_seed_report_per_axis.json").read_text()))
    sol = solve(prob, method="eigenaxis")
    assert sol.success and not any(len(a) for a in sol.switch_times)
    sw = sampled_sign_changes(np.asarray(sol.t), np.asarray(sol.u))
    # J = I: speed up, then brake about the eigenaxis: each axis reverses once, at tf / 2
    assert [len(a) for a in sw] == [1, 1, 1]
    np.testing.assert_allclose(np.concatenate(sw), sol.tf / 2, rtol=1e-6)
    fig = plot_solution(sol, tmp_path / "e.png")
    assert "(3 sign changes of the sampled torque" in fig.axes[2].get_title(loc="left")
    t = np.array([0.0, 1.0, 2.0, 3.0])
    u = np.array([[1.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, -2.0, 0.0], [1.0, 2.0, 0.0]])
    got = sampled_sign_changes(t, u)
    np.testing.assert_allclose(got[0], [0.5, 2.5])
    np.testing.assert_allclose(got[1], [2.0 / 3.0, 2.5])    # (the zero sample between: one change)
    assert got[2].size == 0
