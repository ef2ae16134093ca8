"""Table geometry and the paper's 9-area criterion (MODEL.md, "Frames and the table").

All lengths in metres, in the ``table`` frame: origin at the centre of the playing surface,
z up, x from the robot's end line (x = -1.37) to the opponent's (x = +1.37), y across.
"""

import numpy as np

HALF_LENGTH = 1.37
"""Half the table length along x, m."""
HALF_WIDTH = 0.7625
"""Half the table width along y, m."""
NET_HEIGHT = 0.1525
"""Height of the net's top above the surface, m."""
NET_HALF_WIDTH = 0.9150
"""Half the net's length along y (it overhangs each side line by 15.25 cm), m."""
TABLE_HEIGHT = 0.76
"""Height of the playing surface above the floor, m."""

ZONE_LENGTH = HALF_LENGTH / 3.0
"""Length (along x) of one of the 3 x 3 areas of a half, m (0.4567)."""
ZONE_WIDTH = 2.0 * HALF_WIDTH / 3.0
"""Width (along y) of one area, m (0.5083)."""


def on_table(x, y):
    """Whether points lie on the playing surface (edges included).

    Parameters
    ----------
    x, y : float or ndarray
        Table-frame coordinates, m.

    Returns
    -------
    bool or ndarray of bool
    """
    return (np.abs(x) <= HALF_LENGTH) & (np.abs(y) <= HALF_WIDTH)


def zone_of(x, y):
    """Area (zone) and half of a table point per the 9-area criterion of MODEL.md.

    Rows are thirds of |x| in [0, 1.37] (row 0 next to the net), columns thirds of y from
    +0.7625 (column 0) to -0.7625 (column 2); zone = 3 row + col + 1.

    Parameters
    ----------
    x, y : float
        Table-frame coordinates of the point, m.

    Returns
    -------
    zone : int
        1..9, 0 off the table.
    half : int
        +1 for x > 0 (opponent), -1 for x < 0 (robot), 0 off the table.
    """
    if not (abs(x) <= HALF_LENGTH and abs(y) <= HALF_WIDTH):
        return 0, 0
    row = min(int(abs(x) / ZONE_LENGTH), 2)
    col = min(int((HALF_WIDTH - y) / ZONE_WIDTH), 2)
    half = 1 if x > 0.0 else -1
    return 3 * row + col + 1, half


def zone_centre(zone, half=1):
    """Centre of an area.

    Parameters
    ----------
    zone : int
        Area 1..9 (ValueError otherwise).
    half : int
        +1 (opponent) or -1 (robot).

    Returns
    -------
    ndarray (2,)
        (x, y) of the centre, table frame, m.
    """
    if not 1 <= int(zone) <= 9:
        raise ValueError(f'zone must be 1..9, got {zone}')
    if half not in (1, -1):
        raise ValueError(f'half must be +1 or -1, got {half}')
    row, col = divmod(int(zone) - 1, 3)
    x = half * (row + 0.5) * ZONE_LENGTH
    y = HALF_WIDTH - (col + 0.5) * ZONE_WIDTH
    return np.array([x, y])


def zone_bounds(zone, half=1):
    """Bounds of an area.

    Parameters
    ----------
    zone : int
        Area 1..9.
    half : int
        +1 (opponent) or -1 (robot).

    Returns
    -------
    tuple of float
        (x_min, x_max, y_min, y_max), table frame, m.
    """
    row, col = divmod(int(zone) - 1, 3)
    x0, x1 = row * ZONE_LENGTH, (row + 1) * ZONE_LENGTH
    if half < 0:
        x0, x1 = -x1, -x0
    y1 = HALF_WIDTH - col * ZONE_WIDTH
    return x0, x1, y1 - ZONE_WIDTH, y1


def zone_margin(x, y, zone, half=1):
    """Signed distance from a point to the nearest edge of an area.

    Parameters
    ----------
    x, y : float
        Table-frame coordinates, m.
    zone, half : int
        Area 1..9 and table half (+1 opponent, -1 robot), as for :func:`zone_bounds`.

    Returns
    -------
    float
        Distance, m: positive inside the area, negative outside.
    """
    x0, x1, y0, y1 = zone_bounds(zone, half)
    return min(x - x0, x1 - x, y - y0, y1 - y)
