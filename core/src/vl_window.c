/*
 * The bounded landmark window. A track becomes a landmark after min_track_length
 * frames (in a frame of fewer than first_sight_below observations, at first
 * sight) if its observations agree; when the window is full, candidates are
 * ranked by disparity (nearer points constrain translation better) times a bonus
 * for track age, and room is made only by evicting landmarks not observed in
 * this frame. A landmark whose track ended or broke is marginalized: its rows
 * and columns are dropped, the exact Gaussian marginal, and it goes to the map.
 */
#include "vl_window.h"

#include <string.h>

#include "vl_camera.h"
#include "vl_estimator_internal.h"
#include "vl_guard.h"
#include "vl_linalg.h"
#include "vl_noise.h"
#include "vl_predict.h"
#include "vl_se3.h"
#include "vl_stereo.h"
#include "vl_update.h"

/* Admission score bonus per frame of track age (frames seen before this one)... */
#define VL_ADMISSION_AGE_BONUS 0.5
/* ...counted up to this age: a track already seen 4 frames ranks at 3x its disparity. */
#define VL_ADMISSION_AGE_CAP 4u

int vl_window_find_slot(const vl_estimator_t *e, int32_t id)
{
    for (uint32_t s = 0; s < e->num_landmarks; ++s) {
        if (e->slots[s].id == id) {
            return (int)s;
        }
    }
    return -1;
}

/* World position and covariance: delta l = rho_i - hat(l) phi (or rho_i alone when mapping). */
void vl_window_landmark(const vl_estimator_t *e, uint32_t slot, vl_landmark_t *out)
{
    const vl_landmark_slot_t *s = &e->slots[slot];
    const double *l = vl_landmark_point(e, slot);
    memcpy(out->position, l, 3 * sizeof(double));
    double B[36]; /* over [phi, landmark]; between updates with the deferred prediction applied */
    vl_predict_landmark_block(e, slot, B);
    double J[18] = {0};
    if (e->cfg.mode != VL_MODE_MAPPING) {
        double S[9];
        vl_skew(l, S);
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) {
                J[6 * i + j] = -S[3 * i + j];
            }
        }
    }
    J[3] = J[6 + 4] = J[12 + 5] = 1.0;
    double JB[18];
    vl_matmul(J, B, JB, 3, 6, 6);
    vl_matmul_bt(JB, J, out->covariance, 3, 6, 3);
    out->id = s->id;
    out->observations = s->observations;
    out->first_utime = s->first_utime;
    out->last_utime = s->last_utime;
}

void vl_window_marginalize(vl_estimator_t *e, uint32_t slot)
{
    if (e->cfg.landmark_sink != NULL) {
        vl_landmark_t lm;
        vl_window_landmark(e, slot, &lm);
        e->cfg.landmark_sink(e->cfg.landmark_sink_user, &lm);
    }
    const uint32_t last = e->num_landmarks - 1u;
    if (slot != last) {
        vl_la_move_block(vl_P(e), VL_LD, (int)vl_state_dim(e), (int)vl_landmark_col(slot), (int)vl_landmark_col(last));
        e->slots[slot] = e->slots[last];
        memcpy(&e->landmark_state[3 * slot], &e->landmark_state[3 * last], 3 * sizeof(double));
        e->work_seen[slot] = e->work_seen[last];
    }
    e->num_landmarks--;
    e->counters.landmarks_marginalized++;
}

/*
 * The tracker's detection frame repeats the previous image, and every track it
 * carries resumes at the pixels its point had one step earlier in the camera: to
 * the filter, the carried points move together by the vehicle's step (on 0027 the
 * carried tracks then fit their points displaced that way as well as other tracks
 * fit theirs). Each carried landmark gets the noise of one rigid motion shared by
 * all of them, about the vehicle: delta l_a = rho + phi x a, a = l_a - p, with
 * rho ~ N(0, s^2 |dp|^2 I) and phi ~ N(0, s^2 |dphi|^2 I), (dp, dphi) the step
 * from the previous frame's pose. Hence, with hat(a) hat(b)^T = (a.b) I - b a^T,
 *     Q_ab = s^2 ((|dp|^2 + |dphi|^2 a.b) I - |dphi|^2 b a^T).
 * Shared, not independent per landmark: the tracks all show the same step, and
 * independent noise leaves the pose to explain what they have in common
 * (measured worse than none). A landmark's error in invariant coordinates is its
 * world error plus terms of the pose's, so Q adds to the landmark blocks alone.
 */
uint32_t vl_window_repeat_noise(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count)
{
    uint32_t carried[VL_MAX_LANDMARKS];
    uint32_t n = 0;
    for (uint32_t i = 0; i < count && n < e->num_landmarks; ++i) {
        const int slot = vl_window_find_slot(e, frame->obs[i].id);
        if (slot >= 0) {
            carried[n++] = (uint32_t)slot;
        }
    }
    if (n == 0) {
        return 0; /* also after a reset, which clears the window and the previous frame's pose */
    }
    double dR[9], dphi[3];
    vl_matmul_bt(e->R, e->frame_R, dR, 3, 3, 3);
    vl_so3_log(dR, dphi);
    const double dp[3] = {e->p[0] - e->frame_p[0], e->p[1] - e->frame_p[1], e->p[2] - e->frame_p[2]};
    const double s2 = e->cfg.repeat_anchor_noise * e->cfg.repeat_anchor_noise;
    const double qt = s2 * (dp[0] * dp[0] + dp[1] * dp[1] + dp[2] * dp[2]);
    const double qr = s2 * (dphi[0] * dphi[0] + dphi[1] * dphi[1] + dphi[2] * dphi[2]);
    for (uint32_t i = 0; i < n; ++i) {
        const double *la = vl_landmark_point(e, carried[i]);
        const double a[3] = {la[0] - e->p[0], la[1] - e->p[1], la[2] - e->p[2]};
        const uint32_t ca = vl_landmark_col(carried[i]);
        for (uint32_t j = 0; j <= i; ++j) {
            const double *lb = vl_landmark_point(e, carried[j]);
            const double b[3] = {lb[0] - e->p[0], lb[1] - e->p[1], lb[2] - e->p[2]};
            const uint32_t cb = vl_landmark_col(carried[j]);
            const double diag = qt + qr * (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]);
            for (uint32_t r = 0; r < 3; ++r) {
                for (uint32_t c = 0; c < 3; ++c) {
                    const double q = (r == c ? diag : 0.0) - qr * b[r] * a[c]; /* Q_ab(r, c) */
                    *vl_P_at(e, ca + r, cb + c) += q;
                    if (j != i) {
                        *vl_P_at(e, cb + c, ca + r) += q;
                    }
                }
            }
        }
    }
    return n;
}

void vl_window_mark_carried(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count)
{
    for (uint32_t i = 0; i < count; ++i) {
        const int slot = vl_window_find_slot(e, frame->obs[i].id);
        if (slot >= 0) {
            e->slots[slot].carried = 1;
        }
    }
}

/*
 * A carried track's pixels wander from the point it was triangulated at (README, Accuracy:
 * across a repeat each jumps by about a pixel, and a point displaced sideways errs more as
 * the camera comes closer). A wander of s px is, in the camera frame at depth z, z s / f
 * across and z^2 s / (f b) in depth; in the world Q = A diag(q) A^T with A = R Rc^T.
 */
uint32_t vl_window_carried_walk(vl_estimator_t *e)
{
    const vl_calibration_t *cal = &e->cfg.calibration;
    const double s = e->cfg.repeat_track_walk;
    double Rc[9], tc[3], A[9];
    vl_camera_extrinsics(cal, Rc, tc);
    uint32_t n = 0;
    for (uint32_t slot = 0; slot < e->num_landmarks; ++slot) {
        double b[3], c[3];
        if (!e->slots[slot].carried || vl_camera_point(e, Rc, tc, vl_landmark_point(e, slot), b, c) != 0) {
            continue; /* not carried, or behind the camera: no depth to scale by */
        }
        if (n == 0) {
            vl_matmul_bt(e->R, Rc, A, 3, 3, 3);
        }
        const double z = c[2];
        const double q[3] = {(z * s / cal->fx) * (z * s / cal->fx), (z * s / cal->fy) * (z * s / cal->fy),
                             (z * z * s / (cal->fx * cal->baseline)) * (z * z * s / (cal->fx * cal->baseline))};
        const uint32_t col = vl_landmark_col(slot);
        for (uint32_t r = 0; r < 3; ++r) {
            for (uint32_t k = 0; k <= r; ++k) { /* one value for both triangles: P stays exactly symmetric */
                const double add = A[3 * r] * q[0] * A[3 * k] + A[3 * r + 1] * q[1] * A[3 * k + 1] +
                                   A[3 * r + 2] * q[2] * A[3 * k + 2];
                *vl_P_at(e, col + r, col + k) += add;
                if (k != r) {
                    *vl_P_at(e, col + k, col + r) += add;
                }
            }
        }
        ++n;
    }
    return n;
}

/*
 * Admits a landmark from one stereo observation y (compressed): l = R b + p with
 * b the triangulated point in the IMU frame. In invariant coordinates its error is
 * rho (the pose's) plus the pixel part, so it gets the exact first-order
 * cross-covariance to every state through the pose translation error.
 */
static void admit_landmark(vl_estimator_t *e, int32_t id, const double y[3])
{
    const uint32_t slot = e->num_landmarks;
    vl_landmark_slot_t *s = &e->slots[slot];
    double *l = &e->landmark_state[3 * slot];
    double J_pose[18] = {0}, J_obs[9], noise[3];
    vl_camera_triangulate_world(e, y, l, J_obs);
    if (e->cfg.mode != VL_MODE_MAPPING) {
        for (int i = 0; i < 3; ++i) {
            J_pose[6 * i + VL_IDX_RHO + i] = 1.0;
        }
    }
    vl_stereo_noise_var(e->pixel_var, noise);
    vl_la_append_landmark(vl_P(e), VL_LD, (int)vl_state_dim(e), J_pose, J_obs, noise);

    s->id = id;
    s->observations = 1;
    s->unseen_frames = 0;
    s->updates = 0;
    s->carried = 0;
    s->last_update_frame = e->frame_index;
    s->first_utime = e->state_utime;
    s->last_utime = e->state_utime;
    e->work_seen[slot] = VL_SEEN;
    e->num_landmarks++;
    e->counters.landmarks_initialized++;
    if (e->num_landmarks > e->counters.window_peak) {
        e->counters.window_peak = e->num_landmarks;
    }
}

/* The candidate track of id, continued in this frame (or started); *duplicate when already seen in it. */
static vl_pending_track_t *pending_touch(vl_estimator_t *e, int32_t id, int *duplicate)
{
    *duplicate = 0;
    for (uint32_t i = 0; i < e->num_pending; ++i) {
        vl_pending_track_t *t = &e->pending[i];
        if (t->id == id) {
            if (t->last_frame == e->frame_index) {
                *duplicate = 1;
                return t;
            }
            t->frames_seen++;
            t->last_frame = e->frame_index;
            return t;
        }
    }
    if (e->num_pending >= VL_MAX_PENDING) {
        return NULL;
    }
    vl_pending_track_t *t = &e->pending[e->num_pending++];
    t->id = id;
    t->frames_seen = 1;
    t->last_frame = e->frame_index;
    return t;
}

/* Keeps only candidates seen in this frame: tracks have no gaps, an unseen one has ended. */
static void pending_compact(vl_estimator_t *e)
{
    uint32_t out = 0;
    for (uint32_t i = 0; i < e->num_pending; ++i) {
        if (e->pending[i].last_frame == e->frame_index && e->pending[i].id >= 0) {
            e->pending[out++] = e->pending[i];
        }
    }
    e->num_pending = out;
}

/* A pending track's world point and its covariance from pixel noise alone, from observation y. */
static void pending_triangulate(const vl_estimator_t *e, const double y[3], vl_pending_track_t *t)
{
    double J[9], nv[3], tmp[9];
    vl_camera_triangulate_world(e, y, t->point, J);
    vl_stereo_noise_var(e->pixel_var, nv);
    const double noise[9] = {nv[0], 0, 0, 0, nv[1], 0, 0, 0, nv[2]};
    vl_matmul(J, noise, tmp, 3, 3, 3);
    vl_matmul_bt(tmp, J, t->covariance, 3, 3, 3);
}

/*
 * Does a candidate's observation agree with the point its previous observation
 * gave? The comparison allows for that point's pixel noise, one step of motion
 * noise (dt seconds) and this observation's noise: the same gate as updates.
 */
static int track_consistent(const vl_estimator_t *e, const vl_pending_track_t *t, const double y[3], double dt)
{
    if (e->cfg.gate_chi2 <= 0.0) {
        return 1;
    }
    double y_pred[3], Hp[18], Hx[9];
    if (vl_camera_project_world(e, t->point, y_pred, Hp, Hx) != 0) {
        return 0;
    }
    double sv2, sw2;
    vl_step_velocity_var(e, &sv2, &sw2);
    sv2 *= dt * dt;
    sw2 *= dt * dt;
    double nv[3];
    vl_stereo_noise_var(e->pixel_var, nv);
    double S[9], tmp[9], HQ[18];
    vl_matmul(Hx, t->covariance, tmp, 3, 3, 3);
    vl_matmul_bt(tmp, Hx, S, 3, 3, 3);
    for (int r = 0; r < 3; ++r) {
        for (int j = 0; j < 6; ++j) {
            HQ[6 * r + j] = Hp[6 * r + j] * (j < VL_IDX_PHI ? sv2 : sw2);
        }
    }
    double HQH[9];
    vl_matmul_bt(HQ, Hp, HQH, 3, 6, 3);
    for (int i = 0; i < 9; ++i) {
        S[i] += HQH[i];
    }
    S[0] += nv[0];
    S[4] += nv[1];
    S[8] += nv[2];
    const double r[3] = {y[0] - y_pred[0], y[1] - y_pred[1], y[2] - y_pred[2]};
    return vl_mahalanobis3(S, r) <= e->cfg.gate_chi2;
}

/*
 * A landmark a sparse frame admitted at first sight has had no chance to show
 * that it stands still, and its first update would move the pose (and the
 * offsets) by whatever it did: a track on a moving object does the most harm
 * there (README, Accuracy). So its second sighting, before any update uses it,
 * must agree with its first: the two triangulations at the stereo rows' white
 * noise, one frame of the velocity noise in between. Without that noise
 * measured (no adaptation) every track passes.
 */
static int second_sight_consistent(const vl_estimator_t *e, uint32_t slot, const vl_stereo_obs_t *o, double dt)
{
    if (!(e->stereo_row_var > 0.0) || e->cfg.gate_chi2 <= 0.0) {
        return 1;
    }
    double y[3], pw[3], J[9], nv[3], JN[9], S[9], d[3], lever2 = 0.0;
    vl_stereo_compress(o, y);
    vl_camera_triangulate_world(e, y, pw, J);
    vl_stereo_noise_var(e->stereo_row_var, nv);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            JN[3 * i + j] = J[3 * i + j] * 2.0 * nv[j]; /* both sightings, each at the white noise */
        }
    }
    vl_matmul_bt(JN, J, S, 3, 3, 3);
    const double *l = vl_landmark_point(e, slot);
    for (int i = 0; i < 3; ++i) {
        d[i] = pw[i] - l[i];
        lever2 += (pw[i] - e->p[i]) * (pw[i] - e->p[i]);
    }
    double lin_var, ang_var;
    vl_step_velocity_var(e, &lin_var, &ang_var);
    const double motion = (lin_var + lever2 * ang_var) * dt * dt;
    for (int i = 0; i < 3; ++i) {
        S[4 * i] += motion;
    }
    return vl_mahalanobis3(S, d) <= e->cfg.gate_chi2;
}

/* A candidate for admission; a track found moving on its own is none (vl_noise_track_moving). */
static void add_candidate(const vl_estimator_t *e, vl_candidates_t *c, uint32_t obs, double score)
{
    if (c->count < VL_MAX_FRAME_FEATURES && !vl_noise_track_moving(e, obs)) {
        c->item[c->count].obs = obs;
        c->item[c->count].score = score;
        c->count++;
    }
}

/* Larger disparity (nearer, better conditioned) and longer tracks go first. */
static double admission_score(double disparity, uint32_t frames_seen)
{
    const uint32_t age = frames_seen - 1u;
    const uint32_t counted = age < VL_ADMISSION_AGE_CAP ? age : VL_ADMISSION_AGE_CAP;
    return disparity * (1.0 + VL_ADMISSION_AGE_BONUS * (double)counted);
}

static double depth_of(const vl_calibration_t *cal, double disparity)
{
    return cal->fx * cal->baseline / disparity;
}

static int disparity_admissible(const vl_estimator_t *e, double disparity)
{
    return disparity >= e->cfg.min_disparity && depth_of(&e->cfg.calibration, disparity) <= e->cfg.max_depth;
}

uint32_t vl_window_classify(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count, double frame_dt,
                            vl_candidates_t *candidates)
{
    vl_la_obs_t *rows = e->work_rows;
    uint32_t k = 0;
    const uint32_t min_track_length = count < e->cfg.first_sight_below ? 1u : e->cfg.min_track_length;
    for (uint32_t i = 0; i < count; ++i) {
        const vl_stereo_obs_t *o = &frame->obs[i];
        if (!vl_guard_observation_valid(o)) {
            e->counters.observations_invalid++;
            continue;
        }
        if (!vl_guard_observation_plausible(e, o)) {
            e->counters.observations_implausible++;
            continue;
        }
        const double disparity = o->u_left - o->u_right;
        const int slot = vl_window_find_slot(e, o->id);
        if (slot >= 0) {
            if (e->work_seen[slot] != VL_SEEN_NONE) {
                e->counters.observations_invalid++; /* the same id twice in one frame */
                continue;
            }
            e->work_seen[slot] = VL_SEEN;
            vl_landmark_slot_t *s = &e->slots[slot];
            s->unseen_frames = 0;
            s->last_utime = frame->utime;
            s->observations++;
            if (!(disparity > 0.0)) {
                e->counters.observations_low_disparity++;
                continue;
            }
            if (vl_update_make_row(e, (uint32_t)slot, o, &rows[k]) != 0) {
                e->counters.observations_behind_camera++;
                continue;
            }
            if (e->work_moved[i] || (count < e->cfg.first_sight_below && s->observations == 2u && s->updates == 0u &&
                                     !second_sight_consistent(e, (uint32_t)slot, o, frame_dt))) {
                e->counters.tracks_inconsistent++;
                vl_track_break(e, (uint32_t)slot, i);
                continue;
            }
            e->work_frame_obs[k] = i;
            e->work_slot[k] = (uint32_t)slot;
            k++;
            continue;
        }
        int duplicate = 0;
        vl_pending_track_t *t = pending_touch(e, o->id, &duplicate);
        if (duplicate) {
            e->counters.observations_invalid++;
            continue;
        }
        if (!disparity_admissible(e, disparity)) {
            e->counters.observations_low_disparity++;
            if (t != NULL) {
                t->frames_seen = 0; /* no usable point to compare the next observation with */
            }
            continue;
        }
        if (t == NULL) {
            continue; /* pending table full: the track is retried next frame */
        }
        double y[3];
        vl_stereo_compress(o, y);
        if (t->frames_seen >= 2 && !track_consistent(e, t, y, frame_dt)) {
            e->counters.tracks_inconsistent++;
            t->frames_seen = 1;
        }
        pending_triangulate(e, y, t);
        if (t->frames_seen >= min_track_length) {
            add_candidate(e, candidates, i, admission_score(disparity, t->frames_seen));
        }
    }
    return k;
}

void vl_window_retire(vl_estimator_t *e)
{
    /* Walk down: marginalizing moves the last slot into the freed one. */
    for (uint32_t s = e->num_landmarks; s-- > 0;) {
        if (e->work_seen[s] == VL_SEEN_BROKEN) {
            vl_window_marginalize(e, s);
            e->counters.tracks_broken++;
        } else if (e->work_seen[s] == VL_SEEN_NONE && ++e->slots[s].unseen_frames > e->cfg.max_unseen_frames) {
            vl_window_marginalize(e, s);
        }
    }
}

/* The unobserved landmark unseen longest, or -1: a landmark observed now is never evicted. */
static int eviction_victim(const vl_estimator_t *e)
{
    int victim = -1;
    uint32_t longest = 0;
    for (uint32_t s = 0; s < e->num_landmarks; ++s) {
        if (e->work_seen[s] == VL_SEEN_NONE && e->slots[s].unseen_frames >= longest) {
            longest = e->slots[s].unseen_frames;
            victim = (int)s;
        }
    }
    return victim;
}

void vl_window_admit(vl_estimator_t *e, const vl_stereo_obs_t *obs, vl_candidates_t *c)
{
    for (uint32_t b = 0; b < e->num_broken; ++b) {
        const vl_stereo_obs_t *o = &obs[e->work_broken[b]];
        const double disparity = o->u_left - o->u_right;
        if (disparity_admissible(e, disparity)) {
            add_candidate(e, c, e->work_broken[b], disparity);
        }
    }
    for (uint32_t i = 1; i < c->count; ++i) { /* insertion sort: stable, so deterministic */
        const vl_candidate_t item = c->item[i];
        uint32_t j = i;
        while (j > 0 && c->item[j - 1].score < item.score) {
            c->item[j] = c->item[j - 1];
            --j;
        }
        c->item[j] = item;
    }
    const uint32_t limit = e->cfg.max_admissions;
    for (uint32_t i = 0; i < c->count; ++i) {
        const vl_stereo_obs_t *o = &obs[c->item[i].obs];
        if (limit > 0 && i >= limit) {
            e->counters.landmarks_deferred += c->count - i;
            break;
        }
        if (e->num_landmarks >= e->cfg.max_landmarks) {
            const int victim = eviction_victim(e);
            if (victim < 0) {
                e->counters.landmarks_deferred += c->count - i;
                break;
            }
            vl_window_marginalize(e, (uint32_t)victim);
            e->counters.landmarks_evicted++;
        }
        double y[3];
        vl_stereo_compress(o, y);
        admit_landmark(e, o->id, y);
        /* An admitted id leaves the pending table. */
        for (uint32_t p = 0; p < e->num_pending; ++p) {
            if (e->pending[p].id == o->id) {
                e->pending[p].id = -1;
                break;
            }
        }
    }
    pending_compact(e);
}
