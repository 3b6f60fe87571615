"""Polygon geometry of an arena: area, self-crossing, signed distance to the walls.

Ground floor: the config checks an arena with it and the loop's [safety] measures clearances with it,
so neither imports the other.
"""

from __future__ import annotations

from typing import Any


def polygon_area(vertices: Any) -> float:
    """Signed area of a polygon (positive when counter-clockwise), shoelace formula."""
    import numpy as np

    xy = np.asarray(vertices, dtype=np.float64)
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _segments_cross(p1: Any, p2: Any, q1: Any, q2: Any) -> bool:
    """Whether closed segments p1-p2 and q1-q2 share a point (touching counts)."""

    def orient(a: Any, b: Any, c: Any) -> float:
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    def on(a: Any, b: Any, c: Any) -> bool:  # c on segment a-b, given collinear
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])

    d1, d2, d3, d4 = orient(q1, q2, p1), orient(q1, q2, p2), orient(p1, p2, q1), orient(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and 0 not in (d1, d2, d3, d4):
        return True
    return (
        (d1 == 0 and on(q1, q2, p1)) or (d2 == 0 and on(q1, q2, p2))
        or (d3 == 0 and on(p1, p2, q1)) or (d4 == 0 and on(p1, p2, q2))
    )  # fmt: skip


def polygon_self_crossing(vertices: Any) -> tuple[int, int] | None:
    """Indices (i, j) of two non-adjacent edges of a closed polygon that cross, or None."""
    n = len(vertices)
    edges = [(vertices[i], vertices[(i + 1) % n]) for i in range(n)]
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:  # the closing edge meets the first one at vertex 0
                continue
            if _segments_cross(*edges[i], *edges[j]):
                return i, j
    return None


def boundary_distance(vertices: Any, x: Any, y: Any) -> Any:
    """Signed distance (m) of points (x, y) to a polygon's boundary: positive inside, negative outside."""
    import numpy as np

    xy = np.asarray(vertices, dtype=np.float64)
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    nearest = np.full(np.broadcast(x, y).shape, np.inf)
    inside = np.zeros(nearest.shape, dtype=bool)
    for (ax, ay), (bx, by) in zip(xy, np.roll(xy, -1, axis=0), strict=True):
        ex, ey = bx - ax, by - ay
        t = np.clip(((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
        np.minimum(nearest, np.hypot(x - ax - t * ex, y - ay - t * ey), out=nearest)
        # even-odd rule: count edges crossed by a ray towards +x
        straddles = (ay > y) != (by > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = ax + (y - ay) * ex / np.where(ey == 0, 1.0, ey)
        inside ^= straddles & (x < x_cross)
    return np.where(inside, nearest, -nearest)


def polygon_clearance(vertices: Any, x: Any, y: Any) -> Any:
    """Like `boundary_distance` where it is >= 0, faster for a convex polygon; negative outside.

    Inside a convex polygon the distance to the boundary is the smallest distance to an edge's line,
    one multiply-add per edge and point (outside it is negative, though not the Euclidean distance).
    Other polygons take `boundary_distance`.
    """
    import numpy as np

    xy = np.asarray(vertices, dtype=np.float64)
    edges = np.roll(xy, -1, axis=0) - xy
    turns = edges[:, 0] * np.roll(edges[:, 1], -1) - edges[:, 1] * np.roll(edges[:, 0], -1)
    if not ((turns >= 0).all() or (turns <= 0).all()):
        return boundary_distance(vertices, x, y)
    inward = np.sign(polygon_area(vertices)) * np.column_stack([-edges[:, 1], edges[:, 0]])
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    offset = (inward * xy).sum(axis=1)
    clearance = None
    for (nx, ny), c in zip(inward, offset, strict=True):
        distance = nx * x + ny * y - c
        clearance = distance if clearance is None else np.minimum(clearance, distance, out=clearance)
    return clearance
