"""The default LCM channel names, read from their one definition, platform/vl_channels.h.

IMU, FEATURES, CALIBRATION, POSE, BOT_POSE, STATUS and LANDMARKS are the names every program uses by default;
PREFIX is what the vislam ones share, so a tool that offers another prefix keeps the same suffixes.
"""

import os
import re

_HEADER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "platform", "vl_channels.h")


def _read(path):
    with open(path) as f:
        return dict(re.findall(r'^#define VL_CHANNEL_(\w+) "([^"]+)"', f.read(), re.MULTILINE))


_NAMES = _read(_HEADER)
IMU = _NAMES["IMU"]
FEATURES = _NAMES["FEATURES"]
CALIBRATION = _NAMES["CALIBRATION"]
POSE = _NAMES["POSE"]
BOT_POSE = _NAMES["BOT_POSE"]
STATUS = _NAMES["STATUS"]
LANDMARKS = _NAMES["LANDMARKS"]
PREFIX = os.path.commonprefix([IMU, FEATURES, CALIBRATION, POSE, STATUS])


def with_prefix(name, prefix):
    """A default channel name with PREFIX replaced by prefix."""
    return prefix + name[len(PREFIX):]
