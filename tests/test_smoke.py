from solvers import Grid


def test_grid_areas_sum_to_one():
    assert abs(Grid((4, 5)).areas.sum() - 1.0) < 1e-12
