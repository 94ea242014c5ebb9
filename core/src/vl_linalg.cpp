/*
 * The Eigen shim. Everything here works on Eigen::Map views of the caller's
 * buffers; products are written with noalias() so that Eigen creates no
 * temporaries, and large products run in bounded slabs so that Eigen's packing
 * buffers stay under its stack allocation limit (no heap).
 */
#include "vl_linalg.h"

#include "vislam/vislam.h"

#include <algorithm>

#include <Eigen/Core>
#include <Eigen/Cholesky>

namespace
{

using MatMap = Eigen::Map<Eigen::MatrixXd, 0, Eigen::OuterStride<>>;
using ConstMatMap = Eigen::Map<const Eigen::MatrixXd, 0, Eigen::OuterStride<>>;
using DenseMap = Eigen::Map<Eigen::MatrixXd>;
using Mat12 = Eigen::Matrix<double, 12, 12, Eigen::RowMajor>;
using Mat36 = Eigen::Matrix<double, 3, 6, Eigen::RowMajor>;
using Mat33 = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;

/*
 * Panel width of the blocked factorization, solve and downdate below. Eigen's
 * own large LLT, TRSM and SYRK size a packing buffer by the whole matrix
 * dimension, which past 128 KiB comes from the heap; built from products and
 * small solves on panels this wide, every buffer stays bounded and on the stack.
 */
constexpr Eigen::Index kPanel = 32;
/* Slab of one product: Eigen packs at most kProductDepth x kProductRows (and
 * x kPanel) doubles on the stack, 96 KiB, under its 128 KiB stack limit
 * whatever the landmark capacity: a buffer sized at compile time. 96 rows (a
 * multiple of Eigen's 24-row AVX-512 and 6-row SSE2 kernels) against 32 cut the
 * packing repeated per slab: about 8% off a full-window update (README). */
constexpr Eigen::Index kProductRows = 96;
constexpr Eigen::Index kProductDepth = 128;
static_assert(kProductRows * kProductDepth * sizeof(double) <= EIGEN_STACK_ALLOCATION_LIMIT,
              "a product slab's packed operand must fit Eigen's stack allocation");
static_assert(kPanel * kProductDepth * sizeof(double) <= EIGEN_STACK_ALLOCATION_LIMIT,
              "a panel's packed operand must fit Eigen's stack allocation");
using SmallBlock = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kPanel, kPanel>;

/* C -= A B^T in slabs of kProductRows rows and kProductDepth columns of depth
 * (B has at most kPanel rows). */
template <typename DstT, typename LhsT, typename RhsT> void subtract_product_bt(DstT &&C, const LhsT &A, const RhsT &B)
{
    const Eigen::Index rows = C.rows();
    const Eigen::Index depth = A.cols();
    for (Eigen::Index r = 0; r < rows; r += kProductRows) {
        const Eigen::Index h = (rows - r < kProductRows) ? rows - r : kProductRows;
        for (Eigen::Index d = 0; d < depth; d += kProductDepth) {
            const Eigen::Index w = (depth - d < kProductDepth) ? depth - d : kProductDepth;
            C.middleRows(r, h).noalias() -= A.block(r, d, h, w) * B.middleCols(d, w).transpose();
        }
    }
}

/* In-place lower Cholesky factor of the SPD matrix S (lower triangle read); false if not PD. */
bool cholesky_in_place(DenseMap &S)
{
    const Eigen::Index m = S.rows();
    for (Eigen::Index k = 0; k < m; k += kPanel) {
        const Eigen::Index b = (m - k < kPanel) ? m - k : kPanel;
        const Eigen::Index below = m - k - b;
        if (k > 0) {
            subtract_product_bt(S.block(k, k, b, b), S.block(k, 0, b, k), S.block(k, 0, b, k));
            if (below > 0) {
                subtract_product_bt(S.block(k + b, k, below, b), S.block(k + b, 0, below, k), S.block(k, 0, b, k));
            }
        }
        SmallBlock diag = S.block(k, k, b, b);
        Eigen::LLT<Eigen::Ref<SmallBlock>> llt(diag);
        if (llt.info() != Eigen::Success) {
            return false;
        }
        S.block(k, k, b, b) = diag;
        if (below > 0) {
            auto panel = S.block(k + b, k, below, b);
            diag.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(panel);
        }
    }
    return true;
}

/* W <- W L^-T for the lower factor L held in S, one panel of columns at a time.
 * Each row of W is solved on its own, so any block of rows can be done apart. */
template <typename WT> void solve_right_lower_transpose(const DenseMap &S, WT &&W)
{
    const Eigen::Index m = S.rows();
    for (Eigen::Index k = 0; k < m; k += kPanel) {
        const Eigen::Index b = (m - k < kPanel) ? m - k : kPanel;
        auto panel = W.middleCols(k, b);
        if (k > 0) {
            subtract_product_bt(panel, W.leftCols(k), S.block(k, 0, b, k));
        }
        const SmallBlock diag = S.block(k, k, b, b);
        diag.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(panel);
    }
}

/*
 * The two O(n^2 m) parts of the update as fixed blocks, each written by one
 * task only: the whitening by blocks of kProductRows rows of W (so a block's
 * product slabs are those of the whole), the downdate by panels of kPanel
 * columns of P's lower triangle (rows j..n of columns j..j+b). Panel j costs
 * (n - j) b m: the panels come largest first, so threads that take the next
 * free index (vl_parallel_for_fn) share them out longest-first and finish
 * within about one panel of each other.
 */
struct update_blocks {
    MatMap *P;      /* padded rows (see vl_la_update) */
    Eigen::Index n; /* the state's dimension: P's columns to downdate */
    const DenseMap *S;
    DenseMap *W;        /* padded rows */
    Eigen::Index first; /* the downdate's first column (and row) */
};

uint32_t block_count(Eigen::Index size, Eigen::Index block)
{
    return static_cast<uint32_t>((size + block - 1) / block);
}

void whiten_task(void *arg, uint32_t index)
{
    const update_blocks *u = static_cast<const update_blocks *>(arg);
    const Eigen::Index n = u->W->rows();
    const Eigen::Index r = static_cast<Eigen::Index>(index) * kProductRows;
    const Eigen::Index h = (n - r < kProductRows) ? n - r : kProductRows;
    solve_right_lower_transpose(*u->S, u->W->middleRows(r, h));
}

/* Lower triangle of P -= W W^T for one panel of columns from u->first (rows down to the padding). */
void downdate_task(void *arg, uint32_t index)
{
    const update_blocks *u = static_cast<const update_blocks *>(arg);
    const Eigen::Index rows = u->P->rows();
    const Eigen::Index j = u->first + static_cast<Eigen::Index>(index) * kPanel;
    const Eigen::Index b = (u->n - j < kPanel) ? u->n - j : kPanel;
    subtract_product_bt(u->P->block(j, j, rows - j, b), u->W->middleRows(j, rows - j), u->W->middleRows(j, b));
}

/* Below this many flops in its blocks a loop (the whitening, or the landmark block's
 * downdate) runs them on the calling thread: waking a worker and sharing the panels cost more
 * than half of a median update saves (README "Two cores"), so only the costly updates, the
 * tail, are shared. Measured as 16 Mflop for an update's two loops together, about 8 each. */
constexpr double kParallelMinFlops = 8e6;

bool worth_sharing(const vl_la_workspace_t *ws, double flops)
{
    return ws->parallel_for != nullptr && flops >= kParallelMinFlops;
}

void run_blocks(bool shared, const vl_la_workspace_t *ws, vl_parallel_task_fn task, update_blocks *u, uint32_t count)
{
    if (shared) {
        ws->parallel_for(ws->parallel_ctx, task, u, count);
        return;
    }
    for (uint32_t i = 0; i < count; ++i) {
        task(u, i);
    }
}

/* In the checked build every entry point forbids heap use for its whole body. */
struct no_heap_scope {
#ifdef EIGEN_RUNTIME_NO_MALLOC
    no_heap_scope()
    {
        Eigen::internal::set_is_malloc_allowed(false);
    }
    ~no_heap_scope()
    {
        Eigen::internal::set_is_malloc_allowed(true);
    }
#else
    no_heap_scope()
    {
    }
    ~no_heap_scope()
    {
    }
#endif
};

/* The upper triangle from the lower, from column `from` on. */
void mirror_lower_to_upper(MatMap &P, Eigen::Index from = 1)
{
    const Eigen::Index n = P.rows();
    for (Eigen::Index j = from; j < n; ++j) {
        P.col(j).head(j) = P.row(j).head(j).transpose();
    }
}

using CoreMat = Eigen::Matrix<double, VL_CORE_DIM, VL_CORE_DIM>; /* column-major, as the accumulators */
using CoreParamMat = Eigen::Matrix<double, VL_CORE_DIM, VL_PARAM_DIM>;
using ParamMat = Eigen::Matrix<double, VL_PARAM_DIM, VL_PARAM_DIM>;
using Mat3xCore = Eigen::Matrix<double, 3, VL_CORE_DIM>;
using Mat3xParam = Eigen::Matrix<double, 3, VL_PARAM_DIM>;

/*
 * What every landmark row of a deferred prediction shares (vl_la_settle): with
 * U = [B, E] (n x VL_CORE_DIM; identity on the core rows) and Phi = I + U Y E^T
 * the steps' transition, Phi P0 Phi^T + U A U^T = P0 + U Z^T + Z U^T with
 * Z = M Y^T + U A / 2 and M = P0 E + U Y Pbb0 / 2 (the form of
 * vl_la_propagate's M). Pose states are 0..5, rotation 3..5, parameters 6 on.
 */
struct settle_core {
    CoreParamMat Y;
    Mat3xCore C;                                 /* Y_rot Pbb0 Y^T / 2 + A_rot / 2: U's rows per unit Lam */
    Eigen::Matrix<double, VL_CORE_DIM, 3> Z_rot; /* Z's core rows, rotation columns */
};

settle_core settle_prepare(const vl_deferred_prediction_t *d)
{
    settle_core c;
    const Eigen::Map<const CoreMat> core0(d->core0);
    const Eigen::Map<const CoreMat> A(d->noise);
    c.Y = Eigen::Map<const CoreParamMat>(d->transition);
    const ParamMat half_Pbb = 0.5 * core0.bottomRightCorner<VL_PARAM_DIM, VL_PARAM_DIM>();
    CoreParamMat M = core0.rightCols<VL_PARAM_DIM>();
    M.noalias() += c.Y * half_Pbb;
    CoreMat Z = 0.5 * A;
    Z.noalias() += M * c.Y.transpose();
    c.Z_rot = Z.middleCols<3>(3);
    Mat3xParam YP;
    YP.noalias() = c.Y.middleRows<3>(3) * half_Pbb;
    c.C = 0.5 * A.middleRows<3>(3);
    c.C.noalias() += YP * c.Y.transpose();
    return c;
}

/*
 * One landmark's rows against the core (3 x VL_CORE_DIM, read before the deferred steps)
 * to their settled values: rows + Z_s + Lam Z_c,rot^T with Lam = hat(point)
 * (B's block on the landmark's rows; zero without a point) and
 * Z_s = rows_param Y^T + Lam C, the landmark's part of Z (U's rows being Lam times
 * the rotation rows', what every landmark shares is in C). Returns Lam and Z_s's
 * rotation columns for the landmark block.
 */
template <typename RowsT>
void settle_rows(const settle_core &c, const double *point, RowsT &&rows, Eigen::Matrix3d &Lam, Eigen::Matrix3d &Z_rot)
{
    Lam.setZero();
    if (point != nullptr) {
        Lam << 0.0, -point[2], point[1], point[2], 0.0, -point[0], -point[1], point[0], 0.0;
    }
    Mat3xCore Z;
    Z.noalias() = rows.template rightCols<VL_PARAM_DIM>() * c.Y.transpose();
    Z.noalias() += Lam * c.C;
    rows += Z;
    rows.noalias() += Lam * c.Z_rot.transpose();
    Z_rot = Z.middleCols<3>(3);
}

/* W_l W_l^T for the three rows of W from row c: one pass over W's columns (three
 * neighbouring doubles each), where a general product would cost more to set up. */
Eigen::Matrix3d pending_share(const vl_la_pending_t &p, int c)
{
    double s00 = 0.0, s10 = 0.0, s20 = 0.0, s11 = 0.0, s21 = 0.0, s22 = 0.0;
    const double *w = p.W + c;
    for (int j = 0; j < p.cols; ++j, w += p.rows) {
        s00 += w[0] * w[0];
        s10 += w[1] * w[0];
        s20 += w[2] * w[0];
        s11 += w[1] * w[1];
        s21 += w[2] * w[1];
        s22 += w[2] * w[2];
    }
    Eigen::Matrix3d B;
    B << s00, s10, s20, s10, s11, s21, s20, s21, s22;
    return B;
}

} // namespace

extern "C" void vl_la_configure(void)
{
    /* Eigen sizes its cache blocking from the CPU it runs on; fixed sizes give
     * the same blocking, hence the same rounding, on every host. */
    Eigen::setCpuCacheSizes(32 * 1024, 96 * 1024, 96 * 1024);
}

extern "C" void vl_la_propagate(double *Pbuf, int ld, const double Gp_rm[36], const double *Gt_rm,
                                const double noise_var[6], const double offset_var[6], double a, const double R[36])
{
    no_heap_scope guard;
    /* On a copy of the core block with its size fixed at compile time and padded to whole 4-row
     * packets (zero rows and columns past the core): Eigen unrolls and vectorizes every product,
     * half the time of general rank updates on P in place (README "Results"). */
    constexpr int kPad = (VL_CORE_DIM + 3) / 4 * 4;
    using PadMat = Eigen::Matrix<double, kPad, kPad>;
    using PadParam = Eigen::Matrix<double, kPad, VL_PARAM_DIM>;
    MatMap P(Pbuf, VL_CORE_DIM, VL_CORE_DIM, Eigen::OuterStride<>(ld));
    PadMat C = PadMat::Zero();
    C.topLeftCorner<VL_CORE_DIM, VL_CORE_DIM>() = P;
    /* The inputs move the pose rows only: the parameters' rows of G and Gt stay zero. */
    Eigen::Matrix<double, kPad, 6> N = Eigen::Matrix<double, kPad, 6>::Zero();
    N.topRows<6>() = Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(Gp_rm) *
                     Eigen::Map<const Eigen::Matrix<double, 6, 1>>(noise_var).cwiseSqrt().asDiagonal();
    PadMat add;
    add.noalias() = N * N.transpose();
    if (Gt_rm != nullptr) {
        /* Phi P Phi^T = P + Gt M^T + M Gt^T with M = P E + Gt (E^T P E) / 2. */
        PadParam Gt = PadParam::Zero();
        Gt.topRows<6>() = Eigen::Map<const Eigen::Matrix<double, 6, VL_PARAM_DIM, Eigen::RowMajor>>(Gt_rm);
        PadParam M = C.middleCols<VL_PARAM_DIM>(6);
        const ParamMat half_Pbb = 0.5 * C.block<VL_PARAM_DIM, VL_PARAM_DIM>(6, 6);
        M.noalias() += Gt * half_Pbb;
        PadMat A;
        A.noalias() = Gt * M.transpose();
        add += A + A.transpose();
    }
    C += add;
    if (Gt_rm != nullptr && a != 1.0) {
        /* D P D + (1 - a^2) R: the offsets' rows and columns scaled, their own block refilled. */
        C.middleRows<6>(6) *= a;
        C.middleCols<6>(6) *= a;
        C.block<6, 6>(6, 6) += (1.0 - a * a) * Eigen::Map<const Eigen::Matrix<double, 6, 6>>(R);
    }
    if (offset_var != nullptr) {
        C.diagonal().segment<6>(6) += Eigen::Map<const Eigen::Matrix<double, 6, 1>>(offset_var);
    }
    C.triangularView<Eigen::StrictlyUpper>() = C.transpose(); /* exactly symmetric */
    P = C.topLeftCorner<VL_CORE_DIM, VL_CORE_DIM>();
}

extern "C" void vl_la_settle(double *Pbuf, int ld, int n, const vl_deferred_prediction_t *d, const double *points,
                             double *work)
{
    no_heap_scope guard;
    const Eigen::Index nl = n - VL_CORE_DIM;
    if (nl <= 0) {
        return;
    }
    MatMap P(Pbuf, n, n, Eigen::OuterStride<>(ld));
    const settle_core c = settle_prepare(d);
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 6>> X(work, nl, 6);
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 6>> Xs(work + 6 * nl, nl, 6);
    for (Eigen::Index r = 0; r < nl; r += 3) {
        Eigen::Matrix3d Lam, Z_rot;
        settle_rows(c, points != nullptr ? points + r : nullptr, P.block<3, VL_CORE_DIM>(VL_CORE_DIM + r, 0), Lam,
                    Z_rot);
        X.block<3, 3>(r, 0) = Lam;
        X.block<3, 3>(r, 3) = Z_rot;
        Xs.block<3, 3>(r, 0) = Z_rot;
        Xs.block<3, 3>(r, 3) = Lam;
    }
    if (points != nullptr) {
        /* The landmark block: Lam Z_rot^T + Z_rot Lam^T = X Xs^T, one rank-6 product on the lower triangle. */
        P.bottomRightCorner(nl, nl).triangularView<Eigen::Lower>() += X * Xs.transpose();
    }
    mirror_lower_to_upper(P, VL_CORE_DIM);
}

extern "C" void vl_la_settled_landmark(const double *Pbuf, int ld, int col, const vl_deferred_prediction_t *d,
                                       const double *point, double cross[3 * VL_CORE_DIM], double block[9])
{
    no_heap_scope guard;
    ConstMatMap P(Pbuf, col + 3, col + 3, Eigen::OuterStride<>(ld));
    const settle_core c = settle_prepare(d);
    Eigen::Map<Mat3xCore> rows(cross);
    rows = P.block<3, VL_CORE_DIM>(col, 0);
    Eigen::Matrix3d Lam, Z_rot;
    settle_rows(c, point, rows, Lam, Z_rot);
    Eigen::Map<Eigen::Matrix3d> B(block);
    B = P.block<3, 3>(col, col);
    B.noalias() += Lam * Z_rot.transpose();
    B.noalias() += Z_rot * Lam.transpose();
}

extern "C" void vl_la_obs_covariance(const double *Pbuf, int ld, const vl_la_obs_t *obs, const vl_la_pending_t *pending,
                                     double S_rm[9])
{
    no_heap_scope guard;
    const int n = obs->landmark_col + 3;
    ConstMatMap P(Pbuf, n, n, Eigen::OuterStride<>(ld));
    const Eigen::Map<const Mat36> Hp(obs->H_pose);
    const Eigen::Map<const Mat33> Hl(obs->H_landmark);
    const int c = obs->landmark_col;

    Eigen::Matrix<double, 9, 9> B;
    B.topLeftCorner<6, 6>() = P.topLeftCorner<6, 6>();
    B.topRightCorner<6, 3>() = P.block<6, 3>(0, c);
    B.bottomLeftCorner<3, 6>() = P.block<3, 6>(c, 0);
    B.bottomRightCorner<3, 3>() = P.block<3, 3>(c, c);
    if (pending != nullptr && pending->cols > 0 && c >= VL_CORE_DIM) {
        B.bottomRightCorner<3, 3>() -= pending_share(*pending, c);
    }
    Eigen::Matrix<double, 3, 9> H;
    H << Hp, Hl;
    Eigen::Map<Mat33> S(S_rm);
    S.noalias() = H * B * H.transpose();
    S.diagonal() += Eigen::Map<const Eigen::Vector3d>(obs->noise_var);
}

extern "C" int vl_la_single_correction(const double *Pbuf, int ld, int n, const vl_la_obs_t *obs, double *work,
                                       double *dx_out)
{
    no_heap_scope guard;
    ConstMatMap P(Pbuf, n, n, Eigen::OuterStride<>(ld));
    const Eigen::Map<const Mat36> Hp(obs->H_pose);
    const Eigen::Map<const Mat33> Hl(obs->H_landmark);
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 3>> PHt(work, n, 3);
    PHt.noalias() = P.leftCols<6>() * Hp.transpose();
    PHt.noalias() += P.middleCols<3>(obs->landmark_col) * Hl.transpose();
    Eigen::Matrix3d S;
    S.noalias() = Hp * PHt.topRows<6>();
    S.noalias() += Hl * PHt.middleRows<3>(obs->landmark_col);
    S.diagonal() += Eigen::Map<const Eigen::Vector3d>(obs->noise_var);
    Eigen::LLT<Eigen::Matrix3d> llt(S);
    if (llt.info() != Eigen::Success) {
        return -1;
    }
    const Eigen::Vector3d w = llt.solve(Eigen::Map<const Eigen::Vector3d>(obs->residual));
    Eigen::Map<Eigen::VectorXd>(dx_out, n).noalias() = PHt * w;
    return 0;
}

namespace
{

/* P's rows the whitening and the downdates run on: n rounded up to whole 4-row packets (a
 * remainder row takes Eigen's scalar path in every product slab, 7% of a full window's
 * update at n = 399, README "Results"), within the room ld leaves. */
Eigen::Index padded_rows(int n, int ld)
{
    return std::min<Eigen::Index>((static_cast<Eigen::Index>(n) + 3) / 4 * 4, ld);
}

} // namespace

extern "C" int vl_la_padded_rows(int n, int ld)
{
    return static_cast<int>(padded_rows(n, ld));
}

extern "C" int vl_la_update_core(double *Pbuf, int ld, int n, const vl_la_obs_t *obs, int k,
                                 const vl_la_workspace_t *ws, int pending, double *nis)
{
    no_heap_scope guard;
    const Eigen::Index m = 3 * static_cast<Eigen::Index>(k);
    const Eigen::Index np = padded_rows(n, ld);
    const Eigen::Index nl = np - VL_CORE_DIM; /* the landmark rows, padding included */
    const double nd = static_cast<double>(n), md = static_cast<double>(m);
    const bool shared = worth_sharing(ws, nd * md * (md + 1.0));
    if (shared) {
        ws->parallel_for(ws->parallel_ctx, whiten_task, nullptr, 0); /* the blocks come after S's factorization */
    }
    /* P's rows past n belong to no state and are zeroed, as are W's: the padding changes
     * no state row. */
    MatMap P(Pbuf, n, n, Eigen::OuterStride<>(ld));
    MatMap Ppad(Pbuf, np, n, Eigen::OuterStride<>(ld));
    const DenseMap Wold(ws->PHt, np, pending);
    DenseMap PHt(ws->PHt + np * pending, np, m);
    DenseMap S(ws->S, m, m);
    Eigen::Map<Eigen::VectorXd> dx(ws->dx, np);

    /* P H^T from the observed columns only: each observation reads the six pose
     * columns and its landmark's three. */
    for (int i = 0; i < k; ++i) {
        const Eigen::Map<const Mat36> Hp(obs[i].H_pose);
        const Eigen::Map<const Mat33> Hl(obs[i].H_landmark);
        auto block = PHt.middleCols<3>(3 * i).topRows(n);
        block.noalias() = P.leftCols<6>() * Hp.transpose();
        block.noalias() += P.middleCols<3>(obs[i].landmark_col) * Hl.transpose();
    }
    PHt.bottomRows(np - n).setZero();
    if (pending > 0) {
        /* The pending downdate's share: on the landmark rows, the landmark columns read
         * P - Wold Wold^T, so P H^T loses Wold (Hl Wold_l)^T, with X = H_l Wold_l (m x pending)
         * held past S. */
        DenseMap X(ws->S + m * m, m, pending);
        for (int i = 0; i < k; ++i) {
            const Eigen::Map<const Mat33> Hl(obs[i].H_landmark);
            X.middleRows<3>(3 * i).noalias() = Hl * Wold.middleRows<3>(obs[i].landmark_col);
        }
        for (Eigen::Index c = 0; c < m; c += kPanel) {
            const Eigen::Index b = (m - c < kPanel) ? m - c : kPanel;
            subtract_product_bt(PHt.block(VL_CORE_DIM, c, nl, b), Wold.bottomRows(nl), X.middleRows(c, b));
        }
    }

    /* S = H (P H^T) + R, again reading only the rows each observation touches.
     * Only the lower triangle is needed by the factorization. */
    for (int i = 0; i < k; ++i) {
        const Eigen::Map<const Mat36> Hp(obs[i].H_pose);
        const Eigen::Map<const Mat33> Hl(obs[i].H_landmark);
        const Eigen::Index rows = m - 3 * i;
        auto block = S.block(3 * i, 3 * i, 3, rows);
        block.noalias() = Hp * PHt.block(0, 3 * i, 6, rows);
        block.noalias() += Hl * PHt.block(obs[i].landmark_col, 3 * i, 3, rows);
    }
    /* block rows were written as the upper triangle: move them to the lower. */
    for (Eigen::Index j = 0; j < m; ++j) {
        S.col(j).tail(m - j) = S.row(j).tail(m - j).transpose();
    }
    for (int i = 0; i < k; ++i) {
        S.diagonal().segment<3>(3 * i) += Eigen::Map<const Eigen::Vector3d>(obs[i].noise_var);
    }

    if (!cholesky_in_place(S)) {
        return -1;
    }

    /* Whitened innovation e = L^-1 r; the correction is dx = W e with W = P H^T L^-T. */
    Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 3 * VL_MAX_LANDMARKS, 1> e(m);
    for (int i = 0; i < k; ++i) {
        e.segment<3>(3 * i) = Eigen::Map<const Eigen::Vector3d>(obs[i].residual);
    }
    S.triangularView<Eigen::Lower>().solveInPlace(e);
    if (nis != nullptr) {
        *nis = e.squaredNorm();
    }
    update_blocks blocks = {&Ppad, n, &S, &PHt, 0};
    run_blocks(shared, ws, whiten_task, &blocks, block_count(np, kProductRows));
    dx.noalias() = PHt * e;

    /* The core's columns now, rows and columns alike, so every read of the pose and the
     * parameters is current: P - W W^T on them, the core block from its lower triangle. */
    subtract_product_bt(P.leftCols<VL_CORE_DIM>(), PHt.topRows(n), PHt.topRows<VL_CORE_DIM>());
    P.topRows<VL_CORE_DIM>().rightCols(n - VL_CORE_DIM) =
        P.bottomRows(n - VL_CORE_DIM).leftCols<VL_CORE_DIM>().transpose();
    MatMap core(Pbuf, VL_CORE_DIM, VL_CORE_DIM, Eigen::OuterStride<>(ld));
    mirror_lower_to_upper(core);
    return 0;
}

extern "C" void vl_la_downdate_landmarks(double *Pbuf, int ld, int n, const vl_la_workspace_t *ws, int cols)
{
    no_heap_scope guard;
    if (cols <= 0 || n <= VL_CORE_DIM) {
        return;
    }
    const Eigen::Index np = padded_rows(n, ld);
    const double nl = static_cast<double>(n - VL_CORE_DIM);
    const bool shared = worth_sharing(ws, nl * (nl + 1.0) * static_cast<double>(cols));
    MatMap P(Pbuf, n, n, Eigen::OuterStride<>(ld));
    MatMap Ppad(Pbuf, np, n, Eigen::OuterStride<>(ld));
    DenseMap W(ws->PHt, np, cols);
    Ppad.bottomRows(np - n).setZero();
    update_blocks blocks = {&Ppad, n, nullptr, &W, VL_CORE_DIM};
    run_blocks(shared, ws, downdate_task, &blocks, block_count(n - VL_CORE_DIM, kPanel));
    mirror_lower_to_upper(P, VL_CORE_DIM); /* so P stays exactly symmetric (the core's columns are already) */
}

extern "C" int vl_la_update(double *Pbuf, int ld, int n, const vl_la_obs_t *obs, int k, const vl_la_workspace_t *ws,
                            double *nis)
{
    if (vl_la_update_core(Pbuf, ld, n, obs, k, ws, 0, nis) != 0) {
        return -1;
    }
    vl_la_downdate_landmarks(Pbuf, ld, n, ws, 3 * k);
    return 0;
}

extern "C" void vl_la_pending_share(const vl_la_pending_t *pending, int col, double block[9])
{
    no_heap_scope guard;
    Eigen::Map<Eigen::Matrix3d> B(block);
    if (pending == nullptr || pending->cols <= 0 || col < VL_CORE_DIM) {
        B.setZero();
        return;
    }
    B = pending_share(*pending, col);
}

extern "C" void vl_la_append_landmark(double *Pbuf, int ld, int n, const double J_pose_rm[18], const double J_obs_rm[9],
                                      const double noise_var[3])
{
    no_heap_scope guard;
    MatMap P(Pbuf, n + 3, n + 3, Eigen::OuterStride<>(ld));
    const Eigen::Map<const Mat36> Jp(J_pose_rm);
    const Eigen::Map<const Mat33> Jo(J_obs_rm);

    P.block(n, 0, 3, n).noalias() = Jp * P.topRows<6>().leftCols(n);
    P.block(0, n, n, 3) = P.block(n, 0, 3, n).transpose();
    Mat33 C;
    C.noalias() = Jp * P.topLeftCorner<6, 6>() * Jp.transpose();
    C.noalias() += Jo * Eigen::Map<const Eigen::Vector3d>(noise_var).asDiagonal() * Jo.transpose();
    P.block<3, 3>(n, n) = 0.5 * (C + C.transpose());
}

extern "C" void vl_la_move_block(double *Pbuf, int ld, int n, int dst, int src)
{
    no_heap_scope guard;
    MatMap P(Pbuf, n, n, Eigen::OuterStride<>(ld));
    /* Columns first: afterwards row src at columns dst holds P(src, src), which
     * the row copy then carries into the diagonal block. */
    P.middleCols<3>(dst) = P.middleCols<3>(src);
    P.middleRows<3>(dst) = P.middleRows<3>(src);
}
