"""Offline tools for vislam: dataset conversion (npz2lcm) and trajectory evaluation (evaluate).

Modules:
    geometry  -- SO(3)/SE(3) helpers, quaternions, dead reckoning
    trajio    -- TUM / KITTI / PLY readers and writers, calibration loading
    metrics   -- association; ATE and RPE through evo; consistency (NEES)
    plotting  -- top-down figures and animations (matplotlib)
    lcmtypes  -- locating the lcm-gen generated Python message types
    npz2lcm   -- command line: seed dataset (.npz) to LCM event log
    evaluate  -- command line: ate / gt / consistency / plot / animate / deadreckon
"""


class ToolError(Exception):
    """A user-facing error (bad input file, missing build output): printed without a traceback."""
