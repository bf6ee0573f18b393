"""The layout of a step's views in one framebuffer (`gl_reduce.atlas`): pure arithmetic; the
passes that use it are tested with the renderer (test_gl_renderer)."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_data.sim.gl_reduce import atlas


def test_views_lie_side_by_side_and_each_reads_back_as_its_own_pixels():
    layout = atlas([(256, 144)] * 3, 16384)
    assert layout.size == (768, 144)
    assert layout.origins == ((0, 0), (256, 0), (512, 0))
    pixels = np.arange(144 * 768).reshape(144, 768)
    second = layout.view_of(pixels, 1)
    assert second.shape == (144, 256) and second[0, 0] == 256 and second[-1, -1] == 143 * 768 + 511


def test_a_row_wider_than_gl_allows_wraps_and_rows_are_as_high_as_their_highest_view():
    layout = atlas([(600, 300), (600, 200), (600, 100)], 1300)
    assert layout.origins == ((0, 0), (600, 0), (0, 300))
    assert layout.size == (1200, 400)
    assert layout.viewport(2) == (0, 300, 600, 100)


def test_views_that_cannot_fit_fail_with_their_size():
    with pytest.raises(ValueError, match="2000x100 exceeds"):
        atlas([(2000, 100)], 1024)
    with pytest.raises(ValueError, match="do not fit"):
        atlas([(1000, 600)] * 2, 1024)
