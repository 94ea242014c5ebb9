"""The vislam filter, written again in plain NumPy for reading, not for speed.

This module computes what core/ computes, step for step, for any configuration vislam-run prints
with --print-config in slam or imu_only mode (the default one included: the gate, re-association,
1-point RANSAC, the update time bound, the rescue pass and the noise adaptation). Where the C code
makes a choice (the order of landmark slots, the swap-based partition of the rows, the random
numbers of RANSAC, the stable admission order), this code makes the same one, so on the same log
the two trajectories agree to rounding (tests/python/test_reference.py holds them to it).

Not modelled: the robustness rules of core/src/vl_guard.c that never act on a clean log (time
jumps, new timelines, IMU silence, divergence resets and with them the held sample distrusted after
one an IMU sample led to, frame truncation, implausible IMU samples) and the mapping mode. A log
that would need one stops the run with ReferenceError.

Notation (README, "The estimator"): the pose T = (R, p) is world-from-IMU; the state is
[rho, phi, b_v, b_w, rho_1, ..., rho_N] with the invariant error T = exp(xi) T_hat and
l_i = exp(phi) l_hat_i + J_l(phi) rho_i; the covariance P is (15 + 3N) square. Landmark i's
block starts at column 15 + 3 i.
"""

import math
import time
from dataclasses import dataclass, field

import numpy as np

from vislam_tools import channels
from vislam_tools.geometry import hat3, rot_to_quat
from vislam_tools.lcmtypes import load, load_lcm

CORE_DIM = 15                # rho, phi, linear offset, angular offset, velocity sensor position
MIN_CAMERA_DEPTH = 1e-3      # m; a point nearer than this in front of the camera is "behind" it
MIN_ROWS_FOR_REASSOCIATION = 8
RANSAC_MIN_CONSENSUS = 2     # a hypothesis supports its own row: a consensus needs another
MAX_PENDING = 512            # candidate tracks remembered (2 x VL_MAX_FRAME_FEATURES)
MAX_FRAME_FEATURES = 256
AGE_BONUS, AGE_CAP = 0.5, 4  # admission score: disparity x (1 + 0.5 min(age, 4))
NOISE_ADAPT_RANGE = 100.0    # adapted standard deviations stay within 100x of the configured ones
CONTRADICTION_RUN = 2        # re-associated frames in a row that widen the noise
PIXEL_NOISE_MEMORY = 1000.0  # observations the pixel noise estimate averages over
PIXEL_NOISE_FAST_MEMORY = 100.0  # the same while its std is over PIXEL_FAR_FROM_ROWS x the stereo rows' noise
PIXEL_FAR_FROM_ROWS = 15.0
CHI2_1_MEDIAN = 0.455        # median of chi-square(1): a median of squares to a variance
PIXEL_SAMPLE_CAP = 100.0     # a pixel variance sample counts for at most this many variances in use
PIXEL_SPARSE_FRAME = 12      # observations under which a frame's pixel rows count against their post-fit variance
PIXEL_MIN_RESIDUAL_SHARE = 0.05  # a sparse frame's fitted row expected to keep less of its noise gives no sample
PIXEL_DROP_GAIN = 0.2        # a dense frame's weight in the fast average of log(sample / estimate)
PIXEL_DROP_RATIO = 9.0       # that average under -log(this): the estimate goes to the frames' level
VELOCITY_DENSE_FRAME = 16     # observations from which a frame determines the pose on its own
VELOCITY_NOISE_GAIN = 0.05    # log-variance step per dense frame
VELOCITY_SPARSE_GAIN = 0.1    # per sparse frame (world frame), times the share of the block's prior variance it removed
STEREO_ROW_MEMORY = 1000.0    # observations the stereo rows' white noise averages over
STEREO_ROW_CAP = 9.0          # a stereo-row sample counts for at most this many variances of the estimate
TWO_VIEW_MIN_PAIRS = 3        # tracks in both views from which a sparse frame's motion error is fitted
TWO_VIEW_GAIN = 0.05          # log-variance step per two-view frame, times the noise's share of the expectation
VELOCITY_RATIO_MIN, VELOCITY_RATIO_MAX = 0.1, 10.0
# -E[log clamp(q / k, 0.1, 10)] for q ~ chi-square(k), k = 1, 1.5, 2, 2.5, 3 (numerical integration)
LOG_RATIO_BIAS = (0.768765, 0.593114, 0.479665, 0.400083, 0.341355)
VELOCITY_MIN_INFORMATION = 1e-12
WIDEN_ON_CONTRADICTION = 4.0
WIDEN_RANGE = 20.0          # the widening stops at this factor of the configured std
TWO_VIEW_MOMENT_MEMORY = 300.0  # two-view frames the velocity variances' moment estimate forgets over
TWO_VIEW_MOMENT_MIN_FRAMES = 10.0  # frames it needs before it counts
TWO_VIEW_MOMENT_RISE = 4.0  # it replaces a variance it lies over by this factor (upwards only)
DRIFT_CLIP = 1.0            # a track's two-view residual rows clipped at this many of their stds before summing
DRIFT_MIN_FRAMES = 3        # frames from which a track's drift sum counts
DRIFT_CHI2 = 16.27          # chi-square (3 dof, 99.9 %) of the sum over which the track moves on its own
REOPEN_RATIO = 4.0          # angular variance over its configured value from which the angular offsets reopen
SERIES_ANGLE = 1.0           # below this angle (rad) the Lie-group coefficients come from series
SERIES_TERMS = 14
STEREO_SHARE = np.array([1.0, 0.5, 1.0])  # noise of [u_left, (v_left + v_right) / 2, u_right] / s^2


class ReferenceError(Exception):
    """The log needs something this reference does not model."""


# ------------------------------------------------------------------------------------- SO(3), SE(3)
# Written again rather than taken from vislam_tools.geometry: these follow core/src/vl_se3.c
# (Taylor series below 1 rad, the polar normalization), so that the two filters round alike.

def _trig_series(t2, m):
    """Taylor series of sin t / t (m = 1), (1 - cos t) / t^2 (m = 2), (t - sin t) / t^3 (m = 3),
    (t^2 / 2 + cos t - 1) / t^4 (m = 4): sum_k (-1)^k t^2k / (2k + m)!, with no cancellation."""
    term = 1.0 / math.factorial(m)
    total = term
    for k in range(SERIES_TERMS):
        term *= -t2 / ((2 * k + m + 1) * (2 * k + m + 2))
        total += term
    return total


def so3_coefficients(t):
    """sin t / t, (1 - cos t) / t^2 and (t - sin t) / t^3 for the angle t (rad)."""
    if t < SERIES_ANGLE:
        t2 = t * t
        return _trig_series(t2, 1), _trig_series(t2, 2), _trig_series(t2, 3)
    return math.sin(t) / t, (1.0 - math.cos(t)) / (t * t), (t - math.sin(t)) / (t ** 3)


def so3_exp(phi):
    """exp(hat(phi)) = I + (sin t / t) F + ((1 - cos t) / t^2) F^2 with F = hat(phi) (Rodrigues)."""
    a, b, _ = so3_coefficients(math.sqrt(phi @ phi))
    F = hat3(phi)
    return np.eye(3) + a * F + b * (F @ F)


def so3_left_jacobian(phi):
    """J_l(phi) = I + ((1 - cos t) / t^2) F + ((t - sin t) / t^3) F^2 (Barfoot eq. 7.77)."""
    _, b, c = so3_coefficients(math.sqrt(phi @ phi))
    F = hat3(phi)
    return np.eye(3) + b * F + c * (F @ F)


def se3_exp(xi):
    """exp of the twist xi = [rho, phi]: (R, p) = (exp(phi), J_l(phi) rho)."""
    return so3_exp(xi[3:]), so3_left_jacobian(xi[3:]) @ xi[:3]


def _se3_q(rho, phi):
    """Q(rho, phi), the top-right block of the SE(3) left Jacobian (Barfoot eq. 7.86)."""
    t = math.sqrt(phi @ phi)
    if t < SERIES_ANGLE:
        t2 = t * t
        a, b = _trig_series(t2, 3), _trig_series(t2, 4)
        term = c = 1.0 / 120.0  # c = sum_k (-1)^k (k + 1) t^2k / (2k + 5)!
        for k in range(SERIES_TERMS):
            term *= -t2 / ((2 * k + 6) * (2 * k + 7))
            c += (k + 2) * term
    else:
        s, co, t2 = math.sin(t), math.cos(t), t * t
        a = (t - s) / (t2 * t)
        b = (t2 + 2.0 * co - 2.0) / (2.0 * t2 * t2)
        c = (2.0 * t - 3.0 * s + t * co) / (2.0 * t2 * t2 * t)
    P, F = hat3(rho), hat3(phi)
    FP, PF = F @ P, P @ F
    FPF = FP @ F
    return (0.5 * P + a * (FP + PF + FPF) + b * (F @ FP + PF @ F - 3.0 * FPF)
            + c * (FPF @ F + F @ FPF))


def se3_left_jacobian(xi):
    """The 6x6 left Jacobian [[J_l(phi), Q], [0, J_l(phi)]] of SE(3)."""
    J = np.zeros((6, 6))
    J[:3, :3] = J[3:, 3:] = so3_left_jacobian(xi[3:])
    J[:3, 3:] = _se3_q(xi[:3], xi[3:])
    return J


def se3_right_jacobian(xi):
    """J_r(xi) = J_l(-xi)."""
    return se3_left_jacobian(-np.asarray(xi))


def se3_adjoint(R, p):
    """Ad(T) = [[R, hat(p) R], [0, R]], which maps twists xi -> T xi T^-1."""
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = R
    A[:3, 3:] = hat3(p) @ R
    return A


def so3_normalize(R):
    """The nearest rotation (Frobenius norm) by Newton's iteration on the polar factor,
    X <- (X + X^-T) / 2, as core/src/vl_se3.c does (so the round-off is alike)."""
    R = R.copy()
    for _ in range(20):
        C = np.array([
            [R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1], R[1, 2] * R[2, 0] - R[1, 0] * R[2, 2],
             R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0]],
            [R[0, 2] * R[2, 1] - R[0, 1] * R[2, 2], R[0, 0] * R[2, 2] - R[0, 2] * R[2, 0],
             R[0, 1] * R[2, 0] - R[0, 0] * R[2, 1]],
            [R[0, 1] * R[1, 2] - R[0, 2] * R[1, 1], R[0, 2] * R[1, 0] - R[0, 0] * R[1, 2],
             R[0, 0] * R[1, 1] - R[0, 1] * R[1, 0]]])  # cofactors: X^-T = C / det X
        det = R[0, 0] * C[0, 0] + R[0, 1] * C[0, 1] + R[0, 2] * C[0, 2]
        if not det > 1e-12:
            raise ReferenceError("rotation degenerated (the C code would fall back to a quaternion)")
        nxt = 0.5 * (R + C / det)
        change = np.abs(nxt - R).sum()
        R = nxt
        if change < 1e-15:
            break
    return R


# ------------------------------------------------------------------------------------- stereo camera

@dataclass
class Calibration:
    """The stereo rig: pinhole intrinsics (px), baseline (m) and cam_T_imu (4x4)."""
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    cam_T_imu: np.ndarray

    @property
    def Rc(self):
        return self.cam_T_imu[:3, :3]

    @property
    def tc(self):
        return self.cam_T_imu[:3, 3]


def stereo_project(cal, c):
    """The compressed stereo model y = [u_left, v, u_right] of the camera point c, and dy/dc:
    u_left = fx x / z + cx, v = fy y / z + cy, u_right = fx (x - b) / z + cx."""
    iz = 1.0 / c[2]
    xn, yn, xr = c[0] * iz, c[1] * iz, (c[0] - cal.baseline) * iz
    y = np.array([cal.fx * xn + cal.cx, cal.fy * yn + cal.cy, cal.fx * xr + cal.cx])
    dy_dc = np.array([[cal.fx * iz, 0.0, -cal.fx * xn * iz],
                      [0.0, cal.fy * iz, -cal.fy * yn * iz],
                      [cal.fx * iz, 0.0, -cal.fx * xr * iz]])
    return y, dy_dc


def stereo_triangulate(cal, y):
    """The camera point of a compressed observation and dc/dy: z = fx b / d with the disparity
    d = u_left - u_right, x = (u_left - cx) b / d, y = (v - cy) (fx / fy) b / d."""
    b = cal.baseline
    idd = 1.0 / (y[0] - y[2])
    du, dv = y[0] - cal.cx, (y[1] - cal.cy) * cal.fx / cal.fy
    c = np.array([du * b * idd, dv * b * idd, cal.fx * b * idd])
    bid2 = b * idd * idd
    dc_dy = np.array([[b * idd - du * bid2, 0.0, du * bid2],
                      [-dv * bid2, b * idd * cal.fx / cal.fy, dv * bid2],
                      [-cal.fx * bid2, 0.0, cal.fx * bid2]])
    return c, dc_dy


def compress(o):
    """An observation (id, u_left, v_left, u_right, v_right) as y = [u_left, (v_l + v_r) / 2, u_right]:
    the rows of v_left and v_right in the stereo matrix M are equal, so this loses nothing."""
    return np.array([o[1], 0.5 * (o[2] + o[4]), o[3]])


def joint_update_flops(n, k):
    """vl_work_joint_update: the flops of one joint update with n states and k observations."""
    if k == 0:
        return 0
    m = 3 * k
    pht = 2 * n * 9 * m
    s_rows = 2 * 9 * 3 * (m * k - 3 * k * (k - 1) // 2)
    chol = m * m * m // 3 + m * m
    whiten = m * m + n * m * (m + 1)
    dx = 2 * n * m
    downdate = n * (n + 1) * m
    correct = 1000 + 39 * ((n - CORE_DIM) // 3)
    return pht + s_rows + chol + whiten + dx + downdate + correct


def log_ratio_bias(k):
    """-E[log clamp(q / k, 0.1, 10)] for q chi-square with k degrees of freedom (k within [1, 3]),
    linear between LOG_RATIO_BIAS's points at k = 1, 1.5, ..., 3."""
    t = 2.0 * (min(max(k, 1.0), 3.0) - 1.0)
    i = 3 if t >= 3.0 else int(t)
    f = t - i
    return (1.0 - f) * LOG_RATIO_BIAS[i] + f * LOG_RATIO_BIAS[i + 1]


def stereo_noise(pixel_var):
    """Noise variances of the compressed observation: diag(s^2, s^2 / 2, s^2)."""
    return pixel_var * STEREO_SHARE


def mahalanobis3(S, r):
    """r^T S^-1 r through the Cholesky factor of S; infinite when S is not positive definite."""
    if not S[0, 0] > 0.0:
        return math.inf
    l00 = math.sqrt(S[0, 0])
    l10, l20 = S[1, 0] / l00, S[2, 0] / l00
    d11 = S[1, 1] - l10 * l10
    if not d11 > 0.0:
        return math.inf
    l11 = math.sqrt(d11)
    l21 = (S[2, 1] - l20 * l10) / l11
    d22 = S[2, 2] - l20 * l20 - l21 * l21
    if not d22 > 0.0:
        return math.inf
    l22 = math.sqrt(d22)
    w0 = r[0] / l00
    w1 = (r[1] - l10 * w0) / l11
    w2 = (r[2] - l20 * w0 - l21 * w1) / l22
    return w0 * w0 + w1 * w1 + w2 * w2


def splitmix64(state):
    """One draw of splitmix64: (new state, value), the generator of RANSAC's hypotheses."""
    mask = (1 << 64) - 1
    state = (state + 0x9E3779B97F4A7C15) & mask
    z = state
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & mask
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & mask
    return state, z ^ (z >> 31)


# ------------------------------------------------------------------------------------- velocity samples

def sample_velocity(held, held_utime, new, state_utime, utime, interpolate):
    """The velocity that carries the state from state_utime to utime (us), where a new sample
    arrives (core/src/vl_predict.c, vl_predict_to_sample), and its noise in units of one sample's
    variance. held was sampled at held_utime <= state_utime. Without interpolate the held sample
    applies, with its own noise. With it, each sample is the velocity at its time and the velocity
    is linear between the two: the state moves by the line's mean over what is left of the
    interval, the line at the middle of [state_utime, utime], held + w (new - held) with
    w = ((state_utime + utime) / 2 - held_utime) / (utime - held_utime) (1/2 on a whole interval:
    the trapezoid rule). A mean of two independent samples with weights (1 - w, w) has
    (1 - w)^2 + w^2 of one sample's variance (that neighbouring intervals share a sample is not
    modelled). Works on any stack of components (the C code does each of v, w the same way)."""
    if not interpolate:
        return held, 1.0
    span = float(utime - held_utime)
    middle = 0.5 * (float(state_utime - held_utime) + span)
    w = middle / span if span > 0.0 else 1.0
    return held + w * (new - held), (1.0 - w) * (1.0 - w) + w * w


# ------------------------------------------------------------------------------------- the filter

@dataclass
class Slot:
    """A window landmark's bookkeeping (its point is in Filter.L, its error in P)."""
    id: int
    unseen_frames: int = 0
    seen: int = 0  # this frame: 0 not observed, 1 observed, 2 observed and contradicting (broken)
    updates: int = 0  # its observations the updates used
    last_update_frame: int = 0  # frame of the last update that used it, else of its admission
    carried: bool = False  # its track went through a repeated image (repeat_track_walk)
    observations: int = 1  # frames that observed it, its admission included


@dataclass
class Pending:
    """A track not (yet) in the window: its point and pixel-noise covariance from its last observation."""
    id: int
    frames_seen: int
    last_frame: int
    point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))


@dataclass
class Row:
    """One observation's update rows: y - h(x) ~ H_pose dx_pose + H_landmark dx_landmark + v."""
    slot: int
    obs: int                # index in the frame
    H_pose: np.ndarray      # 3 x 6
    H_landmark: np.ndarray  # 3 x 3
    residual: np.ndarray    # 3
    noise: np.ndarray       # 3 variances


SEEN_NONE, SEEN, SEEN_BROKEN = 0, 1, 2


class Filter:
    """The joint EKF on SE_{N+1}(3) with invariant errors, as core/src does it."""

    def __init__(self, cfg, cal):
        if cfg["mode"] not in ("slam", "imu_only"):
            raise ReferenceError(f"mode {cfg['mode']} is not modelled")
        self.cfg, self.cal = cfg, cal
        self.R, self.p = np.eye(3), np.zeros(3)
        self.b_v, self.b_w = np.zeros(3), np.zeros(3)  # velocity input offsets
        self.s = np.array([cfg[f"velocity_sensor_{a}"] for a in "xyz"], float)  # the sensor's position
        self.L = np.zeros((0, 3))                         # window landmarks, world points
        self.slots = []
        self.pending = []
        self.P = np.zeros((CORE_DIM, CORE_DIM))
        if cfg["estimate_input_offsets"]:
            self.P[6:9, 6:9] = np.eye(3) * cfg["linear_offset_prior"] ** 2
            self.P[9:12, 9:12] = np.eye(3) * cfg["angular_offset_prior"] ** 2
        self.P[12:15, 12:15] = np.diag([cfg[f"velocity_sensor_std_{a}"] ** 2 for a in "xyz"])
        self.sensor_estimated = bool(np.any(np.diag(self.P[12:15, 12:15]) > 0.0))
        self.var_v = cfg["linear_velocity"] ** 2
        self.var_w = cfg["angular_velocity"] ** 2
        self.var_w_reopened = REOPEN_RATIO * self.var_w  # the angular variance the offsets were last reopened for
        self.var_px = cfg["pixel"] ** 2
        self.px_log_ratio = 0.0     # fast average of a dense frame's log(sample / var_px)
        self.var_rows = 0.0         # px^2: the stereo rows' white noise, 0 until measured
        self.rows_evidence = 0.0    # observations it averages over
        self.step_t2 = 0.0          # s^2: sum of tau^2 x noise share since the last frame
        self.step_t = 0.0           # s: sum of tau since the last frame
        self.step_turn = np.zeros(3)  # rad: sum of tau x the corrected angular velocity since then
        self.prev_repeated = False  # the previous frame repeated the one before it
        self.velocity_matched = False
        self.moment_num = [0.0, 0.0]  # per block: sum of w a (seen - c), w = 1 / (2 tr M^2), a = 3 sum tau^2
        self.moment_den = [0.0, 0.0]  # sum of w a^2
        self.moment_frames = [0.0, 0.0]
        self.moved = set()          # this frame's observations whose track contradicted its fellows' motion
        self.contradicted = set()   # the previous frame's observations whose track alone contradicted q
        self.drift = {}             # a sparse frame's observation -> [sum of clipped r, sum of S, frames, moving]
        self.prev_drift = {}        # the previous frame's, when it was sparse
        self.state_utime = None  # us; None until the first IMU sample
        self.last_imu_utime = None
        self.held_v = self.held_w = None
        self.last_frame_utime = None
        self.frame_index = 0
        self.reassociated_run = 0
        self.failed_frame_run = 0
        self.prev_frame = np.zeros((0, 5))                 # the previous frame's observations
        self.frame_R, self.frame_p = np.eye(3), np.zeros(3)  # the pose after the previous frame
        self.broken_obs = []
        self.held, self.held_frame = [], None  # the inliers the time bound deferred: frame indices
        self.counters = {"frames": 0, "updates_refused": 0, "observations_used": 0,
                         "observations_deferred_used": 0, "frames_reassociated": 0, "landmarks_initialized": 0}

    @property
    def n(self):
        return self.P.shape[0]

    # ---- prediction (README "Prediction"; core/src/vl_predict.c)

    def predict_to(self, utime, linear=None, angular=None, noise_share=1.0):
        """T <- T exp(tau (u - b)) with u = (linear, angular), the held sample by default; the
        invariant error does not move (Phi = I) except through the input noise n and the offset
        error db, both entering as u -> u - n - db: d xi = G (n + db) with
        G = -tau Ad(T_new) J_r(tau (u - b)) on the pose, and hat(l_i) times G's rotation rows on
        landmark i. P <- Phi P Phi^T + G Q G^T + Q_b, Phi = I + G E^T, with Q the configured (or
        adapted) variance of one sample times noise_share. A velocity sensor at p in the body frame
        (velocity_sensor_*) sees v + w x p: the body twist is T (u - b) with T = [I hat(p); 0 I],
        and G becomes G T. An error dp of the sensor position moves the body twist by -hat(w) dp
        on its linear rows: the parameters (offsets, then sensor position) enter through
        Gt = [G T, G_lin hat(w)], Phi = I + Gt E^T. The offsets' correlations with every other
        state then fade by a = exp(-tau / offset_correlation_time), their own block kept."""
        tau = (utime - self.state_utime) * 1e-6
        if tau <= 0.0:
            return
        linear = self.held_v if linear is None else linear
        angular = self.held_w if angular is None else angular
        xi = tau * np.concatenate([linear - self.b_v, angular - self.b_w])
        sensor = self.s
        lever = bool(np.any(sensor != 0.0))
        self.step_turn = self.step_turn + xi[3:]
        w = xi[3:] / tau
        if lever:
            xi[:3] += hat3(sensor) @ xi[3:]
        dR, dp = se3_exp(xi)
        self.p = self.p + self.R @ dp
        self.R = so3_normalize(self.R @ dR)
        self.state_utime = utime

        Gp = -tau * se3_adjoint(self.R, self.p) @ se3_right_jacobian(xi)
        Gs = Gp[:, 0:3] @ hat3(w)
        if lever:
            Gp[:, 3:6] += Gp[:, 0:3] @ hat3(sensor)
        offsets = self.cfg["estimate_input_offsets"]
        Gt = np.zeros((6, 9))
        if offsets:
            Gt[:, :6] = Gp
        if self.sensor_estimated:
            Gt[:, 6:] = Gs
        G = np.zeros((self.n, 6))
        Gtn = np.zeros((self.n, 9))
        G[:6], Gtn[:6] = Gp, Gt
        for i, l in enumerate(self.L):
            G[CORE_DIM + 3 * i:CORE_DIM + 3 * i + 3] = hat3(l) @ Gp[3:6]
            Gtn[CORE_DIM + 3 * i:CORE_DIM + 3 * i + 3] = hat3(l) @ Gt[3:6]
        P = self.P
        if offsets or self.sensor_estimated:
            # Phi P Phi^T = P + Gt M^T + M Gt^T with M = P E + Gt (E^T P E) / 2, E the parameter columns.
            M = P[:, 6:15] + Gtn @ (0.5 * P[6:15, 6:15])
            P = P + Gtn @ M.T + M @ Gtn.T
        Q = np.diag([self.var_v * noise_share] * 3 + [self.var_w * noise_share] * 3)
        self.step_t2 += tau * tau * noise_share
        self.step_t += tau
        P = P + G @ Q @ G.T
        tc = self.cfg["offset_correlation_time"]
        if offsets and tc > 0.0:
            # The offsets' correlations with every other state fade: D P D with D = a on their rows,
            # their own block refilled to what it was before the step.
            a = math.exp(-tau / tc)
            Pbb = self.P[6:12, 6:12].copy()
            P[6:12, :] *= a
            P[:, 6:12] *= a
            P[6:12, 6:12] += (1.0 - a * a) * Pbb
        if self.cfg["estimate_input_offsets"]:
            walk = [self.cfg["linear_offset_walk"] ** 2 * tau] * 3 + [self.cfg["angular_offset_walk"] ** 2 * tau] * 3
            P[6:12, 6:12] += np.diag(walk)
        self.P = _symmetric(P)

    def propagate(self, utime, linear, angular):
        """An IMU sample: predict to its time (predict_to_sample), then hold it."""
        linear, angular = np.asarray(linear, float), np.asarray(angular, float)
        self.held = []  # the previous frame's deferred rows: this input moves on from its pose
        if self.state_utime is None:
            self.state_utime = utime
        elif utime <= self.last_imu_utime or utime < self.state_utime:
            raise ReferenceError(f"IMU sample out of time order at {utime}")
        else:
            self._check_silence(utime)
            self.predict_to_sample(utime, linear, angular)
        self.held_v, self.held_w = linear, angular
        self.last_imu_utime = utime

    def predict_to_sample(self, utime, linear, angular):
        """Across the interval from the last sample to this one (the state may be part of the way
        there, at a frame), with the velocity sample_velocity gives; frames between the samples are
        reached with the held sample (update)."""
        u, share = sample_velocity(np.concatenate([self.held_v, self.held_w]), self.last_imu_utime,
                                   np.concatenate([linear, angular]), self.state_utime, utime,
                                   self.cfg["interpolate_velocities"])
        self.predict_to(utime, u[:3], u[3:], share)

    def _check_silence(self, utime):
        if utime - self.last_imu_utime > self.cfg["max_imu_silence"] * 1e6:
            raise ReferenceError(f"IMU silent before {utime}: not modelled")

    # ---- the stereo rig at the current pose (core/src/vl_camera.c)

    def camera_point(self, pw):
        """b = R^T (p_w - p) (IMU frame) and c = Rc b + tc (camera frame); None when behind."""
        b = self.R.T @ (pw - self.p)
        c = self.cal.Rc @ b + self.cal.tc
        return (b, c) if c[2] > MIN_CAMERA_DEPTH else (None, None)

    def triangulate_world(self, y, R=None, p=None):
        """l = R b + p with b = Rc^T (c - tc) the triangulated point in the IMU frame; dl/dy. At the
        current pose unless (R, p) is given."""
        R = self.R if R is None else R
        p = self.p if p is None else p
        c, dc_dy = stereo_triangulate(self.cal, y)
        b = self.cal.Rc.T @ (c - self.cal.tc)
        return R @ b + p, R @ self.cal.Rc.T @ dc_dy

    def make_row(self, slot, frame, i):
        """The observation's rows. With b = R^T (l - p), to first order b = b_hat + R^T (rho_i - rho):
        A = dy/dc Rc R^T on rho_i, -A on rho, zero on phi (the update cannot see rotations of the
        whole world). None when the landmark is behind the camera."""
        b, c = self.camera_point(self.L[slot])
        if b is None:
            return None
        y_pred, dy_dc = stereo_project(self.cal, c)
        A = dy_dc @ self.cal.Rc @ self.R.T
        H_pose = np.zeros((3, 6))
        H_pose[:, :3] = -A
        return Row(slot, i, H_pose, A, compress(frame[i]) - y_pred, stereo_noise(self.var_px))

    def innovation_cov(self, row):
        """S = H P H^T + R from the nine columns the row touches."""
        c = CORE_DIM + 3 * row.slot
        idx = np.r_[0:6, c:c + 3]
        H = np.hstack([row.H_pose, row.H_landmark])
        return H @ self.P[np.ix_(idx, idx)] @ H.T + np.diag(row.noise)

    # ---- the frame (core/src/vl_estimator.c, vl_update)

    def update(self, utime, frame):
        """A stereo frame: predict to it, sort its observations into rows and candidates, fuse the
        rows, retire ended and broken tracks, admit candidates. Returns False when the joint
        update was refused (S not positive definite): then vislam-run writes no pose either."""
        if self.state_utime is None:
            raise ReferenceError("frame before the first IMU sample")
        if utime < self.state_utime or (self.last_frame_utime is not None and utime <= self.last_frame_utime):
            raise ReferenceError(f"frame out of time order at {utime}")
        self._check_silence(utime)
        if len(frame) > MAX_FRAME_FEATURES:
            raise ReferenceError("frame over VL_MAX_FRAME_FEATURES: not modelled")
        self.held, self.held_frame = [], frame
        repeated = self.repeats_previous(frame)
        had_frame = self.last_frame_utime is not None
        self.predict_to(utime)
        # a sparse frame's velocity noise, matched on its tracks' two views before the update
        self.velocity_matched = False
        self.moved = set()
        contradicted = set()
        self.carry_drift(frame)
        if self.cfg["adaptive_noise"] and self.cfg["mode"] == "slam":
            self.observe_stereo_rows(frame)
            if had_frame and not repeated and not self.prev_repeated:
                self.velocity_matched = self.adapt_velocity_two_view(frame, contradicted)
        self.contradicted = contradicted
        self.prev_drift = self.drift
        self.step_t2 = self.step_t = 0.0
        self.step_turn = np.zeros(3)
        self.prev_repeated = repeated
        self.prev_frame = frame
        frame_dt = (utime - self.last_frame_utime) * 1e-6 if self.last_frame_utime is not None else 0.0
        self.last_frame_utime = utime
        self.frame_index += 1
        self.counters["frames"] += 1
        if self.cfg["mode"] == "imu_only":
            return True
        if self.cfg["repeat_track_walk"] > 0.0:
            self.carried_walk()
            if repeated and had_frame:
                for s in self.observed_slots(frame):
                    self.slots[s].carried = True
        if repeated and had_frame and self.cfg["repeat_anchor_noise"] > 0.0:
            self.repeat_noise(frame)
        for s in self.slots:
            s.seen = SEEN_NONE
        self.broken_obs = []
        rows, candidates = self.classify(frame, frame_dt)
        used_before = self.counters["observations_used"]
        reassoc_before = self.counters["frames_reassociated"]
        ok = self.fuse(frame, rows)
        if not ok:
            self.counters["updates_refused"] += 1
        if not ok or self.counters["frames_reassociated"] != reassoc_before:
            self.failed_frame_run += 1
        elif self.counters["observations_used"] != used_before:
            self.failed_frame_run = 0
        if self.cfg["divergence_frames"] > 0 and self.failed_frame_run >= self.cfg["divergence_frames"]:
            raise ReferenceError("divergence reset: not modelled")
        self.retire()
        self.admit(frame, candidates)
        self.frame_R, self.frame_p = self.R.copy(), self.p.copy()
        return ok

    def repeats_previous(self, frame):
        """The frame repeats the previous one's pixels exactly on every id the two share (at least one)."""
        common = 0
        for o in frame:
            for q in self.prev_frame:
                if q[0] == o[0]:
                    if np.any(q[1:] != o[1:]):
                        return False
                    common += 1
                    break
        return common > 0

    def repeat_noise(self, frame):
        """The tracker re-anchors the tracks a repeated image carries: the landmarks it observes
        move together by one rigid motion about the vehicle, delta l_a = rho + phi x (l_a - p), with
        rho and phi isotropic of s^2 times the squared step (dp, dphi) from the previous frame's pose
        (s = repeat_anchor_noise); added to the landmark blocks of P: Q_ab = G_a Sigma G_b^T."""
        carried = self.observed_slots(frame)
        dR = self.R @ self.frame_R.T
        w = 0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
        angle = math.atan2(math.sqrt(w @ w), min(1.0, max(-1.0, 0.5 * (np.trace(dR) - 1.0))))
        dp = self.p - self.frame_p
        s2 = self.cfg["repeat_anchor_noise"] ** 2
        Sigma = np.diag([s2 * (dp @ dp)] * 3 + [s2 * angle * angle] * 3)
        G = np.zeros((self.n, 6))
        for s in carried:
            c = CORE_DIM + 3 * s
            G[c:c + 3] += np.hstack([np.eye(3), -hat3(self.L[s] - self.p)])
        self.P = self.P + G @ Sigma @ G.T

    def observed_slots(self, frame):
        """The window slots the frame observes, in the frame's order (at most one per slot)."""
        out = []
        for o in frame:
            if len(out) >= len(self.slots):
                break
            for s, slot in enumerate(self.slots):
                if slot.id == int(o[0]):
                    out.append(s)
                    break
        return out

    def carried_walk(self):
        """Each frame, a landmark whose track a repeated image carried gets the tracker's wander of
        s = repeat_track_walk px in its camera's x, y and disparity: at depth z, (z s / fx, z s / fy)
        across and z^2 s / (fx b) in depth, to the world by A = R Rc^T; on its own block of P."""
        s, cal = self.cfg["repeat_track_walk"], self.cal
        A = self.R @ cal.Rc.T
        for k, slot in enumerate(self.slots):
            if not slot.carried:
                continue
            _, c = self.camera_point(self.L[k])
            if c is None:
                continue
            z = c[2]
            q = np.array([(z * s / cal.fx) ** 2, (z * s / cal.fy) ** 2, (z * z * s / (cal.fx * cal.baseline)) ** 2])
            i = CORE_DIM + 3 * k
            self.P[i:i + 3, i:i + 3] += A @ np.diag(q) @ A.T

    def _plausible(self, o):
        """The image (2 cx by 2 cy unless configured) widened by image_margin, and max_disparity."""
        m = self.cfg["image_margin"]
        w = (self.cfg["image_width"] or 2.0 * self.cal.cx) + m
        h = (self.cfg["image_height"] or 2.0 * self.cal.cy) + m
        _, ul, vl, ur, vr = o
        return (-m <= ul <= w and -m <= ur <= w and -m <= vl <= h and -m <= vr <= h
                and ul - ur <= self.cfg["max_disparity"])

    def _admissible(self, disparity):
        return (disparity >= self.cfg["min_disparity"]
                and self.cal.fx * self.cal.baseline / disparity <= self.cfg["max_depth"])

    def classify(self, frame, frame_dt):
        """Observations of window landmarks become rows; the others continue (or start) pending
        tracks, which become candidates after min_track_length frames (at first sight in a frame of
        fewer than first_sight_below observations) if consistent."""
        rows, candidates = [], []
        # a sparse frame admits its new tracks at first sight
        min_track_length = 1 if len(frame) < self.cfg["first_sight_below"] else self.cfg["min_track_length"]
        slot_of = {s.id: k for k, s in enumerate(self.slots)}
        for i, o in enumerate(frame):
            oid = int(o[0])
            if not _valid(o) or not self._plausible(o):
                continue
            disparity = o[1] - o[3]
            slot = slot_of.get(oid)
            if slot is not None:
                s = self.slots[slot]
                if s.seen != SEEN_NONE:
                    continue  # the same id twice in one frame
                s.seen, s.unseen_frames = SEEN, 0
                s.observations += 1
                if not disparity > 0.0:
                    continue
                row = self.make_row(slot, frame, i)
                if row is None:
                    continue
                # a landmark a sparse frame admitted at first sight must agree with itself before
                # any update uses it (a track on a moving object breaks here)
                if i in self.moved or (len(frame) < self.cfg["first_sight_below"] and s.observations == 2
                                       and s.updates == 0 and not self._second_sight_consistent(slot, o, frame_dt)):
                    s.seen = SEEN_BROKEN
                    self.broken_obs.append(i)
                    continue
                rows.append(row)
                continue
            t, duplicate = self._pending_touch(oid)
            if duplicate:
                continue
            if not self._admissible(disparity):
                if t is not None:
                    t.frames_seen = 0  # no usable point to compare the next observation with
                continue
            if t is None:
                continue
            y = compress(o)
            if t.frames_seen >= 2 and not self._track_consistent(t, y, frame_dt):
                t.frames_seen = 1
            t.point, J = self.triangulate_world(y)
            t.cov = J @ np.diag(stereo_noise(self.var_px)) @ J.T
            if t.frames_seen >= min_track_length and len(candidates) < MAX_FRAME_FEATURES and not self._moving(i):
                age = min(t.frames_seen - 1, AGE_CAP)
                candidates.append((i, disparity * (1.0 + AGE_BONUS * age)))
        return rows, candidates

    def _second_sight_consistent(self, slot, o, dt):
        """Its two triangulations at the stereo rows' white noise (each sighting), plus one frame of
        the velocity noise at its lever arm, within the update's gate."""
        if not self.var_rows > 0.0 or self.cfg["gate_chi2"] <= 0.0:
            return True
        pw, J = self.triangulate_world(compress(o))
        S = J @ np.diag(2.0 * stereo_noise(self.var_rows)) @ J.T
        d = pw - self.L[slot]
        lever = pw - self.p
        S = S + np.eye(3) * (self.var_v + float(lever @ lever) * self.var_w) * dt * dt
        return mahalanobis3(S, d) <= self.cfg["gate_chi2"]

    def _pending_touch(self, oid):
        for t in self.pending:
            if t.id == oid:
                if t.last_frame == self.frame_index:
                    return t, True
                t.frames_seen += 1
                t.last_frame = self.frame_index
                return t, False
        if len(self.pending) >= MAX_PENDING:
            return None, False
        t = Pending(oid, 1, self.frame_index)
        self.pending.append(t)
        return t, False

    def _track_consistent(self, t, y, dt):
        """Does the observation agree with the point the track's previous observation gave? The
        gate on S = Hx C Hx^T + Hp diag(s_v^2 dt^2, s_w^2 dt^2) Hp^T + R (one step of motion)."""
        if self.cfg["gate_chi2"] <= 0.0:
            return True
        b, c = self.camera_point(t.point)
        if b is None:
            return False
        y_pred, dy_dc = stereo_project(self.cal, c)
        dy_db = dy_dc @ self.cal.Rc
        odot = np.hstack([np.eye(3), -hat3(b)])        # d b / d xi (right perturbation) = -odot(b)
        Hp = -dy_db @ odot
        Hx = dy_db @ self.R.T
        Qm = np.diag([self.var_v * dt * dt] * 3 + [self.var_w * dt * dt] * 3)
        S = Hx @ t.cov @ Hx.T + Hp @ Qm @ Hp.T + np.diag(stereo_noise(self.var_px))
        return mahalanobis3(S, y - y_pred) <= self.cfg["gate_chi2"]

    # ---- outliers and the joint update (vl_outliers.c, vl_update.c, vl_noise.c)

    def update_and_adapt(self, rows, used, rejected, frame_observations):
        """The joint update on rows[:used], then the noise adaptation from the used and the rejected
        rows (frame_observations: the frame's own count)."""
        prior_pose = self.P[:6, :6].copy()
        ok = self.apply(rows[:used])
        if ok and used > 0 and self.cfg["adaptive_noise"]:
            self.adapt_pixel_noise(rows[:used], rejected, frame_observations)
            self.adapt_velocity_noise(prior_pose, used)
        return ok

    def fuse(self, frame, rows):
        """Gate; a re-associated frame is distrusted as a whole; otherwise RANSAC picks the inliers,
        the joint update runs on at most max_update_observations of them, the noise adapts, and the
        rejected rows that agree with the corrected state are rescued in a second update."""
        cfg, k = self.cfg, len(rows)
        if k == 0:
            return True
        if cfg["gate_chi2"] <= 0.0:  # no outlier rejection at all (the seed's plain EKF)
            return self.update_and_adapt(rows, k, [], len(frame))
        inlier = [mahalanobis3(self.innovation_cov(r), r.residual) <= cfg["gate_chi2"] for r in rows]
        failed = k - sum(inlier)
        if k >= MIN_ROWS_FOR_REASSOCIATION and failed > cfg["max_broken_fraction"] * k:
            self.counters["frames_reassociated"] += 1
            for r in rows:
                self.slots[r.slot].seen = SEEN_BROKEN
                self.broken_obs.append(r.obs)
            if cfg["adaptive_noise"]:
                self.reassociated_run += 1
                if self.reassociated_run >= CONTRADICTION_RUN:
                    self.widen_noise()
            return True
        self.reassociated_run = 0
        if cfg["ransac_hypotheses"] > 0 and k >= 2:
            inlier = self.ransac(rows, inlier)
        # The C partition swaps each inlier to the front: inliers keep their order, the rest do not.
        m = 0
        for i in range(k):
            if inlier[i]:
                rows[m], rows[i] = rows[i], rows[m]
                inlier[m], inlier[i] = inlier[i], inlier[m]
                m += 1
        partitioned, rest = m, k - m
        cap = self.rows_cap()
        used = partitioned
        if cap > 0 and partitioned > cap:  # the time bound
            if cfg["rotate_deferred"]:
                self.keep_least_used(rows, partitioned, cap)
            else:  # an evenly spread subset
                for i in range(cap):
                    j = (i * partitioned) // cap
                    rows[i], rows[j] = rows[j], rows[i]
            used = cap
            self.hold(rows[used:partitioned])
        ok = self.update_and_adapt(rows, used, rows[partitioned:], len(frame))
        if not ok or rest == 0:
            return ok
        rescued = []
        for r in rows[partitioned:]:
            row = self.make_row(r.slot, frame, r.obs)
            if row is None:
                continue
            if mahalanobis3(self.innovation_cov(row), row.residual) <= cfg["gate_chi2"]:
                rescued.append(row)
            else:
                self.slots[r.slot].seen = SEEN_BROKEN
                self.broken_obs.append(r.obs)
        if cap > 0 and used + len(rescued) > cap:
            self.hold(rescued[cap - used:])
            rescued = rescued[:cap - used]
        return self.apply(rescued)

    def hold(self, rows):
        """vl_rows_hold: the deferred rows' observations, for update_deferred (apply_deferred)."""
        if self.cfg["apply_deferred"]:
            self.held += [r.obs for r in rows]

    def update_deferred(self):
        """vl_update_deferred, after the frame's pose: the held observations as rows at the corrected
        state, those that pass the gate again, at most what max_deferred_work allows; the innovation
        ratio is not the reference's, so nothing else moves."""
        held, self.held = self.held, []
        if not held:
            return True
        slot_of = {s.id: k for k, s in enumerate(self.slots)}
        rows = []
        for i in held:
            slot = slot_of.get(int(self.held_frame[i][0]))
            row = None if slot is None else self.make_row(slot, self.held_frame, i)
            if row is None:
                continue
            if self.cfg["gate_chi2"] > 0.0 and mahalanobis3(self.innovation_cov(row), row.residual) > self.cfg["gate_chi2"]:
                continue
            rows.append(row)
        if self.cfg["max_deferred_work"] > 0.0:
            rows = rows[:self.rows_fitting(self.cfg["max_deferred_work"])]
        ok = self.apply(rows)
        if ok:
            self.counters["observations_deferred_used"] += len(rows)
        return ok

    def keep_least_used(self, rows, m, cap):
        """rotate_deferred: of the first m rows, the cap whose landmarks the updates used least
        (then longest ago; the earlier of equal rows) move to the front, in their order."""
        def key(i):
            slot = self.slots[rows[i].slot]
            return (slot.updates, slot.last_update_frame, i)
        keep = [False] * m
        for i in sorted(range(m), key=key)[:cap]:
            keep[i] = True
        front = 0
        for i in range(m):
            if keep[i]:
                rows[front], rows[i] = rows[i], rows[front]
                keep[front], keep[i] = True, keep[front]
                front += 1

    def rows_cap(self):
        """The most observations one update may use (0: all): max_update_observations, and under
        max_update_work the largest count whose update (joint_update_flops) fits the budget, at
        least one."""
        cap = int(self.cfg["max_update_observations"])
        if self.cfg["max_update_work"] > 0.0:
            k = self.rows_fitting(self.cfg["max_update_work"])
            if cap == 0 or k < cap:
                cap = k
        return cap

    def rows_fitting(self, mflop):
        """The most observations whose joint update (joint_update_flops) fits mflop, at least one."""
        n, budget, k = CORE_DIM + 3 * len(self.slots), mflop * 1e6, 1
        while k < MAX_FRAME_FEATURES and joint_update_flops(n, k + 1) <= budget:
            k += 1
        return k

    def ransac(self, rows, inlier):
        """1-point RANSAC: each hypothesis is the correction one observation alone would give,
        dx = P H^T S^-1 r; its support, the rows left within ransac_threshold px. The best support
        replaces the gate's flags only when it holds at least RANSAC_MIN_CONSENSUS rows (a hypothesis
        always supports its own row). The frame index seeds splitmix64, so a replay draws the same
        hypotheses."""
        k = len(rows)
        thr2 = self.cfg["ransac_threshold"] ** 2
        H = [np.hstack([r.H_pose, r.H_landmark]) for r in rows]
        cols = [np.r_[0:6, CORE_DIM + 3 * r.slot:CORE_DIM + 3 * r.slot + 3] for r in rows]
        best, state = 0, self.frame_index
        for _ in range(min(int(self.cfg["ransac_hypotheses"]), k)):
            state, draw = splitmix64(state)
            pick = draw % k
            PHt = self.P[:, cols[pick]] @ H[pick].T
            S = H[pick] @ PHt[cols[pick]] + np.diag(rows[pick].noise)
            try:
                Lc = np.linalg.cholesky(S)
            except np.linalg.LinAlgError:
                continue
            w = np.linalg.solve(Lc.T, np.linalg.solve(Lc, rows[pick].residual))
            dx = PHt @ w
            flags = [float(np.sum((r.residual - Hi @ dx[ci]) ** 2)) <= thr2 for r, Hi, ci in zip(rows, H, cols)]
            if sum(flags) > best and sum(flags) >= RANSAC_MIN_CONSENSUS:
                best, inlier = sum(flags), flags
        return inlier

    def apply(self, rows):
        """The joint update: S = H P H^T + R = L L^T, W = P H^T L^-T, dx = W L^-1 r, P <- P - W W^T;
        then X <- exp(dx) X on SE_{N+1}(3): T <- exp(dx_pose) T, and every landmark turns with the
        rotation correction and moves by J_l(phi) times its own translation correction."""
        if not rows:
            return True
        n, m = self.n, 3 * len(rows)
        H = np.zeros((m, n))
        for j, r in enumerate(rows):
            c = CORE_DIM + 3 * r.slot
            H[3 * j:3 * j + 3, 0:6] = r.H_pose
            H[3 * j:3 * j + 3, c:c + 3] = r.H_landmark
        PHt = self.P @ H.T
        S = H @ PHt + np.diag(np.concatenate([r.noise for r in rows]))
        try:
            Lc = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            return False
        W = np.linalg.solve(Lc, PHt.T).T
        dx = W @ np.linalg.solve(Lc, np.concatenate([r.residual for r in rows]))
        if not np.all(np.isfinite(dx)):
            return False
        self.P = _symmetric(self.P - W @ W.T)
        self.dx = dx
        dR, dp = se3_exp(dx[:6])
        Jl = so3_left_jacobian(dx[3:6])
        self.R = so3_normalize(dR @ self.R)
        self.p = dR @ self.p + dp
        self.b_v = self.b_v + dx[6:9]
        self.b_w = self.b_w + dx[9:12]
        self.s = self.s + dx[12:15]
        self.L = self.L @ dR.T + dx[CORE_DIM:].reshape(-1, 3) @ Jl.T
        for r in rows:
            self.slots[r.slot].updates += 1
            self.slots[r.slot].last_update_frame = self.frame_index
        self.counters["observations_used"] += len(rows)
        return True

    def adapt_pixel_noise(self, used, rejected, frame_observations):
        """Residual-based covariance matching: after the update, a used row's post-fit residual e
        has E[e^2] = R_rr - (H P+ H^T)_rr, a rejected row's E[e^2] = R_rr + (H P+ H^T)_rr, so
        (e^2 +- (H P+ H^T)_rr) / share is a sample of the pixel variance; on a sparse frame, whose
        fit absorbs much of each row, R_rr e^2 / E[e^2] / share instead (rows expected to keep under
        5 % of R_rr left out). The median over the used and the rejected rows (the deferred ones
        left out), each capped at 100 variances in use (a frame of one or two rows has no majority
        to outvote an outlier), / 0.455, enters an average that forgets faster the more rows there
        are (PIXEL_NOISE_FAST_MEMORY instead of PIXEL_NOISE_MEMORY observations while its std is over
        PIXEL_FAR_FROM_ROWS times the stereo rows'). A frame is sparse under PIXEL_SPARSE_FRAME observations. A dense frame's sample (floored
        at a hundredth of the estimate) also enters a fast average of its log-ratio to the estimate;
        under -log(PIXEL_DROP_RATIO) the estimate goes to exp(average) times itself, the average to 0."""
        sparse = frame_observations < PIXEL_SPARSE_FRAME
        samples = []
        for rows, fitted in ((used, 1.0), (rejected, -1.0)):
            for r in rows:
                S = self.innovation_cov(r)
                c = CORE_DIM + 3 * r.slot
                e = r.residual - r.H_pose @ self.dx[:6] - r.H_landmark @ self.dx[c:c + 3]
                fit = np.diag(S) - r.noise
                if not sparse:
                    samples.extend((e * e + fitted * fit) / STEREO_SHARE)
                    continue
                expected = r.noise - fitted * fit
                keep = expected > PIXEL_MIN_RESIDUAL_SHARE * r.noise
                samples.extend((r.noise * e * e / np.where(keep, expected, 1.0) / STEREO_SHARE)[keep])
        if len(samples) < 3:
            return
        samples = np.minimum(np.array(samples), PIXEL_SAMPLE_CAP * self.var_px)
        median = np.partition(samples, len(samples) // 2)[len(samples) // 2] / CHI2_1_MEDIAN
        # a median at or under zero (most rows rejected ones that kept less than the fit's spread)
        # says the noise is small against that spread, not what it is: floored as the cap mirrors
        sample = max(median, self.var_px / PIXEL_SAMPLE_CAP)
        if not sparse:
            r = math.log(sample / self.var_px)
            self.px_log_ratio = (1.0 - PIXEL_DROP_GAIN) * self.px_log_ratio + PIXEL_DROP_GAIN * r
            if self.px_log_ratio < -math.log(PIXEL_DROP_RATIO):
                self.var_px = _clamp_var(self.var_px * math.exp(self.px_log_ratio), self.cfg["pixel"])
                self.px_log_ratio = 0.0
                return
        far = self.var_rows > 0.0 and self.var_px > PIXEL_FAR_FROM_ROWS ** 2 * self.var_rows
        w = 1.0 - math.exp(-(len(samples) // 3) / (PIXEL_NOISE_FAST_MEMORY if far else PIXEL_NOISE_MEMORY))
        self.var_px = _clamp_var((1.0 - w) * self.var_px + w * sample, self.cfg["pixel"])

    # ---- the sparse frames' two-view velocity noise (core/src/vl_noise_two_view.c)

    def observe_stereo_rows(self, frame):
        """(v_left - v_right)^2 / 2 of each valid observation: pixel noise alone. The first frame of
        3 or more sets the estimate by its median; later ones by their mean, each sample capped at
        STEREO_ROW_CAP estimates; evidence-weighted over STEREO_ROW_MEMORY observations."""
        samples = np.array([0.5 * (o[2] - o[4]) ** 2 for o in frame if _valid(o) and self._plausible(o)])
        n = len(samples)
        if n < TWO_VIEW_MIN_PAIRS:
            return
        if self.rows_evidence > 0.0:
            sample = float(np.minimum(samples, STEREO_ROW_CAP * self.var_rows).sum()) / n
        else:
            sample = np.partition(samples, n // 2)[n // 2] / CHI2_1_MEDIAN
        if not sample > 0.0:
            return
        held = self.rows_evidence * math.exp(-n / STEREO_ROW_MEMORY)
        w = n / (held + n)
        self.var_rows = (1.0 - w) * self.var_rows + w * sample
        self.rows_evidence = held + n

    def _usable(self, o):
        """Valid, plausible, and with the disparity a landmark needs."""
        return _valid(o) and self._plausible(o) and o[1] - o[3] >= self.cfg["min_disparity"]

    def carry_drift(self, frame):
        """A sparse frame's drift sums start empty, but a track the previous (sparse) frame found
        moving on its own stays so: it is not admitted again (it was broken when found)."""
        self.drift = {}
        if len(frame) >= VELOCITY_DENSE_FRAME or not self.prev_drift:
            return
        for i, o in enumerate(frame):
            j = next((j for j, x in enumerate(self.prev_frame) if x[0] == o[0]), None)
            if j is not None and j in self.prev_drift and self.prev_drift[j][3]:
                self.drift[i] = [np.zeros(3), np.zeros((3, 3)), 0, True]

    def drift_step(self, i, j, r, S):
        """A track's two-view residual r (rows clipped at DRIFT_CLIP of their stds) and its expected
        covariance S added to the sums the previous frame held for it; from DRIFT_MIN_FRAMES on, a
        sum over DRIFT_CHI2 is a track moving on its own (self.moved), and stays so."""
        if i in self.drift and self.drift[i][3]:
            return
        prev = self.prev_drift.get(j)
        c = DRIFT_CLIP * np.sqrt(np.diag(S))
        d = [(prev[0] if prev else 0.0) + np.clip(r, -c, c), (prev[1] if prev else 0.0) + S,
             (prev[2] if prev else 0) + 1, False]
        if d[2] >= DRIFT_MIN_FRAMES and not mahalanobis3(d[1], d[0]) <= DRIFT_CHI2:
            d = [np.zeros(3), np.zeros((3, 3)), 0, True]
            self.moved.add(i)
        self.drift[i] = d

    def _moved_against_the_others(self, terms, kept):
        """The observations whose track's residual against the motion the other kept tracks fit (at
        its white noise plus that fit's covariance) is beyond the gate; none when half or more are."""
        n = len(terms)
        if n < TWO_VIEW_MIN_PAIRS + 1 or self.cfg["gate_chi2"] <= 0.0:
            return set()
        moved = set()
        for t in terms:
            others = [u for u in kept if u is not t]
            if len(others) < TWO_VIEW_MIN_PAIRS:
                continue
            info = sum(u[0] for u in others)
            b = sum(u[1] for u in others)
            try:
                np.linalg.cholesky(info)
            except np.linalg.LinAlgError:
                continue
            C = np.linalg.inv(info)
            Hw, rw = t[5], t[6]
            if not mahalanobis3(np.eye(3) + Hw @ C @ Hw.T, rw - Hw @ (C @ b)) <= self.cfg["gate_chi2"]:
                moved.add(t[4])
        return moved if 2 * len(moved) < n else set()

    def expected_motion_error(self):
        """The motion error the filter expects over the interval, per body axis: the diagonal of
        T Q T^T, Q the input noise (the velocity variance x sum tau^2) plus the parameters' error
        J P_tt J^T, J = [sum tau I, (hat(sum tau w); 0)], T = [I hat(p); 0 I] the input map of a
        velocity sensor at p (identity at the origin), through which the angular noise and offsets
        reach the linear motion."""
        Q = np.diag([self.var_v * self.step_t2] * 3 + [self.var_w * self.step_t2] * 3)
        if self.cfg["estimate_input_offsets"]:
            Q = Q + self.P[6:12, 6:12] * self.step_t * self.step_t
        if self.sensor_estimated:
            Js = np.zeros((6, 3))
            Js[:3] = hat3(self.step_turn)
            cross = self.step_t * Js @ self.P[12:15, 6:12]
            Q = Q + Js @ self.P[12:15, 12:15] @ Js.T + cross + cross.T
        sensor = self.s
        if np.any(sensor != 0.0):
            T = np.eye(6)
            T[:3, 3:] = hat3(sensor)
            Q = T @ Q @ T.T
        return np.diag(Q).copy()

    def adapt_velocity_two_view(self, frame, contradicted):
        """A sparse frame's tracks in both views, r = y - h(predicted motion, previous triangulation)
        = H delta + e (delta the right perturbation of the predicted pose, e both sightings' pixel
        noise at the stereo rows' estimate): a weighted least-squares fit of delta and its
        covariance C; each block matched against C plus the expected motion error q
        (expected_motion_error). Tracks that alone contradict q are left
        out (their observations go to contradicted), and broken (self.moved) when they did so in the
        previous frame too, as are those that contradict the others' fit; a frame whose fit
        residual exceeds its 99 % chi-square quantile is not matched."""
        if len(frame) >= VELOCITY_DENSE_FRAME or not self.var_rows > 0.0 or not self.step_t2 > 0.0:
            return False
        nv = stereo_noise(self.var_rows)
        q = self.expected_motion_error()
        cal, terms = self.cal, []
        for i, o in enumerate(frame):
            if not self._usable(o):
                continue
            j = next((j for j, x in enumerate(self.prev_frame) if x[0] == o[0]), None)
            if j is None or not self._usable(self.prev_frame[j]):
                continue
            prev = self.prev_frame[j]
            pw, dpw_dy = self.triangulate_world(compress(prev), self.frame_R, self.frame_p)
            b, cc = self.camera_point(pw)
            if b is None:
                continue
            y_pred, dy_dc = stereo_project(cal, cc)
            dy_db = dy_dc @ cal.Rc
            H = -dy_db @ np.hstack([np.eye(3), -hat3(b)])
            A = dy_db @ self.R.T @ dpw_dy
            W = A @ np.diag(nv) @ A.T + np.diag(nv)
            r = compress(o) - y_pred
            S = W + H @ np.diag(q) @ H.T
            chi2 = mahalanobis3(S, r)
            try:
                L = np.linalg.cholesky(W)
            except np.linalg.LinAlgError:
                continue
            Hw, rw = np.linalg.solve(L, H), np.linalg.solve(L, r)
            terms.append((Hw.T @ Hw, Hw.T @ rw, float(rw @ rw), chi2, i, Hw, rw, j, r, S))
        contradicting = sum(not t[3] <= self.cfg["gate_chi2"] for t in terms)
        drop = 2 * contradicting < len(terms) and self.cfg["gate_chi2"] > 0.0
        out = [drop and not t[3] <= self.cfg["gate_chi2"] for t in terms]
        kept = [t for t, o in zip(terms, out) if not o]
        # a track that alone contradicts q in two frames in a row moves on its own
        left_out = [t for t, o in zip(terms, out) if o]
        contradicted.update(t[4] for t in left_out)
        self.moved = self._moved_against_the_others(terms, kept)
        self.moved.update(t[4] for t in left_out if t[7] in self.contradicted)
        for t in terms:
            self.drift_step(t[4], t[7], t[8], t[9])
        if len(kept) < TWO_VIEW_MIN_PAIRS:
            return False
        info = sum(t[0] for t in kept)
        bvec = sum(t[1] for t in kept)
        try:
            np.linalg.cholesky(info)
        except np.linalg.LinAlgError:
            return False
        C = np.linalg.inv(info)
        dx = C @ bvec
        fit = sum(t[2] for t in kept) - float(bvec @ dx)
        if not fit <= _chi2_quantile_99(3 * len(kept) - 6):
            return True
        for blk, (name, key) in enumerate((("var_v", "linear_velocity"), ("var_w", "angular_velocity"))):
            sl = slice(3 * blk, 3 * blk + 3)
            noise = getattr(self, name) * self.step_t2
            M = C[sl, sl] + np.diag(q[sl])
            expected = float(np.trace(M))
            spread = float((M * M).sum())
            if not expected > 0.0 or not spread > 0.0 or not noise > 0.0:
                continue
            if self._moment_rise(blk, name, key, float(dx[sl] @ dx[sl]), expected, spread):
                continue
            ratio = min(max(float(dx[sl] @ dx[sl]) / expected, VELOCITY_RATIO_MIN), VELOCITY_RATIO_MAX)
            step = TWO_VIEW_GAIN * 3.0 * noise / expected * (math.log(ratio) + log_ratio_bias(expected * expected / spread))
            setattr(self, name, _clamp_var(getattr(self, name) * math.exp(step), self.cfg[key]))
        self.reopen_angular_offset()
        return True

    def _moment_rise(self, blk, name, key, seen, expected, spread):
        """The frame enters the block's moment estimate of its variance, E[seen] = c + var a, least
        squares over the frames weighted by 1 / (2 tr M^2), seen capped at VELOCITY_RATIO_MAX x its
        expectation; once it holds TWO_VIEW_MOMENT_MIN_FRAMES frames and lies over
        TWO_VIEW_MOMENT_RISE x the variance in use, it replaces it (upwards only). True when it did."""
        var = getattr(self, name)
        keep = math.exp(-1.0 / TWO_VIEW_MOMENT_MEMORY)
        a, w = 3.0 * self.step_t2, 1.0 / (2.0 * spread)
        capped = min(seen, VELOCITY_RATIO_MAX * expected)
        self.moment_num[blk] = keep * self.moment_num[blk] + w * a * (capped - (expected - var * a))
        self.moment_den[blk] = keep * self.moment_den[blk] + w * a * a
        self.moment_frames[blk] = keep * self.moment_frames[blk] + 1.0
        estimate = self.moment_num[blk] / self.moment_den[blk]
        if self.moment_frames[blk] < TWO_VIEW_MOMENT_MIN_FRAMES or not estimate > TWO_VIEW_MOMENT_RISE * var:
            return False
        setattr(self, name, _clamp_var(estimate, self.cfg[key]))
        return True

    def adapt_velocity_noise(self, prior_pose, used):
        """Covariance matching on the pose correction, E[dx dx^T] = P- - P+ = M: each block's variance
        moves by gain x (log(seen / expected) + bias), bias = -E[log clamp(chi2_k / k, 0.1, 10)] with
        k = tr(M)^2 / tr(M^2), zero on average when the filter is right. A dense frame is matched in
        the body frame (Ad(T^-1)), where the velocity noise enters, at a fixed gain; a sparse one in
        the world frame, its gain weighted by the share of the block's prior variance it removed."""
        M_world = prior_pose - self.P[:6, :6]
        dense = used >= VELOCITY_DENSE_FRAME
        if not dense and self.velocity_matched:
            return  # matched on the frame's two views before the update
        if dense:
            Ad_inv = se3_adjoint(self.R.T, -self.R.T @ self.p)
            M = Ad_inv @ M_world @ Ad_inv.T
            dx = Ad_inv @ self.dx[:6]
        else:
            M, dx = M_world, self.dx[:6]
        for b, (name, key) in enumerate((("var_v", "linear_velocity"), ("var_w", "angular_velocity"))):
            blk = slice(3 * b, 3 * b + 3)
            prior = np.trace(prior_pose[blk, blk])
            removed = np.trace(M_world[blk, blk])
            expected = np.trace(M[blk, blk])
            spread = float((M[blk, blk] * M[blk, blk]).sum())
            seen = float(dx[blk] @ dx[blk])
            if (not prior > 0.0 or not removed > VELOCITY_MIN_INFORMATION * prior or not expected > 0.0
                    or not spread > 0.0):
                continue
            ratio = min(max(seen / expected, VELOCITY_RATIO_MIN), VELOCITY_RATIO_MAX)
            gain = VELOCITY_NOISE_GAIN if dense else VELOCITY_SPARSE_GAIN * (removed / prior)
            step = gain * (math.log(ratio) + log_ratio_bias(expected * expected / spread))
            setattr(self, name, _clamp_var(getattr(self, name) * math.exp(step), self.cfg[key]))
        self.reopen_angular_offset()

    def widen_noise(self):
        """Frame after frame contradicting the prior: every noise x4, up to WIDEN_RANGE times the
        configured std (a level already above it stays), within the bounds."""
        def widen(var, std):
            top = (WIDEN_RANGE * std) ** 2
            wide = var * WIDEN_ON_CONTRADICTION
            return _clamp_var(wide if wide < top else max(var, top), std)
        self.var_v = widen(self.var_v, self.cfg["linear_velocity"])
        self.var_w = widen(self.var_w, self.cfg["angular_velocity"])
        self.var_px = widen(self.var_px, self.cfg["pixel"])
        self.reopen_angular_offset()

    def reopen_angular_offset(self):
        """The angular offsets were learned at the angular noise of their time: when the adapted
        angular variance rises past the highest it has been (at first REOPEN_RATIO x the configured
        one) by g, their rows and columns of P scale by sqrt(g), each variance up to its prior."""
        if not self.cfg["estimate_input_offsets"] or not self.var_w > self.var_w_reopened:
            return
        rise = self.var_w / self.var_w_reopened
        prior = self.cfg["angular_offset_prior"] ** 2
        self.var_w_reopened = self.var_w
        for i in range(9, 12):
            var = self.P[i, i]
            f2 = prior / var if var * rise > prior else rise
            if f2 > 1.0:
                f = math.sqrt(f2)
                self.P[i, :] *= f
                self.P[:, i] *= f

    # ---- the window (core/src/vl_window.c)

    def marginalize(self, slot):
        """Drop the landmark's rows and columns (the exact Gaussian marginal); the last slot moves
        into its place, as in the C code, so the slot order stays the same."""
        last = len(self.slots) - 1
        idx = np.arange(self.n)
        if slot != last:
            c, cl = CORE_DIM + 3 * slot, CORE_DIM + 3 * last
            idx[c:c + 3] = idx[cl:cl + 3]
            self.slots[slot] = self.slots[last]
            self.L[slot] = self.L[last]
        idx = idx[:-3]
        self.P = self.P[np.ix_(idx, idx)]
        self.slots.pop()
        self.L = self.L[:-1]

    def retire(self):
        """Tracks that broke or ended (unseen more than max_unseen_frames) leave the window."""
        for s in range(len(self.slots) - 1, -1, -1):
            slot = self.slots[s]
            if slot.seen == SEEN_BROKEN:
                self.marginalize(s)
            elif slot.seen == SEEN_NONE:
                slot.unseen_frames += 1
                if slot.unseen_frames > self.cfg["max_unseen_frames"]:
                    self.marginalize(s)

    def _moving(self, i):
        """The frame's observation i is on a track found moving on its own (not to admit)."""
        return i in self.drift and self.drift[i][3]

    def admit(self, frame, candidates):
        """Candidates (and restarts of broken tracks, by disparity) best first; when the window is
        full, room only by evicting a landmark not observed now (the longest unseen)."""
        for i in self.broken_obs:
            disparity = frame[i][1] - frame[i][3]
            if self._admissible(disparity) and len(candidates) < MAX_FRAME_FEATURES and not self._moving(i):
                candidates.append((i, disparity))
        candidates = sorted(candidates, key=lambda c: -c[1])  # stable, as the C insertion sort
        for i, _ in candidates:
            if len(self.slots) >= self.cfg["max_landmarks"]:
                victim, longest = -1, 0
                for s, slot in enumerate(self.slots):
                    if slot.seen == SEEN_NONE and slot.unseen_frames >= longest:
                        victim, longest = s, slot.unseen_frames
                if victim < 0:
                    break
                self.marginalize(victim)
            self.admit_landmark(int(frame[i][0]), compress(frame[i]))
            for t in self.pending:
                if t.id == int(frame[i][0]):
                    t.id = -1
                    break
        self.pending = [t for t in self.pending if t.last_frame == self.frame_index and t.id >= 0]

    def admit_landmark(self, oid, y):
        """l = R b + p from stereo; in invariant coordinates its error is rho plus the pixel part:
        P_ln = [I 0] P_pose,: and P_ll = P_rho,rho + J_y diag(R) J_y^T (exact to first order)."""
        l, J_obs = self.triangulate_world(y)
        n = self.n
        P = np.zeros((n + 3, n + 3))
        P[:n, :n] = self.P
        P[n:, :n] = self.P[0:3, :n]
        P[:n, n:] = P[n:, :n].T
        C = self.P[0:3, 0:3] + J_obs @ np.diag(stereo_noise(self.var_px)) @ J_obs.T
        P[n:, n:] = 0.5 * (C + C.T)
        self.P = P
        self.L = np.vstack([self.L, l])
        self.slots.append(Slot(oid, 0, SEEN, 0, self.frame_index))
        self.counters["landmarks_initialized"] += 1


def _valid(o):
    """vl_guard_observation_valid: a track id and finite pixels."""
    return o[0] >= 0 and bool(np.all(np.isfinite(o[1:])))


def _chi2_quantile_99(k):
    """The 99 % quantile of chi-square with k degrees of freedom (Wilson and Hilferty from k = 3)."""
    if k <= 0:
        return 0.0
    if k <= 2:
        return 6.635 if k == 1 else 9.210
    h = 2.0 / (9.0 * k)
    c = 1.0 - h + 2.3263 * math.sqrt(h)
    return k * c * c * c


def _symmetric(P):
    """The lower triangle mirrored, as the C code keeps P exactly symmetric."""
    lower = np.tril(P)
    return lower + np.tril(P, -1).T


def _clamp_var(var, configured_std):
    lo = configured_std ** 2 / NOISE_ADAPT_RANGE ** 2
    hi = configured_std ** 2 * NOISE_ADAPT_RANGE ** 2
    return min(max(var, lo), hi)


# ------------------------------------------------------------------------------------- runs

def read_log(path):
    """The inputs of an LCM log in order: ("calib", utime, Calibration), ("imu", utime, v, w) and
    ("frame", utime, array of (id, u_left, v_left, u_right, v_right))."""
    vislam, lcm = load(), load_lcm()
    events = []
    log = lcm.EventLog(str(path), "r")
    for ev in log:
        if ev.channel == channels.CALIBRATION:
            m = vislam.calibration_t.decode(ev.data)
            cal = Calibration(m.fx, m.fy, m.cx, m.cy, m.baseline, np.array(m.cam_T_imu, float).reshape(4, 4))
            events.append(("calib", m.utime, cal))
        elif ev.channel == channels.IMU:
            m = vislam.imu_t.decode(ev.data)
            events.append(("imu", m.utime, np.array(m.linear_velocity), np.array(m.angular_velocity)))
        elif ev.channel == channels.FEATURES:
            m = vislam.stereo_frame_t.decode(ev.data)
            k = m.num_features
            obs = np.column_stack([np.array(m.id[:k], float), m.u_left[:k], m.v_left[:k],
                                   m.u_right[:k], m.v_right[:k]]) if k else np.zeros((0, 5))
            events.append(("frame", m.utime, obs))
    log.close()
    return events


@dataclass
class Run:
    """What a reference run gives: one pose per used frame, and the time of every step (s)."""
    utimes: list
    rotations: list
    positions: list
    update_seconds: list
    propagate_seconds: list
    counters: dict


def run(events, cfg, max_steps=None):
    """Feeds the events to a Filter as vislam-run's session does: the first calibration starts it,
    inputs before it are dropped; one pose per frame whose update was not refused."""
    f = None
    out = Run([], [], [], [], [], {})
    frames = 0
    for ev in events:
        if ev[0] == "calib":
            if f is None:
                f = Filter(cfg, ev[2])
            elif not _same_calibration(ev[2], f.cal):
                raise ReferenceError("calibration changed: not modelled")
            continue
        if f is None:
            continue
        if ev[0] == "imu":
            t0 = time.perf_counter()
            f.propagate(ev[1], ev[2], ev[3])
            out.propagate_seconds.append(time.perf_counter() - t0)
            continue
        if f.state_utime is None:
            continue  # refused as VL_ERR_NOT_READY
        t0 = time.perf_counter()
        ok = f.update(ev[1], ev[2])
        out.update_seconds.append(time.perf_counter() - t0)
        if ok:
            out.utimes.append(ev[1])
            out.rotations.append(f.R.copy())
            out.positions.append(f.p.copy())
        else:
            f.held = []  # nothing after a refused update
        f.update_deferred()  # after the pose, as the session's vl_session_finish
        frames += 1
        if max_steps is not None and frames >= max_steps:
            break
    if f is not None:
        out.counters = dict(f.counters)
    return out


def _same_calibration(a, b):
    return (np.array_equal(a.cam_T_imu, b.cam_T_imu)
            and (a.fx, a.fy, a.cx, a.cy, a.baseline) == (b.fx, b.fy, b.cx, b.cy, b.baseline))


def tum_line(utime, R, p):
    """A trajectory line in vislam-run's format (time from the integer microseconds, %.9f)."""
    w, x, y, z = rot_to_quat(R)
    sign = "-" if utime < 0 else ""
    mag = abs(utime)
    return (f"{sign}{mag // 1000000}.{mag % 1000000:06d} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} "
            f"{x:.9f} {y:.9f} {z:.9f} {w:.9f}\n")


def write_tum(path, result):
    with open(path, "w") as f:
        for u, R, p in zip(result.utimes, result.rotations, result.positions):
            f.write(tum_line(u, R, p))
