/*
 * The work of each stage, in flops (a multiply-add is 2), from the dimensions the
 * stage used. The terms in n (states), m (rows) and k (observations) follow the
 * code they count (vl_linalg.cpp's loops and products); the fixed-size parts
 * (one 3x9 observation, one 3x3 solve, one SE(3) exponential) are rounded
 * estimates, which matter only when n and m are small.
 */
#include "vl_work.h"

#include <string.h>

/* Making one observation's rows: camera point, projection and its Jacobian, two 3x3 products. */
#define VL_WORK_ROW 200u
/* One observation's 3x3 innovation covariance (H P H^T over 9 columns) and its Mahalanobis distance. */
#define VL_WORK_OBS_CHECK (2u * (3u * 9u * 9u + 3u * 9u * 3u) + 40u)
/* The residual of one observation after a correction: 3 rows of 9 multiply-adds. */
#define VL_WORK_RESIDUAL (2u * 3u * 9u + 6u)
/* The pose part of a prediction or a correction: SE(3) exponential, Jacobians, 6x6 products. */
#define VL_WORK_POSE 1000u
/* The step's log (an SO(3) logarithm and a 3x3 product). */
#define VL_WORK_STEP 100u
/* One 3x3 block of a repeated image's shared landmark noise and its mirror: a dot product, 9 entries. */
#define VL_WORK_REPEAT_PAIR 50u
/* One carried landmark's walk: its camera point (two 3x3 products) and six entries of A diag(q) A^T. */
#define VL_WORK_CARRIED_WALK 120u
/* Moving one landmark by a correction: two 3x3 products and a sum. */
#define VL_WORK_LANDMARK_CORRECTION 39u
/* One track's two views: triangulation, projection, the 3x3 weight, whitening [H r] and the
 * 6x6 normal equations. A fit: summing the tracks' normal equations (54 a track), the 6x6
 * inverse and solve, and a track's residual against it (or the two blocks' matching). */
#define VL_WORK_TWO_VIEW_PAIR 700u
#define VL_WORK_TWO_VIEW_FIT 900u
#define VL_WORK_TWO_VIEW_SUM 54u
/* A track's drift sums: three clipped rows, nine covariance terms and a 3x3 Mahalanobis test. */
#define VL_WORK_DRIFT 60u

static void add(vl_estimator_t *e, uint64_t *stage, uint64_t flops)
{
    *stage += flops;
    e->work.flops += flops;
}

uint64_t vl_work_joint_update(uint32_t n_states, uint32_t k_obs)
{
    if (k_obs == 0) {
        return 0;
    }
    const uint64_t n = n_states, k = k_obs, m = 3u * k_obs;
    const uint64_t pht = 2u * n * 9u * m;                               /* P H^T from 9 columns per observation */
    const uint64_t s = 2u * 9u * 3u * (m * k - 3u * k * (k - 1u) / 2u); /* upper block rows of S */
    const uint64_t chol = m * m * m / 3u + m * m;                       /* blocked Cholesky */
    const uint64_t whiten = m * m + n * m * (m + 1u);                   /* L^-1 r and W = P H^T L^-T */
    const uint64_t dx = 2u * n * m;                                     /* dx = W L^-1 r */
    const uint64_t downdate = n * (n + 1u) * m;                         /* P -= W W^T, lower triangle */
    const uint64_t correct = VL_WORK_POSE + VL_WORK_LANDMARK_CORRECTION * ((n - VL_CORE_DIM) / 3u);
    return pht + s + chol + whiten + dx + downdate + correct;
}

/* The lower triangle of the landmark block (n - VL_CORE_DIM states) less m rows' product. */
static uint64_t landmark_downdate(uint64_t n, uint64_t m)
{
    const uint64_t nl = n > VL_CORE_DIM ? n - VL_CORE_DIM : 0u;
    return nl * (nl + 1u) * m;
}

uint64_t vl_work_joint_update_core(uint32_t n_states, uint32_t k_obs, uint32_t pending)
{
    if (k_obs == 0) {
        return 0;
    }
    const uint64_t n = n_states, k = k_obs, m = 3u * k_obs, p = pending;
    /* The pending rows' share of P H^T: H_l W_l per observation, then the landmark rows' product. */
    const uint64_t share = p > 0 ? 2u * 9u * p * k + 2u * (n - VL_CORE_DIM) * p * m : 0u;
    return vl_work_joint_update(n_states, k_obs) - landmark_downdate(n, m) + share;
}

void vl_work_downdate(vl_estimator_t *e, uint32_t n, uint32_t rows)
{
    add(e, &e->work.update, landmark_downdate(n, rows));
}

void vl_work_begin(vl_estimator_t *e)
{
    memset(&e->work, 0, sizeof(e->work));
}

/* vl_la_propagate: full products on the core block padded to kp rows (whole 4-row packets): the
 * noise's rank-6 product, M and Gt M^T when the parameters couple in, and the offsets' decay
 * (their rows and columns scaled, their block refilled). */
static uint64_t propagate_flops(int coupled, int decaying)
{
    const uint64_t np = VL_PARAM_DIM, kp = (VL_CORE_DIM + 3u) / 4u * 4u;
    uint64_t flops = 6u * VL_CORE_DIM + 2u * 6u * kp * kp + kp * kp;
    if (coupled) { /* M = P E + Gt Pbb / 2, then Gt M^T + M Gt^T */
        flops += 2u * np * np * kp + np * kp + 2u * np * kp * kp + 2u * kp * kp;
    }
    if (decaying) {
        flops += 2u * 6u * kp + 2u * 36u;
    }
    return flops;
}

void vl_work_predict(vl_estimator_t *e, int coupled, int decaying)
{
    /* The pose, then P's core block and the deferred noise (VL_CORE_DIM states each), and the
     * transition's parameter rows: O(1). */
    const uint64_t transition = coupled ? 2u * 6u * VL_PARAM_DIM * (VL_PARAM_DIM + 1u) : 0u;
    const uint64_t flops = VL_WORK_POSE + 2u * propagate_flops(coupled, decaying) + transition;
    add(e, &e->work.predict, flops);
    if (e->work.state_dim == 0) {
        e->work.state_dim = VL_CORE_DIM + 3u * e->num_landmarks;
    }
}

void vl_work_settle(vl_estimator_t *e, uint32_t n_states, int moving)
{
    /* The shared terms (M, Z on the core's rows, and C on the rotation rows), each landmark's rows
     * against the core (Z: a 3 x np x core and two 3 x 3 x core products), and the landmark
     * block's rank-6 product on its lower triangle. */
    const uint64_t nl = n_states - VL_CORE_DIM;
    if (nl == 0) {
        return; /* the core block is current already */
    }
    const uint64_t landmarks = nl / 3u;
    const uint64_t np = VL_PARAM_DIM, nc = VL_CORE_DIM;
    const uint64_t core = 2u * nc * np * np + 2u * nc * np * nc + 2u * (3u * np * np + 3u * np * nc) + 300u;
    const uint64_t per_landmark = 2u * (3u * np * nc + 2u * 3u * 3u * nc) + 100u;
    const uint64_t block = moving ? 6u * nl * (nl + 1u) : 0u;
    add(e, &e->work.predict, core + landmarks * per_landmark + block);
}

void vl_work_repeat_noise(vl_estimator_t *e, uint32_t carried)
{
    const uint64_t n = carried;
    add(e, &e->work.predict, VL_WORK_STEP + VL_WORK_REPEAT_PAIR * n * (n + 1u) / 2u);
}

void vl_work_carried_walk(vl_estimator_t *e, uint32_t n)
{
    if (n > 0) { /* A = R Rc^T once, then each landmark */
        add(e, &e->work.predict, 60u + (uint64_t)n * VL_WORK_CARRIED_WALK);
    }
}

void vl_work_gate(vl_estimator_t *e, uint32_t k)
{
    add(e, &e->work.gate, (uint64_t)k * VL_WORK_OBS_CHECK);
}

void vl_work_ransac(vl_estimator_t *e, uint32_t n, uint32_t k, uint32_t hypotheses)
{
    /* One hypothesis: P H^T for one observation (n x 3 from 9 columns), its 3x3 S and
     * solve, dx = P H^T w, then the residual of every observation after dx. */
    const uint64_t one = 2u * (uint64_t)n * 9u * 3u + 6u * (uint64_t)n + 200u + (uint64_t)k * VL_WORK_RESIDUAL;
    add(e, &e->work.ransac, (uint64_t)hypotheses * one);
    e->work.hypotheses += hypotheses;
}

void vl_work_update(vl_estimator_t *e, uint32_t n, uint32_t k, int adapted, uint32_t k_frame)
{
    uint64_t flops = vl_work_joint_update_core(n, k, 0u);
    if (adapted) {
        /* Pixel noise: each row's posterior check (its landmark block less the update's
         * pending rows' share, six multiply-adds a row) and residual, a median of 3 k values;
         * velocity noise: the correction and its 6x6 covariance to the body frame (two
         * 6x6 products and a 6-vector), a few 3x3 sums. */
        flops += (uint64_t)k_frame * (VL_WORK_OBS_CHECK + VL_WORK_RESIDUAL + 12u + 12u * 3u * (uint64_t)k) + 1100u;
    }
    add(e, &e->work.update, flops);
    e->work.state_dim = n;
    e->work.rows += 3u * k;
}

void vl_work_stereo_rows(vl_estimator_t *e, uint32_t count)
{
    add(e, &e->work.update, (uint64_t)count * 10u);
}

void vl_work_two_view(vl_estimator_t *e, uint32_t count, uint32_t previous, uint32_t pairs)
{
    /* The id lookup compares each observation with the previous frame's: one operation each. Then
     * the tracks, one fit without each (leave-one-out) and the fit of all. */
    const uint64_t fit = VL_WORK_TWO_VIEW_FIT + (uint64_t)pairs * VL_WORK_TWO_VIEW_SUM;
    add(e, &e->work.update,
        (uint64_t)count * previous + (uint64_t)pairs * (VL_WORK_TWO_VIEW_PAIR + VL_WORK_DRIFT + fit) + fit);
}

void vl_work_drift_carry(vl_estimator_t *e, uint32_t count, uint32_t previous)
{
    add(e, &e->work.update, (uint64_t)count * previous); /* the id lookup, as the two views' */
}

void vl_work_rescue(vl_estimator_t *e, uint32_t n, uint32_t checked, uint32_t rescued, uint32_t pending)
{
    /* Each check reads its landmark block less the pending rows' share: six multiply-adds a row. */
    const uint64_t check = VL_WORK_ROW + VL_WORK_OBS_CHECK + 12u * (uint64_t)pending;
    add(e, &e->work.rescue, (uint64_t)checked * check + vl_work_joint_update_core(n, rescued, pending));
    e->work.rows += 3u * rescued;
}

void vl_work_deferred(vl_estimator_t *e, uint32_t n, uint32_t checked, uint32_t used)
{
    /* The whole joint update: its downdate runs at once. */
    add(e, &e->work.update, (uint64_t)checked * (VL_WORK_ROW + VL_WORK_OBS_CHECK) + vl_work_joint_update(n, used));
    e->work.state_dim = n;
    e->work.rows += 3u * used;
}

void vl_work_window(vl_estimator_t *e, uint32_t n, uint32_t observations, uint32_t marginalized, uint32_t admitted)
{
    /* A marginalization copies 3 columns and 3 rows of P (and hands the landmark's
     * marginal out); an admission fills 3 rows from the 6 pose rows (J_pose P). */
    const uint64_t marg = 6u * (uint64_t)n + 300u;
    const uint64_t admit = 2u * 3u * 6u * (uint64_t)n + 3u * (uint64_t)n + 500u;
    add(e, &e->work.window,
        (uint64_t)observations * VL_WORK_ROW + (uint64_t)marginalized * marg + (uint64_t)admitted * admit);
}
