"""Rooms-and-corridors building generator (deterministic from its parameters).

Layout (all in m), with ``c`` the corridor width and ``(w, h)`` the room size::

    outer wall: origin .. origin + (cols·w + (cols+1)·c, rows·h + (rows+1)·c)
    room (i, k): x from x0 + c + i·(w + c), y from y0 + c + k·(h + c), size w × h

Corridors run between every pair of room rows and columns and around the rooms, so corridor
centre lines are at ``x0 + c/2 + i·(w + c)`` (i = 0..cols) and ``y0 + c/2 + k·(h + c)``
(k = 0..rows). Every room wall has a door gap of ``door_width`` centred on it. An entrance on a
side of the outer wall opens the full width of the middle corridor meeting that side
(corridor index ``rows // 2`` for west/east, ``cols // 2`` for south/north).
"""
from __future__ import annotations

Segment = tuple[float, float, float, float]


def extent(b) -> tuple[float, float, float, float]:
    """(xmin, ymin, xmax, ymax) of the outer wall (m)."""
    x0, y0 = b.origin
    w, h = b.room_size
    c = b.corridor_width
    return (x0, y0, x0 + b.cols * w + (b.cols + 1) * c, y0 + b.rows * h + (b.rows + 1) * c)


def room_rect(b, col: int, row: int) -> tuple[float, float, float, float]:
    """(xmin, ymin, xmax, ymax) of room (col, row) (m)."""
    x0, y0 = b.origin
    w, h = b.room_size
    c = b.corridor_width
    x = x0 + c + col * (w + c)
    y = y0 + c + row * (h + c)
    return (x, y, x + w, y + h)


def corridor_x(b, i: int) -> float:
    """x of the centre line of vertical corridor i (0..cols) (m)."""
    return b.origin[0] + b.corridor_width / 2 + i * (b.room_size[0] + b.corridor_width)


def corridor_y(b, k: int) -> float:
    """y of the centre line of horizontal corridor k (0..rows) (m)."""
    return b.origin[1] + b.corridor_width / 2 + k * (b.room_size[1] + b.corridor_width)


def _with_gap(ax: float, ay: float, bx: float, by: float, centre: float | None, width: float) -> list[Segment]:
    """Axis-aligned wall a→b, with a gap of ``width`` centred at ``centre`` along its axis."""
    if centre is None:
        return [(ax, ay, bx, by)]
    if ay == by:  # horizontal
        lo, hi = min(ax, bx), max(ax, bx)
        return [(lo, ay, centre - width / 2, ay), (centre + width / 2, ay, hi, ay)]
    lo, hi = min(ay, by), max(ay, by)
    return [(ax, lo, ax, centre - width / 2), (ax, centre + width / 2, ax, hi)]


def wall_segments(b) -> list[Segment]:
    """Every wall segment of the building (outer wall with entrances, rooms with doors)."""
    xmin, ymin, xmax, ymax = extent(b)
    c = b.corridor_width
    segs: list[Segment] = []
    gap_y = corridor_y(b, b.rows // 2)
    gap_x = corridor_x(b, b.cols // 2)
    segs += _with_gap(xmin, ymin, xmax, ymin, gap_x if "south" in b.entrances else None, c)
    segs += _with_gap(xmin, ymax, xmax, ymax, gap_x if "north" in b.entrances else None, c)
    segs += _with_gap(xmin, ymin, xmin, ymax, gap_y if "west" in b.entrances else None, c)
    segs += _with_gap(xmax, ymin, xmax, ymax, gap_y if "east" in b.entrances else None, c)
    d = b.door_width
    for i in range(b.cols):
        for k in range(b.rows):
            x1, y1, x2, y2 = room_rect(b, i, k)
            cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
            segs += _with_gap(x1, y1, x2, y1, cx, d)
            segs += _with_gap(x1, y2, x2, y2, cx, d)
            segs += _with_gap(x1, y1, x1, y2, cy, d)
            segs += _with_gap(x2, y1, x2, y2, cy, d)
    return segs
