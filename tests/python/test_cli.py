"""The launchers' command-line conventions (vislam_tools.cli): --version as the C programs print
it, and a quiet end when the reader of their output has gone."""

import os
import re
import signal
import subprocess
import sys

import pytest

from conftest import REPO
from vislam_tools import cli

LAUNCHERS = [("evaluate", "tools/evaluate"), ("npz2lcm", "tools/npz2lcm"), ("conditions", "tools/conditions"),
             ("testbed", "tools/testbed"),
             ("vislam-faults", "tools/faults/vislam-faults")]


def run(path, *args, **kwargs):
    env = dict(os.environ, VISLAM_PYTHON=sys.executable)
    return subprocess.run([str(REPO / path), *args], env=env, text=True, timeout=60, **kwargs)


def test_project_version_is_the_cmake_one():
    text = (REPO / "CMakeLists.txt").read_text()
    assert f"project(vislam VERSION {cli.project_version()} " in text


@pytest.mark.parametrize("prog,path", LAUNCHERS)
def test_version_line(prog, path):
    res = run(path, "--version", capture_output=True)
    assert res.returncode == 0, res.stderr
    assert res.stdout == f"{prog} {cli.version()}\n"
    assert re.fullmatch(rf"{re.escape(prog)} \d+\.\d+\.\d+( \(git [0-9A-Za-z._-]+\))?\n", res.stdout)


def test_version_without_git(monkeypatch):
    monkeypatch.setattr(cli, "git_description", lambda: None)
    assert cli.version() == cli.project_version()
    monkeypatch.setattr(cli, "git_description", lambda: "1a2b3c4-dirty")
    assert cli.version() == f"{cli.project_version()} (git 1a2b3c4-dirty)"


@pytest.mark.parametrize("prog,path", LAUNCHERS)
@pytest.mark.parametrize("args", [["--help"], ["--version"]])
def test_closed_pipe_ends_quietly(prog, path, args):
    """Output into a pipe whose reader has gone: killed by SIGPIPE like the C programs, no traceback."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        res = run(path, *args, stdout=write_end, stderr=subprocess.PIPE)
    finally:
        os.close(write_end)
    assert res.returncode == -signal.SIGPIPE, res.stderr
    assert res.stderr == ""
