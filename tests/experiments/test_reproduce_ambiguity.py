"""The held-out print of experiments/paper/reproduce_ambiguity.py: three beads of circular section with
their heights and chord widths, read back off the grid."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.paper.reproduce_ambiguity import HELD_OUT, MM, held_out_print


def test_the_held_out_beads_have_their_heights_and_widths() -> None:
    m = 512
    d = held_out_print(m) * MM
    axis = np.linspace(-MM, MM, m)
    cell = axis[1] - axis[0]
    (_, _, width_1, height_1), _, (_, _, width_3, height_3) = HELD_OUT
    column = d[:, np.argmin(np.abs(axis - 5.0))]  # x = 5 mm crosses the first bead at y = -8 mm
    near = np.abs(axis + 8.0) < 2.0
    assert column[near].max() == pytest.approx(height_1, abs=0.01)
    assert np.count_nonzero(column[near] > 0.0) * cell == pytest.approx(width_1, abs=2 * cell)
    row = d[np.argmin(np.abs(axis - 0.0))]  # y = 0 crosses the vertical bead at x = -5 mm
    across = np.abs(axis + 5.0) < 3.0
    assert row[across].max() == pytest.approx(height_3, abs=0.01)
    assert np.count_nonzero(row[across] > 0.0) * cell == pytest.approx(width_3, abs=2 * cell)
