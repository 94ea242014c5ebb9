"""The Python tools take the default channel names from platform/vl_channels.h."""

import re
from pathlib import Path

from vislam_tools import channels


def test_names_are_the_headers():
    header = (Path(__file__).resolve().parents[2] / "platform" / "vl_channels.h").read_text()
    defined = dict(re.findall(r'^#define VL_CHANNEL_(\w+) "([^"]+)"', header, re.MULTILINE))
    assert defined["IMU"] == channels.IMU == "VISLAM_IMU"
    assert defined["FEATURES"] == channels.FEATURES
    assert defined["CALIBRATION"] == channels.CALIBRATION
    assert defined["POSE"] == channels.POSE
    assert defined["STATUS"] == channels.STATUS
    assert defined["BOT_POSE"] == channels.BOT_POSE
    assert defined["LANDMARKS"] == channels.LANDMARKS


def test_prefix_replaces_the_shared_part():
    assert channels.PREFIX == "VISLAM_"
    assert channels.with_prefix(channels.CALIBRATION, "CAR1_") == "CAR1_CALIB"
    assert channels.with_prefix(channels.IMU, channels.PREFIX) == channels.IMU
