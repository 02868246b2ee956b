"""Frame features: red share over both hue bands, opening, ArUco markers."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.scoring import (
    ArucoScorer,
    ArucoSettings,
    HogPeopleScorer,
    RedShareScorer,
    RedShareSettings,
    ScorerUnavailable,
    make_scorer,
)

GREY = (128, 128, 128)


def _hsv_color(h: int, s: int = 255, v: int = 255) -> tuple[int, int, int]:
    bgr = cv2.cvtColor(np.uint8([[[h, s, v]]]), cv2.COLOR_HSV2BGR)[0, 0]
    return (int(bgr[0]), int(bgr[1]), int(bgr[2]))


def _frame(color: tuple[int, int, int] = GREY) -> np.ndarray:
    return np.full((480, 640, 3), color, np.uint8)


def test_grey_frame_has_no_red() -> None:
    assert RedShareScorer().score(_frame()) == {"red": 0.0}


@pytest.mark.parametrize("hue", [0, 5, 10, 170, 175, 179])
def test_both_red_hue_bands_count(hue: int) -> None:
    image = _frame()
    image[0:240, :] = _hsv_color(hue)  # top half red
    assert RedShareScorer().score(image)["red"] == 0.5


@pytest.mark.parametrize("hue", [30, 60, 120])
def test_other_hues_do_not_count(hue: int) -> None:
    assert RedShareScorer().score(_frame(_hsv_color(hue)))["red"] == 0.0


@settings(max_examples=25, deadline=None)
@given(x=st.integers(0, 79), y=st.integers(0, 59), w=st.integers(2, 80), h=st.integers(2, 60))
def test_red_share_of_an_aligned_rectangle_is_exact(x: int, y: int, w: int, h: int) -> None:
    """A rectangle on even coordinates survives the half-scale and a 3x3 opening exactly."""
    image = _frame()
    x0, y0 = 4 * x, 4 * y
    x1, y1 = min(640, x0 + 4 * w), min(480, y0 + 4 * h)
    image[y0:y1, x0:x1] = (0, 0, 255)
    expected = (x1 - x0) * (y1 - y0) / (640 * 480)
    assert RedShareScorer().score(image)["red"] == pytest.approx(expected, abs=1e-12)


def test_opening_removes_isolated_red_pixels() -> None:
    image = _frame()
    image[::8, ::8] = (0, 0, 255)  # speckle noise
    assert RedShareScorer(RedShareSettings(scale=1.0)).score(image)["red"] == 0.0
    unfiltered = RedShareScorer(RedShareSettings(scale=1.0, kernel_px=0)).score(image)["red"]
    assert unfiltered == pytest.approx(60 * 80 / (640 * 480))


def test_thresholds_are_configurable() -> None:
    dark_red = _hsv_color(0, 255, 50)  # below the default V >= 70
    image = _frame(dark_red)
    assert RedShareScorer().score(image)["red"] == 0.0
    loose = RedShareSettings(lower1=(0, 100, 30), lower2=(170, 100, 30))
    assert RedShareScorer(loose).score(image)["red"] == 1.0


def test_invalid_thresholds_are_rejected() -> None:
    with pytest.raises(ValueError, match="lower1"):
        RedShareSettings(lower1=(200, 0, 0))


def _marker_frame(marker_id: int) -> np.ndarray:
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    marker = cv2.aruco.generateImageMarker(dictionary, marker_id, 160)
    image = np.full((480, 640, 3), 255, np.uint8)
    image[160:320, 240:400] = cv2.cvtColor(marker, cv2.COLOR_GRAY2BGR)
    return image


def test_aruco_marker_is_the_object() -> None:
    result = ArucoScorer().score(_marker_frame(7))
    assert result == {"object": True, "markers": [7]}
    assert ArucoScorer().score(_frame()) == {"object": False, "markers": []}


def test_aruco_target_ids_filter() -> None:
    scorer = ArucoScorer(ArucoSettings(target_ids=(3,)))
    assert scorer.score(_marker_frame(7)) == {"object": False, "markers": [7]}
    assert scorer.score(_marker_frame(3))["object"] is True


def test_unknown_aruco_dictionary() -> None:
    with pytest.raises(ValueError, match="DICT_9X9"):
        ArucoScorer(ArucoSettings(dictionary="DICT_9X9"))


def test_composite_merges_and_ors_object() -> None:
    scorer = make_scorer(["red_share", "aruco"])
    image = _marker_frame(1)
    image[0:120, :] = (0, 0, 255)
    result = scorer.score(image)
    assert result["red"] == 0.25 and result["object"] is True and result["markers"] == [1]
    with pytest.raises(ValueError, match="unknown scorer"):
        make_scorer(["magic"])


def test_hog_people_detector_reports_when_missing() -> None:
    if hasattr(cv2, "HOGDescriptor"):
        assert HogPeopleScorer().score(_frame())["people"] == 0
    else:
        with pytest.raises(ScorerUnavailable, match="opencv-contrib"):
            HogPeopleScorer()
