"""Plots of a ``SlewSolution`` (matplotlib).

Importing ``solvers`` never imports matplotlib: this module is imported on demand and
imports matplotlib inside its functions. When a ``path`` is given the figure is built on
a bare Agg canvas (no pyplot, no GUI backend, nothing left open in pyplot's registry);
without a path the figure comes from ``pyplot.figure`` so that ``plt.show()`` works.

Panels, all against time in the problem's units:

1. attitude: the quaternion components ``q0..q3`` (scalar first);
2. body rates ``ω``, with the rate limits where the problem has them;
3. torques ``u``, with the switch instants of each axis as vertical lines (for an answer
   whose control is its samples, collocation's or the eigenaxis slew's: the sign changes);
4. switching functions ``S_i = (J⁻¹ λω)_i`` with the zero line (per-axis bound:
   ``u_i = -u_max,i sign S_i``, so every crossing is a switch);
5. the Hamiltonian ``H = λqᵀ q̇ + λωᵀ ω̇`` evaluated from the dense samples with the
   environment's dynamics (``slew_env.core.dynamics.state_rhs``). In the reporting scale
   of ``SlewSolution`` (``λ0 = 1`` dropped) it is ``-1`` and constant along an extremal
   (for a penalised cone answer, ``-(1 + P + ε Σφ)``: within about ``3 ε ln 2`` of -1).

``plot_sensor_path``: the sensor's direction on the unit sphere with the keep-out cones,
the start and the target, and each cone's clearance margin over time.
"""
from __future__ import annotations

import numpy as np

AXES = ("x", "y", "z")
_AXIS_COLORS = ("tab:blue", "tab:orange", "tab:green")
_QUAT_COLORS = ("k", "tab:blue", "tab:orange", "tab:green")
PANEL_TITLES = ("attitude", "body rates", "torques", "switching functions", "Hamiltonian")


def _require_trajectory(sol):
    t = np.asarray(sol.t, dtype=float)
    if t.ndim != 1 or t.shape[0] < 2:
        raise ValueError(f"plot: this solution has no trajectory to plot "
                         f"(success={sol.success}, status={sol.status}: {sol.message})")
    if sol.problem is None:
        raise ValueError("plot: the solution carries no problem (the inertia is needed)")
    return t


def hamiltonian_along(sol) -> np.ndarray:
    """``H(t_k) = λq(t_k)ᵀ q̇(t_k) + λω(t_k)ᵀ ω̇(t_k)`` at the dense samples of ``sol``.

    ``q̇, ω̇`` come from ``slew_env.core.dynamics.state_rhs`` with the sampled torque
    ``sol.u`` and the problem's inertia (problem units). For a verified extremal this is
    ``-1`` at every sample (the reporting scale of ``SlewSolution``).
    """
    from slew_env.core.dynamics import state_rhs

    _require_trajectory(sol)
    J = np.ascontiguousarray(sol.problem.inertia, dtype=float)
    q = np.asarray(sol.q, dtype=float)
    w = np.asarray(sol.omega, dtype=float)
    u = np.asarray(sol.u, dtype=float)
    lam = np.asarray(sol.costate, dtype=float)
    H = np.empty(q.shape[0])
    for k in range(q.shape[0]):
        x = np.concatenate([q[k], w[k]])
        H[k] = float(lam[k] @ state_rhs(x, np.ascontiguousarray(u[k]), J))
    return H


def switching_functions(sol) -> np.ndarray:
    """``S(t_k) = J⁻¹ λω(t_k)`` (n, 3), in problem units."""
    _require_trajectory(sol)
    return np.asarray(sol.costate, dtype=float)[:, 4:7] / np.asarray(sol.problem.inertia, dtype=float)


def sampled_sign_changes(t, u) -> list:
    """Per axis, the instants where the sampled torque ``u`` (n, 3) changes sign, each where the
    line between the two samples around it crosses zero (a zero sample between opposite signs
    counts once)."""
    out = []
    for i in range(3):
        ts = []
        last = None                 # (t, u) of the last sample with a sign
        for k in range(len(t)):
            v = float(u[k, i])
            if v == 0.0 or not np.isfinite(v):
                continue
            if last is not None and (last[1] > 0.0) != (v > 0.0):
                t0, v0 = last
                ts.append(t0 + (t[k] - t0) * v0 / (v0 - v))
            last = (float(t[k]), v)
        out.append(np.asarray(ts))
    return out


def _new_figure(path, figsize):
    if path is None:
        import matplotlib.pyplot as plt
        return plt.figure(figsize=figsize)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig


def plot_solution(sol, path=None, dpi=120):
    """Five-panel figure of ``sol`` (see module docstring); saved as PNG to ``path`` if given.

    Returns the ``matplotlib.figure.Figure``. Raises ``ValueError`` when the solution has
    no trajectory (a failed solve that never converged).
    """
    t = _require_trajectory(sol)
    S = switching_functions(sol)
    H = hamiltonian_along(sol)
    q = np.asarray(sol.q, dtype=float)
    w = np.asarray(sol.omega, dtype=float)
    u = np.asarray(sol.u, dtype=float)
    sw = [np.asarray(s, dtype=float) for s in sol.switch_times]

    fig = _new_figure(path, (9.0, 13.0))
    axs = fig.subplots(5, 1, sharex=True)
    ax_q, ax_w, ax_u, ax_s, ax_h = axs

    for i in range(4):
        ax_q.plot(t, q[:, i], color=_QUAT_COLORS[i], label=f"q{i}")
    ax_q.set_ylabel("q")

    for i in range(3):
        ax_w.plot(t, w[:, i], color=_AXIS_COLORS[i], label=f"ω{AXES[i]}")
    ax_w.axhline(0.0, color="0.6", lw=0.6)
    prob = getattr(sol, "problem", None)
    if prob is not None and prob.rate_max is not None:
        for i in range(3):
            for sgn in (1.0, -1.0):
                ax_w.axhline(sgn * float(prob.rate_max[i]), color=_AXIS_COLORS[i], ls=":", lw=0.9,
                             label=f"rate_max {AXES[i]}" if sgn > 0 else None)
    if prob is not None and prob.rate_norm_max is not None:
        ax_w.plot(t, np.linalg.norm(w, axis=1), color="0.35", lw=0.9, label="‖ω‖")
        ax_w.axhline(float(prob.rate_norm_max), color="0.35", ls=":", lw=0.9, label="rate_norm_max")
    ax_w.set_ylabel("ω")

    for i in range(3):
        ax_u.plot(t, u[:, i], color=_AXIS_COLORS[i], label=f"u{AXES[i]}", drawstyle="default")
    # the switch instants are the control of a bang-bang answer; of an answer whose control is its
    # samples (collocation, the eigenaxis slew) they are only where the sampled torque changes sign
    bang = getattr(sol, "control_law", "") in ("bang-bang", "costate")
    if not bang and not any(len(a) for a in sw):
        # answers whose record lists none (the eigenaxis slew, penalised answers): from the samples
        sw = sampled_sign_changes(t, u)
    n_sw = 0
    for i in range(3):
        for ts in sw[i]:
            ax_u.axvline(ts, color=_AXIS_COLORS[i], ls="--" if bang else ":", lw=0.9, alpha=0.8,
                         label=(f"switch {AXES[i]}" if bang else f"sign change {AXES[i]}") if ts == sw[i][0] else None)
            n_sw += 1
    ax_u.set_ylabel("u")

    # an answer without costates (a switch-time answer with cones, or whose SLSQP iterate was not
    # a KKT point: its costates are NaN) has no switching functions or Hamiltonian to draw
    has_costates = bool(np.all(np.isfinite(S))) and bool(np.all(np.isfinite(H)))
    for i in range(3):
        ax_s.plot(t, S[:, i], color=_AXIS_COLORS[i], label=f"S{AXES[i]}")
    ax_s.axhline(0.0, color="k", lw=0.8)
    ax_s.set_ylabel("S = J⁻¹λω")

    if has_costates:
        ax_h.plot(t, H, color="tab:red", label="H")
    ax_h.axhline(-1.0, color="k", ls=":", lw=0.8, label="-1")
    ax_h.set_ylabel("H")
    if has_costates:
        lo, hi = min(float(np.min(H)), -1.0), max(float(np.max(H)), -1.0)
        pad = max(0.25, 0.1 * (hi - lo))
        ax_h.set_ylim(lo - pad, hi + pad)
        ax_h.ticklabel_format(axis="y", useOffset=False)
        dev = float(np.max(np.abs(H + 1.0)))
        ax_h.text(0.01, 0.92, f"max |H + 1| = {dev:.2e}", transform=ax_h.transAxes, va="top", fontsize=9)
    else:
        for ax in (ax_s, ax_h):
            ax.text(0.5, 0.5, f"no costates: a {sol.method or 'non-extremal'} answer is not an extremal",
                    transform=ax.transAxes, ha="center", va="center", fontsize=9, color="0.3")
    ax_h.set_xlabel("t (problem time units)")

    titles = (PANEL_TITLES[0] + " (quaternion, scalar first)", PANEL_TITLES[1],
              f"{PANEL_TITLES[2]} ({n_sw} switches)" if bang else
              f"{PANEL_TITLES[2]} ({n_sw} sign changes of the sampled torque; the control is its samples)",
              f"{PANEL_TITLES[3]} S_i = (J⁻¹λω)_i",
              f"{PANEL_TITLES[4]} λqᵀq̇ + λωᵀω̇ (≈ -1 along an extremal)")
    for ax, title in zip(axs, titles):
        ax.set_title(title, fontsize=10, loc="left")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8, ncol=4)
        ax.set_xlim(float(t[0]), float(t[-1]))
    fig.suptitle(f"tf = {sol.tf:.10g}   method = {sol.method or '?'}   success = {sol.success}", fontsize=12)
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    if path is not None:
        fig.savefig(path, dpi=dpi, format="png")
    return fig


def cone_margins_along(sol) -> np.ndarray:
    """Clearance margin (rad) of each cone at the dense samples of ``sol``: (n, n_cones)."""
    from .clearance import cone_margins

    _require_trajectory(sol)
    return cone_margins(sol.problem, sol.q)


def plot_sensor_path(sol, path=None, dpi=120):
    """The sensor's inertial direction on the unit sphere, with the keep-out cones (their
    boundary circles), the start and the target; and each cone's clearance margin over time.

    For pointing slews and slews with cones (``slew solve --plot`` writes it next to the
    main figure). Returns the ``Figure``.
    """
    from slew_env.core.cones import perpendicular_basis
    from .clearance import sensor_directions

    t = _require_trajectory(sol)
    prob = sol.problem
    d = sensor_directions(np.asarray(sol.q, dtype=float), prob.sensor_axis)
    fig = _new_figure(path, (11.0, 5.0))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    # a faint wire sphere for orientation
    lat, lon = np.meshgrid(np.linspace(-np.pi / 2, np.pi / 2, 13), np.linspace(0.0, 2 * np.pi, 25))
    ax.plot_wireframe(np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat), color="0.85", lw=0.4)
    phi = np.linspace(0.0, 2 * np.pi, 181)
    for k, c in enumerate(prob.cones):
        e1, e2 = (np.asarray(v, dtype=float) for v in perpendicular_basis(np.asarray(c.axis, dtype=float)))
        ring = (np.cos(c.half_angle) * np.asarray(c.axis)[None, :]
                + np.sin(c.half_angle) * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))
        ax.plot(ring[:, 0], ring[:, 1], ring[:, 2], color="tab:red", lw=1.2, label="keep-out cones" if k == 0 else None)
    ax.plot(d[:, 0], d[:, 1], d[:, 2], color="tab:blue", lw=1.8, label="sensor path")
    ax.scatter(*d[0], color="tab:green", s=40, label="start")
    target = (np.asarray(prob.sensor_target, dtype=float) if prob.sensor_target is not None else d[-1])
    target = target / np.linalg.norm(target)
    ax.scatter(*target, color="k", marker="x", s=60, label="target")
    ax.set_box_aspect((1, 1, 1))
    # look at the sphere from the middle of the path, so the path is seen face-on
    c = d.mean(axis=0) + target
    if np.linalg.norm(c) > 1e-9:
        c = c / np.linalg.norm(c)
        ax.view_init(elev=float(np.degrees(np.arcsin(np.clip(c[2], -1.0, 1.0)))),
                     azim=float(np.degrees(np.arctan2(c[1], c[0]))))
    # a 3-D axes' title sits among its tick labels: the figure's coordinates keep it above them
    fig.text(0.06, 0.9, "sensor direction (inertial)", fontsize=10)
    ax.legend(loc="upper left", fontsize=8)

    axm = fig.add_subplot(1, 2, 2)
    m = cone_margins_along(sol)
    for k in range(m.shape[1]):
        axm.plot(t, np.degrees(m[:, k]), label=f"cone {k + 1}")
    axm.axhline(0.0, color="k", lw=0.8)
    axm.set_xlabel("t (problem time units)")
    axm.set_ylabel("clearance margin (deg)")
    worst = sol.verification.get("cone_clearance", {}).get("value")
    note = f"certified minimum {worst:.2e} rad" if worst is not None else "no cones" if not m.shape[1] else ""
    axm.set_title(f"clearance margin  {note}", fontsize=10, loc="left")
    axm.grid(True, alpha=0.3)
    if m.shape[1]:
        axm.legend(loc="best", fontsize=8)
    fig.suptitle(f"tf = {sol.tf:.8g}   method = {sol.method or '?'}   exact = {sol.exact}", fontsize=12)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    if path is not None:
        fig.savefig(path, dpi=dpi, format="png")
    return fig
