"""Whether any path can keep the sensor out of a problem's keep-out cones (a cone set that blocks
every path, or a start or target inside a cone, is refused before any solve; ``solvers.collocation``
documents the test)."""

from __future__ import annotations

import math

import numpy as np


# ----------------------------------------------------------------------------- cone topology
def _caps_cannot_separate(cones) -> bool:
    """True when the union of the cones' closed caps certainly leaves the rest of the sphere
    connected, so no two free directions are separated (no grid needed).

    Caps narrower than a hemisphere are geodesically convex, so each non-empty intersection
    of them is contractible and the union has the homotopy type of their nerve (the nerve
    theorem). If no chain of pairwise-overlapping caps closes a loop (the overlap graph is a
    forest), the nerve has no 1-cycles, and by Alexander duality the complement of the union
    is connected. With one or two cones, or three that do not all overlap, this settles it.
    """
    if any(c.half_angle >= 0.5 * math.pi for c in cones):
        return False
    n = len(cones)
    parent = list(range(n))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i
    for i in range(n):
        for j in range(i + 1, n):
            cosang = float(np.clip(np.dot(cones[i].axis, cones[j].axis), -1.0, 1.0))
            # closed caps meet when the axes are at most α_i + α_j apart (tangency counts)
            if math.acos(cosang) <= cones[i].half_angle + cones[j].half_angle + 1e-12:
                ri, rj = root(i), root(j)
                if ri == rj:
                    return False        # a loop of overlapping caps: let the grid decide
                parent[ri] = rj
    return True


def _three_caps_separate(problem) -> "bool | None":
    """Whether three pairwise-overlapping caps, each narrower than a hemisphere, separate the
    start and target directions, exactly; ``None`` where this does not apply (the grid decides).

    By the nerve theorem the union is contractible when the three caps share a point, and then
    leaves the rest of the sphere connected; when they do not, the union is a ring and the rest
    of the sphere has two components. The geodesic triangle of the three axes has its sides
    inside the union (the arc from ``a_i`` to ``a_j`` runs through cap ``i`` up to ``α_i`` from
    ``a_i`` and the rest, at most ``α_j`` long where the caps overlap, through cap ``j``), and
    by the KKM lemma its inside is not covered when the caps share no point: one component lies
    inside the triangle and the other outside. The start and target (outside every cap) are
    separated exactly when one of them is inside the triangle.

    The caps share a point when one of the candidates does: an axis (a cap inside the other
    two), or a point where two boundary circles cross (a vertex of the intersection). A cone's
    inside is open (a margin of 0 is allowed): two tangent caps leave a way through the point
    they share, so the ring is closed only where every pair overlaps."""
    cones = problem.cones
    if len(cones) != 3 or any(c.half_angle >= 0.5 * math.pi for c in cones):
        return None
    a = [np.asarray(c.axis, float) / np.linalg.norm(c.axis) for c in cones]
    cos_a = [math.cos(c.half_angle) for c in cones]
    for i in range(3):
        for j in range(i + 1, 3):
            if float(np.linalg.norm(np.cross(a[i], a[j]))) < 1e-6:
                return None     # (nearly) the same axis: their circles' crossings are ill-conditioned
            overlap = cones[i].half_angle + cones[j].half_angle - math.acos(float(np.clip(a[i] @ a[j], -1.0, 1.0)))
            if overlap < -1e-12:
                return None     # not a loop of overlapping caps (_caps_cannot_separate's case)
            if overlap <= 1e-12:
                # tangent caps: a path through the point they share keeps a margin of 0, which is
                # allowed (a keep-out cone's inside is open), so the ring is not closed there
                return False
    vol = float(a[0] @ np.cross(a[1], a[2]))
    if abs(vol) < 1e-9:
        return None             # axes on one great circle: no proper triangle

    def inside_all(x):
        return all(float(x @ a[k]) >= cos_a[k] - 1e-12 for k in range(3))
    candidates = list(a)
    for i in range(3):
        for j in range(i + 1, 3):
            # x·a_i = cos α_i, x·a_j = cos α_j, |x| = 1: x = u + t n, u in the plane of a_i, a_j
            n = np.cross(a[i], a[j])
            nn = float(n @ n)           # = 1 - (a_i·a_j)², accurate for near axes too; ≥ 1e-12 above
            g = float(a[i] @ a[j])
            ci = (cos_a[i] - g * cos_a[j]) / nn
            cj = (cos_a[j] - g * cos_a[i]) / nn
            u = ci * a[i] + cj * a[j]
            rest = 1.0 - float(u @ u)
            if rest < 0.0:
                continue        # the circles do not cross (one cap inside the other)
            t = math.sqrt(rest / nn)
            candidates += [u + t * n, u - t * n]
    if any(inside_all(x) for x in candidates):
        return False

    def in_triangle(v):
        v = np.asarray(v, float)
        sg = math.copysign(1.0, vol)
        return (sg * float(v @ np.cross(a[0], a[1])) > 0.0 and sg * float(v @ np.cross(a[1], a[2])) > 0.0
                and sg * float(v @ np.cross(a[2], a[0])) > 0.0)
    return in_triangle(problem.start_direction) != in_triangle(problem.target_direction)


def cones_block_every_path(problem, resolution_deg=0.5):
    """True when the keep-out cones certainly separate the start and target sensor directions.

    When no loop of pairwise-overlapping cones exists (``_caps_cannot_separate``, exact for
    cones narrower than a hemisphere: one or two cones, or three that do not all overlap),
    nothing is separated and no grid is needed; three that all overlap are settled exactly
    too (``_three_caps_separate``). Otherwise (four or more cones in a loop, a cap of a
    hemisphere or more, three axes on one great circle) a flood fill on a
    latitude–longitude grid of the sphere (about 0.1 s). A cell counts as blocked only
    when it lies inside a cone by more than its own radius, so the test is optimistic: a
    gap narrower than the grid is treated as open (IPOPT then decides), and a ``True`` is
    never wrong by more than the resolution.
    """
    if not problem.cones or _caps_cannot_separate(problem.cones):
        return False
    exact = _three_caps_separate(problem)
    if exact is not None:
        return exact        # (three caps ringing a hole: exact, 30 µs instead of the grid's 0.1 s)
    # (remembered: ``solve`` asks before its clock starts, collocation again inside it)
    key = (np.asarray(problem.start_direction, float).tobytes(), np.asarray(problem.target_direction, float).tobytes(),
           tuple((np.asarray(c.axis, float).tobytes(), float(c.half_angle)) for c in problem.cones),
           float(resolution_deg))
    blocked = _SEPARATION.get(key)
    if blocked is None:
        blocked = _SEPARATION[key] = _grid_separates(problem, resolution_deg)
        for old in list(_SEPARATION)[:-256]:      # (pop: another thread may evict the same key)
            _SEPARATION.pop(old, None)
    return blocked


_SEPARATION: dict = {}


def check_cones_passable(problem) -> None:
    """``ValueError`` (field ``cones``) when the cones separate the start and target sensor
    directions (``cones_block_every_path``): an infeasible problem is an input error."""
    if problem.cones and cones_block_every_path(problem):
        raise ValueError(f"cones: the {len(problem.cones)} keep-out cone(s) separate the start and target "
                         "sensor directions: every path crosses a cone (infeasible)")


def _grid_separates(problem, resolution_deg):
    """The flood fill of ``cones_block_every_path``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    d = math.radians(resolution_deg)
    n_lat = int(math.ceil(math.pi / d))
    n_lon = int(math.ceil(2 * math.pi / d))
    lat = -0.5 * math.pi + (np.arange(n_lat) + 0.5) * math.pi / n_lat
    lon = (np.arange(n_lon) + 0.5) * 2 * math.pi / n_lon
    LA, LO = np.meshgrid(lat, lon, indexing="ij")
    P = np.stack([np.cos(LA) * np.cos(LO), np.cos(LA) * np.sin(LO), np.sin(LA)], axis=-1)
    # a bound on the cell's angular circumradius: half-diagonal with the longitude extent
    # of its wider (equator-side) edge, plus 1 %; a cell is blocked only when its centre is
    # deeper inside a cone than that, i.e. the whole cell is inside the cone. A path from
    # start to target crosses a chain of edge- or corner-adjacent cells, each holding a
    # free point and so counted free: different components prove there is no path.
    dlat = math.pi / n_lat
    wide = np.cos(np.maximum(0.0, np.abs(LA) - 0.5 * dlat))
    rad = 1.01 * 0.5 * np.hypot(dlat, 2 * math.pi / n_lon * wide) + 1e-9
    free = np.ones((n_lat, n_lon), dtype=bool)
    for c in problem.cones:
        ang = np.arccos(np.clip(P @ c.axis, -1.0, 1.0))
        free &= ang > c.half_angle - rad
    idx = np.arange(n_lat * n_lon).reshape(n_lat, n_lon)
    rows, cols = [], []

    def link(a, b, m):
        rows.append(a[m])
        cols.append(b[m])
    right = np.roll(idx, -1, axis=1)
    link(idx, right, free & np.roll(free, -1, axis=1))
    for shift in (0, 1, -1):   # down, down-right, down-left
        down = np.roll(idx[1:], shift, axis=1)
        fd = np.roll(free[1:], shift, axis=1)
        link(idx[:-1], down, free[:-1] & fd)
    # cells around each pole touch each other
    for r in (0, n_lat - 1):
        ring = idx[r][free[r]]
        if ring.size > 1:
            rows.append(ring[:-1])
            cols.append(ring[1:])
    rows = np.concatenate(rows)
    cols = np.concatenate(cols)
    G = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(idx.size, idx.size))
    _, labels = connected_components(G, directed=False)

    def cell(v):
        v = np.asarray(v, float) / np.linalg.norm(v)
        la = math.asin(max(-1.0, min(1.0, v[2])))
        lo = math.atan2(v[1], v[0]) % (2 * math.pi)
        i = min(n_lat - 1, int((la + 0.5 * math.pi) / (math.pi / n_lat)))
        j = min(n_lon - 1, int(lo / (2 * math.pi / n_lon)))
        # the start / target may sit on a cone boundary: use the nearest free cell around it
        best = None
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                ii, jj = i + di, (j + dj) % n_lon
                if 0 <= ii < n_lat and free[ii, jj]:
                    dist = float(np.linalg.norm(P[ii, jj] - v))
                    if best is None or dist < best[0]:
                        best = (dist, idx[ii, jj])
        return None if best is None else best[1]
    a = cell(problem.start_direction)
    b = cell(problem.target_direction)
    if a is None or b is None:
        return True
    return labels[a] != labels[b]
