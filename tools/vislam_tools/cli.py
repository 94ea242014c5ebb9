"""What the command-line tools share with the C programs: the version line, and a quiet end when
the reader of their output goes away.

``--version`` prints "PROG VERSION (git DESCRIPTION)" as the C programs do (platform/vl_cli.h):
the project version from its one definition, ``project(vislam VERSION ...)`` in the top-level
CMakeLists.txt, and ``git describe --always --dirty`` of this source tree, left out when the tree
is not its own git checkout or git is missing.
"""

import argparse
import os
import re
import signal
import subprocess
import sys

_REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))


def project_version():
    """The CMake project version, or "unknown" when the top-level CMakeLists.txt cannot be read."""
    try:
        with open(os.path.join(_REPO, "CMakeLists.txt")) as f:
            m = re.search(r"project\(\s*vislam\s+VERSION\s+([0-9][^\s)]*)", f.read())
    except OSError:
        return "unknown"
    return m.group(1) if m else "unknown"


def _git(*args):
    """Output of git in the source tree, or None."""
    try:
        out = subprocess.run(["git", "-C", _REPO, *args], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def git_description():
    """``git describe --always --dirty`` of the source tree when it is its own checkout, else None."""
    top = _git("rev-parse", "--show-toplevel")
    if top is None or os.path.realpath(top) != os.path.realpath(_REPO):
        return None
    return _git("describe", "--always", "--dirty") or None


def version():
    """"0.1.0 (git 1a2b3c4-dirty)", or "0.1.0" outside a git checkout."""
    describe = git_description()
    return f"{project_version()} (git {describe})" if describe else project_version()


class _VersionAction(argparse.Action):
    """--version: the version is looked up only when asked for (git runs then, not at every start)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="print the version and exit"):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog} {version()}")
        parser.exit()


def add_version(parser):
    """Adds --version to an argparse parser."""
    parser.add_argument("--version", action=_VersionAction)
    return parser


def run(main):
    """Runs a tool's main() as a program and exits with its status.

    SIGPIPE gets its default action back (Python ignores it and raises BrokenPipeError instead),
    so ``tool ... | head`` ends the tool quietly, as it ends the C programs, without a traceback.
    """
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    sys.exit(main())
