"""The methods' colours and markers, one list for every picture of a comparison: the
precision-recall PNG (``evaluation.plot``) and the Rerun viewer's evaluation plots
(``viewer._log_eval``), so a method has the same colour in ``demo.png`` as in
``demo.rrd``.

Colour-blind-safe qualitative palettes: Okabe-Ito's eight, then four of Paul Tol's muted
ones, so the twelve first methods (the demo's ten) each have a colour of their own. Past
them a method shares a colour with an earlier one, and takes the next marker.
"""

from __future__ import annotations

#: RGB, 0-255, in the order methods are listed.
SERIES_COLORS: tuple[tuple[int, int, int], ...] = (
    (0, 114, 178),
    (230, 159, 0),
    (0, 158, 115),
    (204, 121, 167),
    (86, 180, 233),
    (213, 94, 0),
    (240, 228, 66),
    (0, 0, 0),
    (51, 34, 136),
    (153, 153, 51),
    (136, 34, 85),
    (153, 153, 153),
)

#: The markers' order, by name (each drawing side spells them its own way).
SERIES_MARKERS = ("circle", "diamond", "square", "cross", "up", "down", "asterisk")


def series_style(k: int) -> tuple[tuple[int, int, int], str]:
    """The colour and marker name of the ``k``-th method (``k`` from 0).

    >>> series_style(0), series_style(12)
    (((0, 114, 178), 'circle'), ((0, 114, 178), 'diamond'))
    """
    color = SERIES_COLORS[k % len(SERIES_COLORS)]
    return color, SERIES_MARKERS[k // len(SERIES_COLORS) % len(SERIES_MARKERS)]
