"""Rectangles, SAT overlap against shapely, and just-touching / just-apart cases."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from dica.ica.core.occupancy import Rects, footprints, overlap_matrix, overlap_pairs


def rects(cx, cy, angle, hl=2.5, hw=0.9) -> Rects:
    a = np.atleast_1d(np.asarray(angle, float))
    return Rects(
        np.stack([np.atleast_1d(cx), np.atleast_1d(cy)], -1).astype(float),
        np.stack([np.cos(a), np.sin(a)], -1),
        hl,
        hw,
    )


def to_shapely(r: Rects) -> np.ndarray:
    c = r.corners()
    return shapely.polygons(np.concatenate([c, c[:, :1]], axis=1))


@settings(max_examples=60, derandomize=True, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_sat_matches_shapely_on_random_boxes(seed):
    rng = np.random.default_rng(seed)
    n = 40
    a = rects(rng.uniform(-6, 6, n), rng.uniform(-6, 6, n), rng.uniform(-np.pi, np.pi, n))
    b = rects(rng.uniform(-6, 6, n), rng.uniform(-6, 6, n), rng.uniform(-np.pi, np.pi, n))
    ours = overlap_matrix(a, b)
    truth = shapely.intersects(to_shapely(a)[:, None], to_shapely(b)[None, :])
    assert (ours == truth).all()
    ia, ib = rng.integers(0, n, 50), rng.integers(0, n, 50)
    assert (overlap_pairs(a, ia, b, ib) == truth[ia, ib]).all()


@pytest.mark.parametrize("angle", [0.0, np.pi / 2, 0.3, -1.1])
def test_just_touching_counts_and_just_apart_does_not(angle):
    u = np.array([np.cos(angle), np.sin(angle)])
    a = rects(0.0, 0.0, angle)
    # end to end along the heading: centres 5 m apart touch, 5 m + 1 mm do not
    touch = rects(*(u * 5.0), angle)
    apart = rects(*(u * 5.001), angle)
    assert overlap_matrix(a, touch)[0, 0]
    assert not overlap_matrix(a, apart)[0, 0]
    # side by side: 1.8 m apart touch
    n = np.array([-u[1], u[0]])
    assert overlap_matrix(a, rects(*(n * 1.8), angle))[0, 0]
    assert not overlap_matrix(a, rects(*(n * 1.801), angle))[0, 0]


def test_corner_to_corner_touch():
    a = rects(0.0, 0.0, 0.0, 1.0, 1.0)
    assert overlap_matrix(a, rects(2.0, 2.0, 0.0, 1.0, 1.0))[0, 0]
    assert not overlap_matrix(a, rects(2.0, 2.001, 0.0, 1.0, 1.0))[0, 0]
    # a diamond whose tip just reaches the square's edge
    d = np.sqrt(2.0)
    assert overlap_matrix(a, rects(1.0 + d, 0.0, np.pi / 4, 1.0, 1.0))[0, 0]
    assert not overlap_matrix(a, rects(1.0 + d + 1e-3, 0.0, np.pi / 4, 1.0, 1.0))[0, 0]


def test_footprint_front_is_on_the_route_and_heading_is_rear_to_front(ch45):
    route = next(r for r in ch45.routes if r.turn.value == "left")
    s = np.linspace(0.0, route.cross_length_m + 5.0, 30)
    fp = footprints(route, s, 5.0, 1.8)
    front = fp.centre + fp.heading * 2.5
    assert np.allclose(front, route.points(s), atol=1e-9)
    chord = route.points(s) - route.points(s - 5.0)
    chord /= np.linalg.norm(chord, axis=1, keepdims=True)
    assert np.allclose(fp.heading, chord, atol=1e-9)  # as SUMO: rear to front


def test_project_recovers_arc_length(ch45):
    for route in ch45.routes:
        s = np.linspace(-50.0, route.cross_length_m + 5.0, 200)
        got, off = route.project(route.points(s))
        assert np.allclose(got, s, atol=1e-6)
        assert off.max() < 1e-6
