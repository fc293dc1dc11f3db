"""Plane geometry for the motion area: a polygon's area and whether a point lies inside it."""

from __future__ import annotations

from collections.abc import Sequence

Polygon = Sequence[tuple[float, float]]
EPS = 1e-9


def area(polygon: Polygon) -> float:
    """Absolute area (shoelace formula); 0 for collinear or repeated corners."""
    total = 0.0
    n = len(polygon)
    for i in range(n):
        x1, y1 = polygon[i]
        x2, y2 = polygon[(i + 1) % n]
        total += x1 * y2 - x2 * y1
    return abs(total) / 2.0


def _on_segment(px: float, py: float, a: tuple[float, float], b: tuple[float, float]) -> bool:
    (ax, ay), (bx, by) = a, b
    cross = (bx - ax) * (py - ay) - (by - ay) * (px - ax)
    if abs(cross) > EPS * max(1.0, abs(bx - ax) + abs(by - ay)):
        return False
    return min(ax, bx) - EPS <= px <= max(ax, bx) + EPS and min(ay, by) - EPS <= py <= max(ay, by) + EPS


def inside(x: float, y: float, polygon: Polygon) -> bool:
    """True if (x, y) is inside the polygon or on its border (even-odd rule for the inside)."""
    n = len(polygon)
    result = False
    for i in range(n):
        a, b = polygon[i], polygon[(i + 1) % n]
        if _on_segment(x, y, a, b):
            return True
        (ax, ay), (bx, by) = a, b
        if (ay > y) != (by > y):
            cross_x = ax + (y - ay) * (bx - ax) / (by - ay)
            if x < cross_x:
                result = not result
    return result
