"""The README's snippet for reading vislam's channels from Python, run as written against real logs."""

import os
import re
import subprocess
import sys

import pytest

from conftest import REPO
from vislam_tools import channels, lcmtypes

SAMPLE = REPO / "data" / "sample.lcmlog"


def readme_snippet():
    """The first python code block of the README section on reading the channels from Python."""
    text = (REPO / "README.md").read_text()
    section = text.index("### Reading the channels from Python")
    match = re.compile(r"```python\n(.*?)```", re.DOTALL).search(text, section)
    assert match, "README: no python block after '### Reading the channels from Python'"
    return match.group(1)


def run_snippet(code, types_dir):
    """Run code from the repository's root with the generated types on PYTHONPATH; its output lines."""
    env = dict(os.environ, PYTHONPATH=str(types_dir))
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    return res.stdout.splitlines()


def test_snippet_reads_every_frame_of_the_sample_log(vislam_types):
    import lcm
    code = readme_snippet()
    assert '"data/sample.lcmlog"' in code
    lines = run_snippet(code, lcmtypes.types_dir())
    frames = [vislam_types.stereo_frame_t.decode(e.data) for e in lcm.EventLog(str(SAMPLE), "r")
              if e.channel == channels.FEATURES]
    assert len(frames) > 0 and len(lines) == len(frames)
    for line, f in zip(lines, frames):
        channel, utime, n, u_min = line.split()
        assert (channel, int(utime), int(n)) == (channels.FEATURES, f.utime, f.num_features)
        assert float(u_min) == pytest.approx(min(f.u_left[:f.num_features], default=0), abs=0.05)


def test_snippet_decodes_both_pose_messages(vislam_types, tmp_path):
    """A log as lcm-logger records it from vislamd: the pose channels print their own lines."""
    import bot_core
    import lcm
    pose = vislam_types.pose_t()
    pose.utime, pose.position, pose.linear_velocity = 1500, [1.0, 2.0, 3.0], [4.0, 0.0, 0.0]
    bot = bot_core.pose_t()
    bot.utime, bot.pos, bot.vel = 1500, [1.0, 2.0, 3.0], [0.0, 4.0, 0.0]
    log_path = tmp_path / "outputs.lcmlog"
    log = lcm.EventLog(str(log_path), "w", overwrite=True)
    log.write_event(1500, channels.POSE, pose.encode())
    log.write_event(1500, channels.BOT_POSE, bot.encode())
    log.write_event(1500, "OTHER", b"\x00")
    log.close()
    lines = run_snippet(readme_snippet().replace('"data/sample.lcmlog"', repr(str(log_path))),
                        lcmtypes.types_dir())
    assert lines == [f"{channels.POSE} 1500 (1.0, 2.0, 3.0) body velocity (4.0, 0.0, 0.0)",
                     f"{channels.BOT_POSE} 1500 (1.0, 2.0, 3.0) world velocity (0.0, 4.0, 0.0)"]
