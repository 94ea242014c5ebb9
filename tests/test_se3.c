/**
 * @file test_se3.c
 * @brief Unity tests of the SO(3)/SE(3) helpers in core/src/vl_se3.c.
 *
 * Closed forms are checked against independent references: truncated power
 * series of the 4x4 / 6x6 matrix exponentials (no cancellation for the
 * moderate arguments used), group identities, and central finite differences.
 */
#include "unity.h"
#include "vl_test_util.h"
#include "vislam/vislam.h"
#include "vl_se3.h"

#include <math.h>
#include <string.h>

static const double k_pi = 3.14159265358979323846;

void setUp(void)
{
}
void tearDown(void)
{
}

/* ---- helpers ------------------------------------------------------------ */

static void identity(double *M, int n)
{
    int i;
    memset(M, 0, sizeof(double) * (size_t)(n * n));
    for (i = 0; i < n; ++i) {
        M[i * n + i] = 1.0;
    }
}

/* exp(A) of an n x n matrix (n <= 6) by its power series; terms until negligible. */
static void expm_series(const double *A, double *E, int n)
{
    double term[36], next[36];
    int k, i;
    identity(E, n);
    identity(term, n);
    for (k = 1; k < 60; ++k) {
        vl_matmul(term, A, next, n, n, n);
        for (i = 0; i < n * n; ++i) {
            term[i] = next[i] / k;
            E[i] += term[i];
        }
    }
}

/* sum_{k>=0} A^k / (k+1)! (the left Jacobian as a series of ad(xi)). */
static void jac_series(const double *A, double *J, int n)
{
    double term[36], next[36];
    int k, i;
    identity(J, n);
    identity(term, n);
    for (k = 1; k < 60; ++k) {
        vl_matmul(term, A, next, n, n, n);
        for (i = 0; i < n * n; ++i) {
            term[i] = next[i] / (k + 1);
            J[i] += term[i];
        }
    }
}

/* 4x4 hat(xi) = [[hat(phi), rho], [0, 0]]. */
static void se3_hat4(const double xi[6], double H[16])
{
    double S[9];
    int i, j;
    vl_skew(xi + 3, S);
    memset(H, 0, sizeof(double) * 16);
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            H[4 * i + j] = S[3 * i + j];
        }
        H[4 * i + 3] = xi[i];
    }
}

static void pose_to_4x4(const double R[9], const double p[3], double T[16])
{
    int i, j;
    memset(T, 0, sizeof(double) * 16);
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            T[4 * i + j] = R[3 * i + j];
        }
        T[4 * i + 3] = p[i];
    }
    T[15] = 1.0;
}

/* (R, p) = (R1, p1) (R2, p2) */
static void compose(const double R1[9], const double p1[3], const double R2[9], const double p2[3], double R[9],
                    double p[3])
{
    int i;
    vl_matmul(R1, R2, R, 3, 3, 3);
    vl_matmul(R1, p2, p, 3, 3, 1);
    for (i = 0; i < 3; ++i) {
        p[i] += p1[i];
    }
}

static void inverse(const double R[9], const double p[3], double Ri[9], double pi_[3])
{
    int i, j;
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            Ri[3 * i + j] = R[3 * j + i];
        }
    }
    vl_matmul(Ri, p, pi_, 3, 3, 1);
    for (i = 0; i < 3; ++i) {
        pi_[i] = -pi_[i];
    }
}

/* phi of magnitude t along a fixed, non-axis-aligned direction d. */
static void scaled_dir(const double d[3], double t, double phi[3])
{
    const double n = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    phi[0] = t * d[0] / n;
    phi[1] = t * d[1] / n;
    phi[2] = t * d[2] / n;
}

/* Angles probing the series branch, both sides of its threshold (1 rad), and the region near pi. */
static const double k_angles[] = {0.0,       1e-12, 1e-7,      1e-4, 0.03, 0.1, 0.5,
                                  0.9999999, 1.0,   1.0000001, 1.3,  2.0,  3.0, 3.14};
#define N_ANGLES ((int)(sizeof(k_angles) / sizeof(k_angles[0])))

static const double k_dirs[][3] = {{0.3, -0.5, 0.8}, {1.0, 0.0, 0.0}, {-0.2, 0.9, 0.1}, {0.0, 0.0, -1.0}};
#define N_DIRS ((int)(sizeof(k_dirs) / sizeof(k_dirs[0])))

/* ---- basic helpers ------------------------------------------------------ */

void test_skew_matches_cross_product(void)
{
    const double v[3] = {0.3, -1.2, 2.5};
    const double w[3] = {-0.7, 0.4, 1.1};
    const double cross[3] = {v[1] * w[2] - v[2] * w[1], v[2] * w[0] - v[0] * w[2], v[0] * w[1] - v[1] * w[0]};
    double S[9], Sw[3];
    vl_skew(v, S);
    vl_matmul(S, w, Sw, 3, 3, 1);
    VL_TEST_ASSERT_CLOSE(Sw, cross, 3, 1e-15);
}

void test_matmul_variants_agree(void)
{
    /* A is 2x3, B is 3x4. */
    const double A[6] = {1, 2, 3, 4, 5, 6};
    const double B[12] = {1, -1, 0, 2, 3, 0.5, -2, 1, 0, 1, 4, -3};
    const double expect[8] = {7, 3, 8, -5, 19, 4.5, 14, -5};
    double C[8], At[6], Bt[12], C2[8], C3[8];
    int i, j;
    vl_matmul(A, B, C, 2, 3, 4);
    VL_TEST_ASSERT_CLOSE(C, expect, 8, 1e-15);
    for (i = 0; i < 2; ++i) {
        for (j = 0; j < 3; ++j) {
            At[j * 2 + i] = A[i * 3 + j];
        }
    }
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 4; ++j) {
            Bt[j * 3 + i] = B[i * 4 + j];
        }
    }
    vl_matmul_bt(A, Bt, C2, 2, 3, 4);
    vl_matmul_at(At, B, C3, 2, 3, 4);
    VL_TEST_ASSERT_CLOSE(C2, expect, 8, 1e-15);
    VL_TEST_ASSERT_CLOSE(C3, expect, 8, 1e-15);
}

/* ---- SO(3) -------------------------------------------------------------- */

void test_so3_exp_matches_series(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double phi[3], S[9], E[9], R[9];
            scaled_dir(k_dirs[d], k_angles[a], phi);
            vl_skew(phi, S);
            expm_series(S, E, 3);
            vl_so3_exp(phi, R);
            VL_TEST_ASSERT_CLOSE(R, E, 9, 1e-14);
        }
    }
}

void test_so3_exp_is_orthonormal(void)
{
    const double phi[3] = {1.1, -2.0, 0.4};
    double R[9], RRt[9], I[9];
    vl_so3_exp(phi, R);
    vl_matmul_bt(R, R, RRt, 3, 3, 3);
    identity(I, 3);
    VL_TEST_ASSERT_CLOSE(RRt, I, 9, 1e-15);
}

void test_so3_log_round_trip_all_angles(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double phi[3], R[9], back[3];
            scaled_dir(k_dirs[d], k_angles[a], phi);
            vl_so3_exp(phi, R);
            vl_so3_log(R, back);
            VL_TEST_ASSERT_CLOSE(back, phi, 3, 1e-14);
        }
    }
}

void test_so3_log_round_trip_near_pi(void)
{
    const double eps[] = {1e-3, 1e-6, 1e-9, 1e-12};
    int e, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (e = 0; e < 4; ++e) {
            double phi[3], R[9], back[3];
            scaled_dir(k_dirs[d], k_pi - eps[e], phi);
            vl_so3_exp(phi, R);
            vl_so3_log(R, back);
            VL_TEST_ASSERT_CLOSE(back, phi, 3, 1e-13);
        }
    }
}

void test_so3_log_at_pi_gives_valid_angle(void)
{
    int d;
    for (d = 0; d < N_DIRS; ++d) {
        double phi[3], R[9], back[3], R2[9];
        scaled_dir(k_dirs[d], k_pi, phi);
        vl_so3_exp(phi, R);
        vl_so3_log(R, back);
        /* +phi and -phi are the same rotation at pi: check the rotation and the angle. */
        TEST_ASSERT_DOUBLE_WITHIN(1e-14, k_pi, sqrt(back[0] * back[0] + back[1] * back[1] + back[2] * back[2]));
        vl_so3_exp(back, R2);
        VL_TEST_ASSERT_CLOSE(R2, R, 9, 1e-14);
    }
}

void test_so3_log_of_identity_is_zero(void)
{
    double I[9], phi[3];
    const double zero[3] = {0.0, 0.0, 0.0};
    identity(I, 3);
    vl_so3_log(I, phi);
    VL_TEST_ASSERT_CLOSE(phi, zero, 3, 0.0);
}

void test_so3_left_jacobian_matches_series(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double phi[3], S[9], Js[9], J[9];
            scaled_dir(k_dirs[d], k_angles[a], phi);
            vl_skew(phi, S);
            jac_series(S, Js, 3);
            vl_so3_left_jacobian(phi, J);
            VL_TEST_ASSERT_CLOSE(J, Js, 9, 1e-14);
        }
    }
}

void test_so3_left_jacobian_finite_difference(void)
{
    const double h = 1e-6;
    int a, d, i, r;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES - 1; ++a) { /* at 3.14 the log of exp(phi + d) wraps */
            double phi[3], R0[9], J[9], Jfd[9];
            scaled_dir(k_dirs[d], k_angles[a], phi);
            vl_so3_exp(phi, R0);
            vl_so3_left_jacobian(phi, J);
            for (i = 0; i < 3; ++i) {
                double pp[3], pm[3], Rp[9], Rm[9], Dp[9], Dm[9], lp[3], lm[3];
                memcpy(pp, phi, sizeof(pp));
                memcpy(pm, phi, sizeof(pm));
                pp[i] += h;
                pm[i] -= h;
                vl_so3_exp(pp, Rp);
                vl_so3_exp(pm, Rm);
                vl_matmul_bt(Rp, R0, Dp, 3, 3, 3);
                vl_matmul_bt(Rm, R0, Dm, 3, 3, 3);
                vl_so3_log(Dp, lp);
                vl_so3_log(Dm, lm);
                for (r = 0; r < 3; ++r) {
                    Jfd[3 * r + i] = (lp[r] - lm[r]) / (2.0 * h);
                }
            }
            VL_TEST_ASSERT_CLOSE(J, Jfd, 9, 1e-8);
        }
    }
}

void test_so3_normalize_restores_orthonormality(void)
{
    const double phi[3] = {0.4, -0.3, 1.9};
    double R[9], Rn[9], RRt[9], I[9];
    int i;
    vl_so3_exp(phi, R);
    memcpy(Rn, R, sizeof(R));
    for (i = 0; i < 9; ++i) {
        Rn[i] += 1e-6 * (double)((i * 7) % 5 - 2);
    }
    vl_so3_normalize(Rn);
    vl_matmul_bt(Rn, Rn, RRt, 3, 3, 3);
    identity(I, 3);
    VL_TEST_ASSERT_CLOSE(RRt, I, 9, 1e-15);
    /* The projection moves it by about the size of the perturbation, not more. */
    VL_TEST_ASSERT_CLOSE(Rn, R, 9, 1e-5);
}

void test_so3_normalize_keeps_rotation_unchanged(void)
{
    const double phi[3] = {-2.2, 0.7, 0.1};
    double R[9], Rn[9];
    vl_so3_exp(phi, R);
    memcpy(Rn, R, sizeof(R));
    vl_so3_normalize(Rn);
    VL_TEST_ASSERT_CLOSE(Rn, R, 9, 1e-15);
}

void test_so3_normalize_degenerate_input_gives_rotation(void)
{
    double bad[3][9] = {{-1, 0, 0, 0, 1, 0, 0, 0, 1}, /* reflection */
                        {0, 0, 0, 0, 0, 0, 0, 0, 0},  /* singular */
                        {1, 0, 0, 0, 1, 0, 0, 0, 1}}; /* NaN, filled below */
    int k;
    bad[2][4] = NAN;
    for (k = 0; k < 3; ++k) {
        double RRt[9], I[9], det;
        double *R = bad[k];
        vl_so3_normalize(R);
        vl_matmul_bt(R, R, RRt, 3, 3, 3);
        identity(I, 3);
        VL_TEST_ASSERT_CLOSE(RRt, I, 9, 1e-14);
        det = R[0] * (R[4] * R[8] - R[5] * R[7]) - R[1] * (R[3] * R[8] - R[5] * R[6]) +
              R[2] * (R[3] * R[7] - R[4] * R[6]);
        TEST_ASSERT_DOUBLE_WITHIN(1e-14, 1.0, det);
    }
}

/* ---- quaternions -------------------------------------------------------- */

void test_quaternion_to_rotation_known_value(void)
{
    /* 90 degrees about z. */
    const double q[4] = {sqrt(0.5), 0.0, 0.0, sqrt(0.5)};
    const double expect[9] = {0, -1, 0, 1, 0, 0, 0, 0, 1};
    double R[9];
    vl_quaternion_to_rotation(q, R);
    VL_TEST_ASSERT_CLOSE(R, expect, 9, 1e-15);
}

void test_rotation_to_quaternion_round_trip_all_branches(void)
{
    /* Near pi about each axis exercises every branch of the solver. */
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double phi[3], R[9], q[4], R2[9], q2[4];
            scaled_dir(k_dirs[d], k_angles[a], phi);
            vl_so3_exp(phi, R);
            vl_rotation_to_quaternion(R, q);
            TEST_ASSERT_TRUE(q[0] >= 0.0);
            TEST_ASSERT_DOUBLE_WITHIN(1e-15, 1.0, q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
            /* q = [cos(t/2), sin(t/2) axis] */
            TEST_ASSERT_DOUBLE_WITHIN(1e-15, cos(0.5 * k_angles[a]), q[0]);
            vl_quaternion_to_rotation(q, R2);
            VL_TEST_ASSERT_CLOSE(R2, R, 9, 1e-15);
            vl_rotation_to_quaternion(R2, q2);
            VL_TEST_ASSERT_CLOSE(q2, q, 4, 1e-15);
        }
    }
    {
        const double axes[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
        for (d = 0; d < 3; ++d) {
            double phi[3], R[9], q[4], R2[9];
            scaled_dir(axes[d], k_pi, phi);
            vl_so3_exp(phi, R);
            vl_rotation_to_quaternion(R, q);
            vl_quaternion_to_rotation(q, R2);
            VL_TEST_ASSERT_CLOSE(R2, R, 9, 1e-15);
            TEST_ASSERT_DOUBLE_WITHIN(1e-15, 1.0, fabs(q[1 + d]));
        }
    }
}

/* ---- SE(3) -------------------------------------------------------------- */

static void make_xi(int d, double t, double xi[6])
{
    const double rho[3] = {0.7, -1.4, 2.1};
    scaled_dir(k_dirs[d], t, xi + 3);
    xi[0] = rho[0] + 0.1 * d;
    xi[1] = rho[1];
    xi[2] = rho[2] - 0.2 * d;
}

void test_se3_exp_matches_series(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double xi[6], H[16], E[16], R[9], p[3], T[16];
            make_xi(d, k_angles[a], xi);
            se3_hat4(xi, H);
            expm_series(H, E, 4);
            vl_se3_exp(xi, R, p);
            pose_to_4x4(R, p, T);
            VL_TEST_ASSERT_CLOSE(T, E, 16, 1e-13);
        }
    }
}

void test_se3_log_round_trip_all_angles(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double xi[6], R[9], p[3], back[6];
            make_xi(d, k_angles[a], xi);
            vl_se3_exp(xi, R, p);
            vl_se3_log(R, p, back);
            VL_TEST_ASSERT_CLOSE(back, xi, 6, 1e-13);
        }
    }
}

void test_se3_log_round_trip_near_pi(void)
{
    const double eps[] = {1e-3, 1e-6, 1e-9};
    int e, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (e = 0; e < 3; ++e) {
            double xi[6], R[9], p[3], back[6];
            make_xi(d, k_pi - eps[e], xi);
            vl_se3_exp(xi, R, p);
            vl_se3_log(R, p, back);
            VL_TEST_ASSERT_CLOSE(back, xi, 6, 1e-12);
        }
    }
}

void test_se3_adjoint_conjugates_exp(void)
{
    /* T exp(xi) T^-1 = exp(Ad(T) xi) */
    const double xiT[6] = {1.5, -0.3, 0.8, 0.6, -1.1, 2.0};
    const double xi[6] = {-0.4, 0.9, 0.2, 0.3, 0.25, -0.7};
    double RT[9], pT[3], Ad[36], Adxi[6], Re[9], pe[3], R1[9], p1[3], RTi[9], pTi[3], Rl[9], pl[3], Rr[9], pr[3];
    vl_se3_exp(xiT, RT, pT);
    vl_se3_adjoint(RT, pT, Ad);
    vl_matmul(Ad, xi, Adxi, 6, 6, 1);
    vl_se3_exp(xi, Re, pe);
    compose(RT, pT, Re, pe, R1, p1);
    inverse(RT, pT, RTi, pTi);
    compose(R1, p1, RTi, pTi, Rl, pl);
    vl_se3_exp(Adxi, Rr, pr);
    VL_TEST_ASSERT_CLOSE(Rl, Rr, 9, 1e-14);
    VL_TEST_ASSERT_CLOSE(pl, pr, 3, 1e-14);
}

void test_se3_adjoint_inverse_inverts_the_adjoint(void)
{
    /* Ad(T^-1) Ad(T) = I, and Ad(T^-1) = Ad of the inverse pose */
    const double xiT[6] = {1.5, -0.3, 0.8, 0.6, -1.1, 2.0};
    static const double I6[36] = {1, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0,
                                  0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1};
    double R[9], p[3], Ri[9], pi[3], Ad[36], Ad_inv[36], Ad_of_inverse[36], prod[36];
    vl_se3_exp(xiT, R, p);
    vl_se3_adjoint(R, p, Ad);
    vl_se3_adjoint_inverse(R, p, Ad_inv);
    vl_matmul(Ad_inv, Ad, prod, 6, 6, 6);
    VL_TEST_ASSERT_CLOSE(prod, I6, 36, 1e-13);
    inverse(R, p, Ri, pi);
    vl_se3_adjoint(Ri, pi, Ad_of_inverse);
    VL_TEST_ASSERT_CLOSE(Ad_inv, Ad_of_inverse, 36, 1e-14);
}

void test_se3_adjoint_of_exp_equals_exp_of_curly_hat(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double xi[6], R[9], p[3], Ad[36], ad[36], E[36];
            make_xi(d, k_angles[a], xi);
            vl_se3_exp(xi, R, p);
            vl_se3_adjoint(R, p, Ad);
            vl_se3_curly_hat(xi, ad);
            expm_series(ad, E, 6);
            VL_TEST_ASSERT_CLOSE(Ad, E, 36, 1e-13);
        }
    }
}

void test_se3_curly_hat_is_commutator(void)
{
    /* hat(ad(x) y) = hat(x) hat(y) - hat(y) hat(x) */
    const double x[6] = {0.3, -0.2, 1.1, 0.5, -0.4, 0.9};
    const double y[6] = {-1.0, 0.7, 0.2, -0.3, 0.8, 0.1};
    double ad[36], z[6], Hx[16], Hy[16], Hz[16], XY[16], YX[16], C[16];
    int i;
    vl_se3_curly_hat(x, ad);
    vl_matmul(ad, y, z, 6, 6, 1);
    se3_hat4(x, Hx);
    se3_hat4(y, Hy);
    se3_hat4(z, Hz);
    vl_matmul(Hx, Hy, XY, 4, 4, 4);
    vl_matmul(Hy, Hx, YX, 4, 4, 4);
    for (i = 0; i < 16; ++i) {
        C[i] = XY[i] - YX[i];
    }
    VL_TEST_ASSERT_CLOSE(Hz, C, 16, 1e-15);
}

void test_se3_left_jacobian_matches_series(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double xi[6], ad[36], Js[36], J[36];
            make_xi(d, k_angles[a], xi);
            vl_se3_curly_hat(xi, ad);
            jac_series(ad, Js, 6);
            vl_se3_left_jacobian(xi, J);
            VL_TEST_ASSERT_CLOSE(J, Js, 36, 1e-13);
        }
    }
}

void test_se3_left_jacobian_small_angle_accuracy(void)
{
    /* The series branch must agree with the exact ad-series to ~1e-15 near zero,
     * and stay continuous across its threshold. */
    const double tiny[] = {1e-15, 1e-9, 1e-6, 1e-3, 0.01, 0.1};
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < 6; ++a) {
            double xi[6], ad[36], Js[36], J[36];
            make_xi(d, tiny[a], xi);
            vl_se3_curly_hat(xi, ad);
            jac_series(ad, Js, 6);
            vl_se3_left_jacobian(xi, J);
            VL_TEST_ASSERT_CLOSE(J, Js, 36, 1e-15);
        }
    }
    {
        /* Adjacent doubles on either side of the 1 rad switch (the x axis keeps |phi| exact). */
        double xa[6] = {0.7, -1.4, 2.1, 0.0, 0.0, 0.0}, xb[6], Ja[36], Jb[36];
        memcpy(xb, xa, sizeof(xa));
        xa[3] = nextafter(1.0, 0.0);
        xb[3] = 1.0;
        vl_se3_left_jacobian(xa, Ja);
        vl_se3_left_jacobian(xb, Jb);
        VL_TEST_ASSERT_CLOSE(Ja, Jb, 36, 1e-15);
    }
}

void test_se3_left_jacobian_equals_adjoint_times_right(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES; ++a) {
            double xi[6], R[9], p[3], Ad[36], Jl[36], Jr[36], AJr[36];
            make_xi(d, k_angles[a], xi);
            vl_se3_exp(xi, R, p);
            vl_se3_adjoint(R, p, Ad);
            vl_se3_left_jacobian(xi, Jl);
            vl_se3_right_jacobian(xi, Jr);
            vl_matmul(Ad, Jr, AJr, 6, 6, 6);
            VL_TEST_ASSERT_CLOSE(Jl, AJr, 36, 1e-13);
        }
    }
}

/* Column i of the numeric Jacobian of log(exp(xi + d) exp(xi)^-1) (left) or
 * log(exp(xi)^-1 exp(xi + d)) (right). */
static void se3_jacobian_fd(const double xi[6], int left, double Jfd[36])
{
    const double h = 1e-6;
    double R0[9], p0[3], R0i[9], p0i[3];
    int i, r;
    vl_se3_exp(xi, R0, p0);
    inverse(R0, p0, R0i, p0i);
    for (i = 0; i < 6; ++i) {
        double lpm[2][6];
        int s;
        for (s = 0; s < 2; ++s) {
            double x[6], R[9], p[3], Rd[9], pd[3];
            memcpy(x, xi, sizeof(x));
            x[i] += s == 0 ? h : -h;
            vl_se3_exp(x, R, p);
            if (left) {
                compose(R, p, R0i, p0i, Rd, pd);
            } else {
                compose(R0i, p0i, R, p, Rd, pd);
            }
            vl_se3_log(Rd, pd, lpm[s]);
        }
        for (r = 0; r < 6; ++r) {
            Jfd[6 * r + i] = (lpm[0][r] - lpm[1][r]) / (2.0 * h);
        }
    }
}

void test_se3_left_jacobian_finite_difference(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES - 1; ++a) {
            double xi[6], J[36], Jfd[36];
            make_xi(d, k_angles[a], xi);
            vl_se3_left_jacobian(xi, J);
            se3_jacobian_fd(xi, 1, Jfd);
            VL_TEST_ASSERT_CLOSE(J, Jfd, 36, 1e-8);
        }
    }
}

void test_se3_right_jacobian_finite_difference(void)
{
    int a, d;
    for (d = 0; d < N_DIRS; ++d) {
        for (a = 0; a < N_ANGLES - 1; ++a) {
            double xi[6], J[36], Jfd[36];
            make_xi(d, k_angles[a], xi);
            vl_se3_right_jacobian(xi, J);
            se3_jacobian_fd(xi, 0, Jfd);
            VL_TEST_ASSERT_CLOSE(J, Jfd, 36, 1e-8);
        }
    }
}

void test_circle_dot_matches_hat_product(void)
{
    /* hat(xi) [s; 1] = s_odot xi, exactly. */
    const double s[3] = {1.2, -0.4, 3.3};
    const double xi[6] = {0.1, -0.7, 0.25, -1.3, 0.6, 0.45};
    const double sh[4] = {s[0], s[1], s[2], 1.0};
    double H[16], Hs[4], D[18], Dxi[3];
    se3_hat4(xi, H);
    vl_matmul(H, sh, Hs, 4, 4, 1);
    vl_circle_dot(s, D);
    vl_matmul(D, xi, Dxi, 3, 6, 1);
    VL_TEST_ASSERT_CLOSE(Dxi, Hs, 3, 1e-15);
    TEST_ASSERT_DOUBLE_WITHIN(0.0, 0.0, Hs[3]);
}

void test_circle_dot_finite_difference(void)
{
    /* d/dxi of T exp(xi) s at xi = 0 is R s_odot: the right-perturbation point Jacobian. */
    const double xiT[6] = {0.5, 1.0, -2.0, 0.3, -0.9, 1.7};
    const double s[3] = {2.0, -1.5, 6.0};
    const double h = 1e-6;
    double RT[9], pT[3], D[18], J[18], Jfd[18];
    int i, r;
    vl_se3_exp(xiT, RT, pT);
    vl_circle_dot(s, D);
    vl_matmul(RT, D, J, 3, 3, 6);
    for (i = 0; i < 6; ++i) {
        double yv[2][3];
        int k;
        for (k = 0; k < 2; ++k) {
            double x[6] = {0, 0, 0, 0, 0, 0}, Re[9], pe[3], R[9], p[3];
            x[i] = k == 0 ? h : -h;
            vl_se3_exp(x, Re, pe);
            compose(RT, pT, Re, pe, R, p);
            vl_matmul(R, s, yv[k], 3, 3, 1);
            for (r = 0; r < 3; ++r) {
                yv[k][r] += p[r];
            }
        }
        for (r = 0; r < 3; ++r) {
            Jfd[6 * r + i] = (yv[0][r] - yv[1][r]) / (2.0 * h);
        }
    }
    VL_TEST_ASSERT_CLOSE(J, Jfd, 18, 1e-8);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_skew_matches_cross_product);
    RUN_TEST(test_matmul_variants_agree);
    RUN_TEST(test_so3_exp_matches_series);
    RUN_TEST(test_so3_exp_is_orthonormal);
    RUN_TEST(test_so3_log_round_trip_all_angles);
    RUN_TEST(test_so3_log_round_trip_near_pi);
    RUN_TEST(test_so3_log_at_pi_gives_valid_angle);
    RUN_TEST(test_so3_log_of_identity_is_zero);
    RUN_TEST(test_so3_left_jacobian_matches_series);
    RUN_TEST(test_so3_left_jacobian_finite_difference);
    RUN_TEST(test_so3_normalize_restores_orthonormality);
    RUN_TEST(test_so3_normalize_keeps_rotation_unchanged);
    RUN_TEST(test_so3_normalize_degenerate_input_gives_rotation);
    RUN_TEST(test_quaternion_to_rotation_known_value);
    RUN_TEST(test_rotation_to_quaternion_round_trip_all_branches);
    RUN_TEST(test_se3_exp_matches_series);
    RUN_TEST(test_se3_log_round_trip_all_angles);
    RUN_TEST(test_se3_log_round_trip_near_pi);
    RUN_TEST(test_se3_adjoint_conjugates_exp);
    RUN_TEST(test_se3_adjoint_inverse_inverts_the_adjoint);
    RUN_TEST(test_se3_adjoint_of_exp_equals_exp_of_curly_hat);
    RUN_TEST(test_se3_curly_hat_is_commutator);
    RUN_TEST(test_se3_left_jacobian_matches_series);
    RUN_TEST(test_se3_left_jacobian_small_angle_accuracy);
    RUN_TEST(test_se3_left_jacobian_equals_adjoint_times_right);
    RUN_TEST(test_se3_left_jacobian_finite_difference);
    RUN_TEST(test_se3_right_jacobian_finite_difference);
    RUN_TEST(test_circle_dot_matches_hat_product);
    RUN_TEST(test_circle_dot_finite_difference);
    return UNITY_END();
}
