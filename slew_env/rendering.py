"""Matplotlib rendering of a slew: the sensor path on the unit sphere and time histories.

The figure is drawn off-screen with the Agg canvas (no pyplot, so no backend or
global figure state is touched). ``"human"`` mode shows the same frames in a
pygame window, as Gymnasium's classic-control environments do.
"""
from __future__ import annotations

import numpy as np

from .core import task as _t
from .core.cones import perpendicular_basis

WIDTH, HEIGHT, DPI = 960, 540, 96


def cone_circle(axis, half_angle, n=90):
    """Points (n, 3) of the circle where a cone of ``half_angle`` about ``axis`` meets the unit sphere."""
    axis = np.asarray(axis, dtype=float)
    e1, e2 = perpendicular_basis(axis)
    phi = np.linspace(0.0, 2.0 * np.pi, n)
    return (np.cos(half_angle) * axis[None, :]
            + np.sin(half_angle) * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))


class SlewRenderer:
    """Draws frames of one slew; keeps its figure between calls."""

    def __init__(self, fps: int = 20):
        from matplotlib.figure import Figure
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        self.fps = fps
        self.fig = Figure(figsize=(WIDTH / DPI, HEIGHT / DPI), dpi=DPI)
        self.canvas = FigureCanvasAgg(self.fig)
        self._window = None
        self._clock = None

    def draw(self, task: np.ndarray, history: dict) -> np.ndarray:
        """Render ``task`` (flat layout) with ``history`` arrays; return an (H, W, 3) uint8 frame.

        ``history`` holds ``time`` (n,), ``attitude_error`` (n,) rad, ``sensor``
        (n, 3) inertial sensor directions, ``rates`` (n, 3) ω·T and ``torque``
        (n, 3) u/u_max, one row per control instant.
        """
        fig = self.fig
        fig.clf()
        gs = fig.add_gridspec(3, 2, width_ratios=(1.15, 1.0), left=0.02, right=0.98,
                              top=0.93, bottom=0.09, hspace=0.35, wspace=0.18)
        ax3 = fig.add_subplot(gs[:, 0], projection="3d")
        self._draw_sphere(ax3, task, history["sensor"])
        t = history["time"]
        ax = fig.add_subplot(gs[0, 1])
        ax.plot(t, np.degrees(history["attitude_error"]), color="k", lw=1.2)
        ax.set_ylabel("error (deg)")
        ax.set_ylim(bottom=0.0)
        ax = fig.add_subplot(gs[1, 1], sharex=ax)
        for i, c in enumerate("rgb"):
            ax.plot(t, history["rates"][:, i], color=c, lw=1.0, label=f"ω{i + 1}")
        ax.set_ylabel("ω·T")
        ax.legend(loc="upper right", fontsize=7, ncol=3)
        ax = fig.add_subplot(gs[2, 1], sharex=ax)
        for i, c in enumerate("rgb"):
            # Torque is held over each control step, so draw it as a staircase.
            ax.step(t, history["torque"][:, i], where="pre", color=c, lw=1.0, label=f"u{i + 1}")
        ax.set_ylim(-1.1, 1.1)
        ax.set_ylabel("u / u_max")
        ax.set_xlabel("time")
        ax.legend(loc="upper right", fontsize=7, ncol=3)
        kind = "pointing" if task[_t.T_POINTING] > 0.5 else "full attitude"
        fig.suptitle(f"slew ({kind}, {int(task[_t.T_NCONES])} cones)  t = {t[-1]:.3g}", fontsize=10)
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[:, :, :3].copy()

    @staticmethod
    def _draw_sphere(ax, task, path):
        u = np.linspace(0.0, 2.0 * np.pi, 25)
        v = np.linspace(0.0, np.pi, 13)
        ax.plot_wireframe(np.outer(np.cos(u), np.sin(v)), np.outer(np.sin(u), np.sin(v)),
                          np.outer(np.ones_like(u), np.cos(v)), color="0.85", lw=0.4)
        for k in range(int(task[_t.T_NCONES])):
            o = _t.T_CONES + _t.CONE_STRIDE * k
            c = cone_circle(task[o:o + 3], task[o + 3])
            ax.plot(c[:, 0], c[:, 1], c[:, 2], color="tab:red", lw=1.5)
            ax.scatter(*task[o:o + 3], color="tab:red", marker="x", s=15)
        start, target = path[0], task[_t.T_TARGET:_t.T_TARGET + 3]
        ax.plot(path[:, 0], path[:, 1], path[:, 2], color="tab:blue", lw=1.8)
        ax.scatter(*start, color="tab:green", s=40, label="start")
        ax.scatter(*target, color="tab:orange", marker="*", s=110, label="target")
        ax.scatter(*path[-1], color="tab:blue", s=25, label="sensor")
        # Look at the slew from outside the sphere, above the start-target midpoint.
        mid = start + target
        if np.linalg.norm(mid) < 1e-6:
            mid = start
        mid = mid / np.linalg.norm(mid)
        ax.view_init(elev=float(np.degrees(np.arcsin(np.clip(mid[2], -1, 1)))),
                     azim=float(np.degrees(np.arctan2(mid[1], mid[0]))))
        ax.set_xlim(-1, 1)
        ax.set_ylim(-1, 1)
        ax.set_zlim(-1, 1)
        ax.set_box_aspect((1, 1, 1), zoom=1.3)
        ax.set_axis_off()
        ax.legend(loc="lower left", fontsize=7)

    def show(self, frame: np.ndarray) -> None:
        """Display ``frame`` in a pygame window (``render_mode="human"``)."""
        import pygame

        if self._window is None:
            pygame.display.init()  # display only: pygame.init() would also open audio
            pygame.display.set_caption("Slew-v0")
            self._window = pygame.display.set_mode((frame.shape[1], frame.shape[0]))
            self._clock = pygame.time.Clock()
        surf = pygame.surfarray.make_surface(np.ascontiguousarray(frame.swapaxes(0, 1)))
        self._window.blit(surf, (0, 0))
        pygame.event.pump()
        pygame.display.flip()
        self._clock.tick(self.fps)

    def close(self) -> None:
        if self._window is not None:
            import pygame
            pygame.display.quit()
            self._window = None
