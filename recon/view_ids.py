"""The kaleidoscope's nine views: their ids, where each sits in the 3×3 grid, how its image is
mirrored, and the order views are taken in.

View ids: 0 centre, 1 left, 2 right, 3 top, 4 bottom, then the corners 5 top-left, 6 top-right,
7 bottom-left, 8 bottom-right.  One convention for the whole project (the simulator's designs,
the calibration, the application), in a module that imports nothing.
"""

from __future__ import annotations

__all__ = ["VIEW_GRID", "VIEW_FLIPS", "ALL_VIEWS", "VIEW_ORDER"]

#: Grid cell (row, column) of every view id in the 3×3 layout, as seen on the sensor.
VIEW_GRID = {0: (1, 1), 1: (1, 0), 2: (1, 2), 3: (0, 1), 4: (2, 1),
             5: (0, 0), 6: (0, 2), 7: (2, 0), 8: (2, 2)}

#: Image axes (0 rows, 1 columns) that the mirrors reverse in every view, relative to the centre.
VIEW_FLIPS = {0: (), 1: (1,), 2: (1,), 3: (0,), 4: (0,), 5: (0, 1), 6: (0, 1), 7: (0, 1),
              8: (0, 1)}

ALL_VIEWS = tuple(range(9))

#: The order views are taken in: a reconstruction from *n* views uses ``VIEW_ORDER[:n]``.
VIEW_ORDER = (0, 1, 2, 3, 4, 5, 6, 7, 8)
