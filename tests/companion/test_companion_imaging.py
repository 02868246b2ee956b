"""A frame becomes an image message with full/half/quarter JPEG versions (eq. 4.33)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.imaging import encode_versions, image_message
from companion.protocol import message_metadata
from utility_specs.files import builtin_spec

T0 = 1_700_000_000.0


def _image() -> np.ndarray:
    rng = np.random.default_rng(1)
    image = np.full((480, 640, 3), 90, np.uint8)
    image[100:300, 200:400] = (0, 0, 255)
    image += rng.integers(0, 20, image.shape, dtype=np.uint8)
    return image


def test_versions_sizes_and_diagonal_quality() -> None:
    encoded = image_message(_image(), sender="d1", seq=4, t_gen=T0,
                            features={"red": 0.13, "object": False},
                            geotag={"lat_deg": 50.0, "lon_deg": 19.9, "yaw_rad": 1.0})
    m = encoded.message
    assert [v.name for v in m.versions] == ["full", "half", "quarter"]
    assert [v.size for v in m.versions] == [len(p) for p in encoded.payloads]
    assert [v.quality for v in m.versions] == [1.0, 0.5, 0.25]  # 640x480 -> 320x240 -> 160x120
    assert m.size == len(encoded.payloads[0]) and m.version == 0
    assert m.versions[0].size > m.versions[1].size > m.versions[2].size
    assert m.data["red"] == 0.13 and m.data["object"] is False
    assert m.data["lat_deg"] == 50.0 and m.data["yaw_rad"] == 1.0
    assert m.data["diagonal_px"] == 800.0
    assert (m.type, m.sender, m.seq, m.t_gen) == ("image", "d1", 4, T0)
    half = cv2.imdecode(np.frombuffer(encoded.payloads[1], np.uint8), cv2.IMREAD_COLOR)
    assert half.shape == (240, 320, 3)


def test_odd_sizes_use_the_real_diagonal() -> None:
    versions = encode_versions(np.zeros((101, 203, 3), np.uint8))
    assert [(v.width_px, v.height_px) for v in versions] == [(203, 101), (102, 50), (51, 25)]


def test_jpeg_quality_is_checked() -> None:
    with pytest.raises(ValueError, match="jpeg_quality"):
        encode_versions(_image(), jpeg_quality=0)


def test_message_utility_follows_red_share_and_version() -> None:
    """The shipped image spec rates a red frame higher and a half version at half (eq. 7.1)."""
    spec = builtin_spec("image_streaming")
    utility = spec["image"].utility
    plain = image_message(_image(), sender="d1", seq=1, t_gen=T0, features={"red": 0.0},
                          geotag={}).message
    red = image_message(_image(), sender="d1", seq=2, t_gen=T0, features={"red": 0.5},
                        geotag={}).message
    assert utility.scale(red) == pytest.approx(6.0 * utility.scale(plain))
    assert utility.scale(red.with_version(1)) == pytest.approx(0.5 * utility.scale(red))


def test_metadata_fits_the_wire_encoder() -> None:
    m = image_message(_image(), sender="d1", seq=1, t_gen=T0, features={"red": 0.1},
                      geotag={"lat_deg": 1.0}).message
    meta = message_metadata(m)
    assert meta["d"]["red"] == 0.1 and len(meta["v"]) == 3


def test_offered_versions_are_relative_to_the_best_offered() -> None:
    encoded = image_message(_image(), sender="d1", seq=1, t_gen=T0, features={}, geotag={},
                            scales=[("half", 0.5), ("quarter", 0.25)])
    assert [(v.name, v.quality) for v in encoded.message.versions] == [("half", 1.0),
                                                                      ("quarter", 0.5)]
    assert encoded.message.data["width_px"] == 320


def test_the_camera_frame_index_numbers_the_stream() -> None:
    """Round 11: the frame index rides in ``data["frame"]`` (the other drones' optimisers
    read the stream's frame rate from it); ``seq`` stays the drone's message counter."""
    numbered = image_message(_image(), sender="d1", seq=40, t_gen=T0, features={"red": 0.0},
                             geotag={}, frame_index=12).message
    assert numbered.data["frame"] == 12 and numbered.seq == 40
    unnumbered = image_message(_image(), sender="d1", seq=41, t_gen=T0,
                               features={"red": 0.0}, geotag={}).message
    assert "frame" not in unnumbered.data
