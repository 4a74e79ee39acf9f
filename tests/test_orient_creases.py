"""patchcloud.core.orient: crease links between surface patches more than 60 degrees apart, by hand."""

import numpy as np
import pytest

from patchcloud.core.orient import CREASE_AGREEMENT, LeafSet, crease_agreement, link_agreements


def sheet(centroid, e1, e3, spreads, edge=1.0):
    """One surface leaf: a sheet of points around ``centroid`` with axes e1, e3 x e1, e3 and standard deviations
    ``spreads`` along them (metres)."""
    e1, e3 = np.asarray(e1, float), np.asarray(e3, float)
    e1, e3 = e1 / np.linalg.norm(e1), e3 / np.linalg.norm(e3)
    frame = np.column_stack([e1, np.cross(e3, e1), e3])[None]
    c = np.asarray([centroid], float)
    return LeafSet(c - edge / 2, np.full(1, edge), c, frame, np.zeros((1, 6)), np.full(1, 0.005), np.zeros(1, np.uint8),
                   np.full(1, 50), np.asarray([spreads], float) ** 2)


ONE = np.array([0])


def agreement(a, b):
    return crease_agreement(a, ONE, b, ONE)[0]


S2 = 0.5**0.5


@pytest.mark.parametrize("turn_a, turn_b, expected", [(1, 1, 1), (-1, -1, 1), (1, -1, -1), (-1, 1, -1)])
def test_a_roof_ridge_links_its_two_planes_outward_or_both_inward(turn_a, turn_b, expected):
    # a gable roof: planes at 45 degrees, ridge along y at x = 0, z = 1; outward normals (-1, 0, 1) and (1, 0, 1)
    a = sheet([-0.35, 0.0, 0.65], [S2, 0, S2], turn_a * np.array([-1.0, 0, 1]), [0.28, 0.28, 0.005])
    b = sheet([0.35, 0.0, 0.65], [S2, 0, -S2], turn_b * np.array([1.0, 0, 1]), [0.28, 0.28, 0.005])
    assert agreement(a, b) == expected * CREASE_AGREEMENT
    assert agreement(b, a) == expected * CREASE_AGREEMENT  # the same either way round


def test_a_wall_on_the_ground_in_front_of_it_links_outward():
    ground = sheet([0.5, 0.0, 0.0], [0, 1, 0], [0, 0, 1], [0.28, 0.28, 0.005])  # x > 0: in front of the wall
    wall = sheet([0.0, 0.0, 0.5], [0, 1, 0], [1, 0, 0], [0.28, 0.28, 0.005])
    assert agreement(ground, wall) == CREASE_AGREEMENT
    assert agreement(ground, wall._replace(frame=-wall.frame)) == -CREASE_AGREEMENT


def test_ground_beside_a_buildings_corner_says_nothing_of_the_next_wall():
    # the ground outside the -x wall lies behind the +y wall's plane; it is far from that wall along their crease
    ground = sheet([-1.0, 18.0, 0.0], [1, 0, 0], [0, 0, 1], [0.6, 1.1, 0.005], edge=4.0)
    wall = sheet([1.4, 20.0, 0.5], [1, 0, 0], [0, 1, 0], [0.26, 0.29, 0.005])
    assert agreement(ground, wall) == 0.0


def test_ground_round_a_small_building_says_nothing_of_its_walls():
    # one 8 m leaf of ground round a 4 m building (the tile holds only the ground's ring): its centroid lies inside the
    # walls, behind each wall's plane, but the ring is on both sides of it (found by review: at 8 m tiles only, every
    # wall turned inward)
    ring = sheet([3.99, 3.98, -0.30], [1, 0, 0], [0, 0, 1], [2.584, 2.582, 0.005], edge=8.0)
    wall = sheet([6.05, 3.00, 1.03], [0, 1, 0], [1, 0, 0], [0.578, 0.563, 0.005], edge=2.0)
    assert agreement(ring, wall) == 0.0


def test_a_fence_standing_across_the_ground_says_nothing():
    # the ground's leaf goes on both sides of the fence: its centroid is not clearly on one side
    ground = sheet([0.05, 0.0, 0.0], [1, 0, 0], [0, 0, 1], [0.29, 0.29, 0.005])
    fence = sheet([0.0, 0.0, 0.5], [0, 1, 0], [1, 0, 0], [0.29, 0.29, 0.005])
    assert agreement(ground, fence) == 0.0


@pytest.mark.parametrize("spreads", [[0.5, 0.01, 0.005], [0.3, 0.25, 0.15]], ids=["a line of points", "a thick blob"])
def test_a_line_or_a_blob_takes_no_part(spreads):
    ground = sheet([0.5, 0.0, 0.0], [0, 1, 0], [0, 0, 1], spreads)
    wall = sheet([0.0, 0.0, 0.5], [0, 1, 0], [1, 0, 0], [0.28, 0.28, 0.005])
    assert agreement(ground, wall) == 0.0


def test_link_agreements_uses_the_crease_rule_only_past_60_degrees():
    # a wall's lowest leaf beside the ground: the PCA normals are 90 degrees apart, so the crease rule links them,
    # whatever the leaf's quadric does (a strip of a few rows curls it: its curvature across them is undetermined)
    ground = sheet([0.5, 0.0, 0.0], [0, 1, 0], [0, 0, 1], [0.28, 0.28, 0.005])
    foot = sheet([0.0, 0.0, 0.25], [0, 1, 0], [1, 0, 0], [0.28, 0.14, 0.005])
    lower = np.array([[0.25, -0.25, -0.25], [-0.25, -0.25, -0.25]])  # the foot's +x face touches the ground's cube

    def link(a, b):
        two = LeafSet(*(np.concatenate([x, y]) for x, y in zip(a, b)))._replace(lower=lower, edge=np.full(2, 0.5))
        return link_agreements(two, np.array([1]), two, np.array([0]), np.array([1]))[2]

    for curl in (0.0, 2.0, -2.0):
        coeffs = foot.coeffs.copy()
        coeffs[0, 2] = curl  # w = curl v^2 along the strip's short axis (z)
        assert link(ground, foot._replace(coeffs=coeffs)).tolist() == [CREASE_AGREEMENT]
        assert link(ground, foot._replace(coeffs=coeffs, frame=-foot.frame)).tolist() == [-CREASE_AGREEMENT]
    tilted = sheet([0.0, 0.0, 0.05], [0, 1, 0], [S2, 0, S2], [0.28, 0.28, 0.005])  # 45 degrees: face sampling
    assert abs(link(ground, tilted)[0]) != CREASE_AGREEMENT
