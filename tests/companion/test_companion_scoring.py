"""Frame features: red share over both hue bands, opening, ArUco markers, HOG people."""

from __future__ import annotations

from typing import ClassVar

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.scoring import (
    ArucoScorer,
    ArucoSettings,
    HogPeopleScorer,
    HogSettings,
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


HAS_HOG = hasattr(cv2, "HOGDescriptor")
needs_hog = pytest.mark.skipif(not HAS_HOG, reason=f"OpenCV {cv2.__version__} has no "
                               "HOGDescriptor (opencv-python-headless>=4.10,<5 has it)")


def _person_frame(height: int = 240, x: int = 320, bg: int = 200, fg: int = 40) -> np.ndarray:
    """A dark upright person-like silhouette (head, torso, arms, legs) on a plain background."""
    image = np.full((480, 640, 3), bg, np.uint8)
    top, u, col = (480 - height) // 2, height / 8.0, (fg, fg, fg)  # u: one head height

    def pt(dx: float, dy: float) -> tuple[int, int]:
        return (round(x + dx * u), round(top + dy * u))

    cv2.circle(image, pt(0, 0.5), round(0.5 * u), col, -1, cv2.LINE_AA)
    cv2.ellipse(image, pt(0, 2.6), (round(0.95 * u), round(1.7 * u)), 0, 0, 360, col, -1,
                cv2.LINE_AA)
    for side in (-1, 1):
        cv2.line(image, pt(0.9 * side, 1.5), pt(1.2 * side, 4.0), col, round(0.45 * u),
                 cv2.LINE_AA)
        cv2.line(image, pt(0.45 * side, 4.0), pt(0.7 * side, 7.8), col, round(0.6 * u),
                 cv2.LINE_AA)
    return image


@needs_hog
@pytest.mark.parametrize(("height", "x"), [(180, 200), (240, 320), (300, 420)])
def test_hog_finds_a_person_silhouette(height: int, x: int) -> None:
    result = HogPeopleScorer().score(_person_frame(height, x))
    assert result["people"] == 1 and result["object"] is True
    assert result["people_score"] >= 1.0  # well above the 0.5 margin threshold


@needs_hog
def test_hog_scale_trades_small_people_for_speed() -> None:
    """The 64x128 window on a half-size copy misses a 120 px person that full size finds."""
    small = _person_frame(120)
    assert HogPeopleScorer().score(small)["people"] == 0
    assert HogPeopleScorer(HogSettings(scale=1.0)).score(small)["people"] == 1


@needs_hog
def test_hog_finds_nobody_in_plain_or_red_frames() -> None:
    red = _frame()
    red[100:380, 200:440] = (0, 0, 255)
    for image in (_frame(), red, _marker_frame(5)):
        assert HogPeopleScorer().score(image) == {"people": 0, "people_score": 0.0,
                                                  "object": False}


@needs_hog
def test_hog_finds_nobody_in_synthetic_aerial_frames() -> None:
    """Fields, tracks, red objects and markers seen from 20-80 m are not people."""
    from sitl.camera import CameraPose, SyntheticCamera
    from sitl.scenes import load_scene

    camera = SyntheticCamera(load_scene("demo"), width_px=640, height_px=480)
    scorer = HogPeopleScorer()
    rng = np.random.default_rng(3)
    for i in range(6):
        pose = CameraPose(east_m=float(rng.uniform(-150, 150)),
                          north_m=float(rng.uniform(-150, 150)),
                          up_m=float(rng.uniform(20, 80)), yaw_rad=float(rng.uniform(0, 6.28)))
        assert scorer.score(camera.render(pose, t_s=float(i)))["people"] == 0


@needs_hog
def test_composite_with_hog_people_ors_object() -> None:
    scorer = make_scorer(["red_share", "aruco", "hog_people"])
    result = scorer.score(_person_frame())
    assert result["object"] is True and result["people"] == 1 and result["markers"] == []
    assert result["red"] == 0.0


class _FakeHog:
    """Stands in for cv2.HOGDescriptor: records the call, returns fixed detections."""

    calls: ClassVar[list[tuple[tuple[int, ...], tuple[int, int], float]]] = []
    weights: ClassVar[tuple[float, ...]] = ()

    def setSVMDetector(self, detector: object) -> None:
        assert detector == "default-people"

    @staticmethod
    def getDefaultPeopleDetector() -> str:
        return "default-people"

    def detectMultiScale(self, image: np.ndarray, *, winStride: tuple[int, int],
                         scale: float) -> tuple[np.ndarray, np.ndarray]:
        _FakeHog.calls.append((image.shape, winStride, scale))
        rects = np.zeros((len(self.weights), 4), np.int32)
        return rects, np.array(self.weights, np.float64).reshape(-1, 1)


def test_hog_plumbing_scales_filters_and_reports(monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs on every OpenCV: the detector sees the scaled frame, weak windows do not count."""
    monkeypatch.setattr(cv2, "HOGDescriptor", _FakeHog, raising=False)
    monkeypatch.setattr(_FakeHog, "calls", [])
    monkeypatch.setattr(_FakeHog, "weights", (0.3, 2.5, 0.9))
    scorer = HogPeopleScorer(HogSettings(scale=0.5, win_stride_px=16, pyramid_scale=1.2))
    assert scorer.score(_frame()) == {"people": 2, "people_score": 2.5, "object": True}
    assert _FakeHog.calls == [((240, 320, 3), (16, 16), 1.2)]
    monkeypatch.setattr(_FakeHog, "weights", (0.49,))
    assert HogPeopleScorer(min_weight=0.5).score(_frame()) == {
        "people": 0, "people_score": 0.0, "object": False}
    assert HogPeopleScorer(scale=1.0, min_weight=0.0).score(_frame())["people"] == 1
    assert _FakeHog.calls[-1][0] == (480, 640, 3)
    merged = make_scorer(["red_share", "hog_people"],
                         {"hog_people": HogSettings(min_weight=0.4)}).score(_frame())
    assert merged == {"red": 0.0, "people": 1, "people_score": 0.49, "object": True}


def test_hog_missing_names_the_fix(monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs on every OpenCV: without HOGDescriptor the scorer refuses to start, saying why."""
    monkeypatch.delattr(cv2, "HOGDescriptor", raising=False)
    monkeypatch.delattr(cv2, "xobjdetect", raising=False)
    for build in (HogPeopleScorer, lambda: make_scorer(["red_share", "hog_people"])):
        with pytest.raises(ScorerUnavailable,
                           match=r'opencv-python-headless>=4\.10,<5.*opencv-contrib'):
            build()


@pytest.mark.skipif(HAS_HOG, reason="this OpenCV has HOGDescriptor")
def test_hog_people_detector_reports_when_missing() -> None:
    with pytest.raises(ScorerUnavailable, match=f"not in OpenCV {cv2.__version__}"):
        HogPeopleScorer()


@pytest.mark.parametrize(("field", "value"), [("scale", 0.0), ("scale", 1.5),
                                              ("win_stride_px", 12), ("win_stride_px", 0),
                                              ("pyramid_scale", 1.0), ("min_weight", -1.0)])
def test_invalid_hog_settings_are_rejected(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        HogSettings(**{field: value})
    with pytest.raises(TypeError, match="not both"):
        HogPeopleScorer(HogSettings(), scale=0.5)
