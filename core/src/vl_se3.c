/**
 * @file vl_se3.c
 * @brief SO(3)/SE(3) exponential, logarithm, adjoints and Jacobians (row-major, C99).
 *
 * The closed forms follow the usual Rodrigues-type expansions. Every
 * coefficient of the form (trig combination) / theta^k loses digits to
 * cancellation as theta -> 0, so below VL_SERIES_ANGLE each one is evaluated
 * from its Taylor series instead (no cancellation there: the terms shrink fast).
 */
#include "vl_se3.h"

#include "vislam/vislam.h"

#include <math.h>

/* Below this angle (rad) every coefficient comes from its Taylor series.
 * The closed forms lose about eps / theta^2 (SO(3) terms) to 180 eps / theta^4
 * (the last Q coefficient) of relative accuracy to cancellation, so the
 * switch sits where both sides are good to a few 1e-14 or better. */
#define VL_SERIES_ANGLE 1.0
/* Terms of each series: at theta = 1 the dropped remainder is below 1e-30. */
#define VL_SERIES_TERMS 14

/* sum_k (-1)^k t^(2k) / (2k + m)!, i.e. the Taylor series of sin t / t (m = 1),
 * (1 - cos t) / t^2 (m = 2), (t - sin t) / t^3 (m = 3), (t^2/2 + cos t - 1) / t^4 (m = 4). */
static double vl_trig_series(double t2, int m)
{
    double term = 1.0;
    double sum;
    int k;
    for (k = 2; k <= m; ++k) {
        term /= k;
    }
    sum = term;
    for (k = 0; k < VL_SERIES_TERMS; ++k) {
        term *= -t2 / ((double)(2 * k + m + 1) * (double)(2 * k + m + 2));
        sum += term;
    }
    return sum;
}

void vl_skew(const double v[3], double S[9])
{
    S[0] = 0.0;
    S[1] = -v[2];
    S[2] = v[1];
    S[3] = v[2];
    S[4] = 0.0;
    S[5] = -v[0];
    S[6] = -v[1];
    S[7] = v[0];
    S[8] = 0.0;
}

void vl_matmul(const double *A, const double *B, double *C, int r, int k, int c)
{
    int i, j, l;
    for (i = 0; i < r; ++i) {
        for (j = 0; j < c; ++j) {
            double s = 0.0;
            for (l = 0; l < k; ++l) {
                s += A[i * k + l] * B[l * c + j];
            }
            C[i * c + j] = s;
        }
    }
}

void vl_matmul_bt(const double *A, const double *B, double *C, int r, int k, int c)
{
    int i, j, l;
    for (i = 0; i < r; ++i) {
        for (j = 0; j < c; ++j) {
            double s = 0.0;
            for (l = 0; l < k; ++l) {
                s += A[i * k + l] * B[j * k + l];
            }
            C[i * c + j] = s;
        }
    }
}

void vl_matmul_at(const double *A, const double *B, double *C, int r, int k, int c)
{
    int i, j, l;
    for (i = 0; i < r; ++i) {
        for (j = 0; j < c; ++j) {
            double s = 0.0;
            for (l = 0; l < k; ++l) {
                s += A[l * r + i] * B[l * c + j];
            }
            C[i * c + j] = s;
        }
    }
}

double vl_norm3(const double v[3])
{
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

/* M = a I + b S + c S S for the skew matrix S of v (the common shape of exp(phi) and J(phi)). */
static void vl_so3_poly(const double v[3], double a, double b, double c, double M[9])
{
    double S[9];
    double S2[9];
    int i;
    vl_skew(v, S);
    vl_matmul(S, S, S2, 3, 3, 3);
    for (i = 0; i < 9; ++i) {
        M[i] = b * S[i] + c * S2[i];
    }
    M[0] += a;
    M[4] += a;
    M[8] += a;
}

/* sin(t)/t, (1 - cos t)/t^2 and (t - sin t)/t^3. */
static void vl_so3_coeffs(double t, double *sinc, double *cosc, double *sinc3)
{
    if (t < VL_SERIES_ANGLE) {
        const double t2 = t * t;
        *sinc = vl_trig_series(t2, 1);
        *cosc = vl_trig_series(t2, 2);
        *sinc3 = vl_trig_series(t2, 3);
    } else {
        const double s = sin(t);
        const double c = cos(t);
        *sinc = s / t;
        *cosc = (1.0 - c) / (t * t);
        *sinc3 = (t - s) / (t * t * t);
    }
}

void vl_so3_exp(const double phi[3], double R[9])
{
    double sinc, cosc, sinc3;
    vl_so3_coeffs(vl_norm3(phi), &sinc, &cosc, &sinc3);
    vl_so3_poly(phi, 1.0, sinc, cosc, R);
}

void vl_so3_left_jacobian(const double phi[3], double J[9])
{
    double sinc, cosc, sinc3;
    vl_so3_coeffs(vl_norm3(phi), &sinc, &cosc, &sinc3);
    vl_so3_poly(phi, 1.0, cosc, sinc3, J);
}

/* Inverse left Jacobian of SO(3): I - hat(phi)/2 + k hat(phi)^2 with
 * k = (1 - (t/2) cot(t/2)) / t^2, written with the half angle so it stays
 * well conditioned up to t = pi (where sin(t) -> 0 but sin(t/2) -> 1). */
static void vl_so3_left_jacobian_inverse(const double phi[3], double Ji[9])
{
    const double t = vl_norm3(phi);
    double k;
    if (t < VL_SERIES_ANGLE) {
        /* k = sum_n |B_2n| t^(2n-2) / (2n)! (Bernoulli numbers); the terms shrink
         * by (t / 2 pi)^2, so ten of them leave < 1e-16 at t = 1. */
        static const double coef[10] = {1.0 / 12.0,
                                        1.0 / 720.0,
                                        1.0 / 30240.0,
                                        1.0 / 1209600.0,
                                        1.0 / 47900160.0,
                                        691.0 / 1307674368000.0,
                                        1.0 / 74724249600.0,
                                        3.3896802963225827e-13,
                                        8.586062056277845e-15,
                                        2.174868698558062e-16};
        const double t2 = t * t;
        int n;
        k = coef[9];
        for (n = 8; n >= 0; --n) {
            k = coef[n] + t2 * k;
        }
    } else {
        const double h = 0.5 * t;
        k = (1.0 - h * cos(h) / sin(h)) / (t * t);
    }
    vl_so3_poly(phi, 1.0, -0.5, k, Ji);
}

void vl_so3_log(const double R[9], double phi[3])
{
    /* w = sin(t) a from the antisymmetric part; cos(t) from the trace. */
    double w[3];
    double c, s, t;
    w[0] = 0.5 * (R[7] - R[5]);
    w[1] = 0.5 * (R[2] - R[6]);
    w[2] = 0.5 * (R[3] - R[1]);
    c = 0.5 * (R[0] + R[4] + R[8] - 1.0);
    if (c > 1.0) {
        c = 1.0;
    } else if (c < -1.0) {
        c = -1.0;
    }
    s = vl_norm3(w);
    t = atan2(s, c);

    if (c >= 0.0) {
        /* t <= pi/2: the axis from w is accurate (relative error eps / sin t, sin t >= t * 2/pi). */
        /* t / sin(t) has no cancellation; s == 0 only at t == 0. */
        const double scale = s > 0.0 ? t / s : 1.0;
        phi[0] = scale * w[0];
        phi[1] = scale * w[1];
        phi[2] = scale * w[2];
    } else {
        /* t > pi/2: sin t -> 0 near pi, so take the axis from the symmetric part
         * B = (R + R^T)/2 - c I = (1 - c) a a^T through its largest diagonal
         * entry (>= (1 - c)/3 >= 1/3), and only its sign from w. */
        double B[9];
        double a[3];
        double n;
        int i, j;
        for (i = 0; i < 3; ++i) {
            for (j = 0; j < 3; ++j) {
                B[3 * i + j] = 0.5 * (R[3 * i + j] + R[3 * j + i]);
            }
            B[4 * i] -= c;
        }
        j = 0;
        if (B[4] > B[4 * j]) {
            j = 1;
        }
        if (B[8] > B[4 * j]) {
            j = 2;
        }
        a[0] = B[j];
        a[1] = B[3 + j];
        a[2] = B[6 + j];
        n = vl_norm3(a);
        if (!(n > 0.0)) {
            /* Only for a non-rotation input; keep the output finite. */
            phi[0] = phi[1] = phi[2] = 0.0;
            return;
        }
        if (a[0] * w[0] + a[1] * w[1] + a[2] * w[2] < 0.0) {
            n = -n;
        }
        phi[0] = t * a[0] / n;
        phi[1] = t * a[1] / n;
        phi[2] = t * a[2] / n;
    }
}

void vl_se3_exp(const double xi[6], double R[9], double p[3])
{
    double J[9];
    vl_so3_exp(xi + 3, R);
    vl_so3_left_jacobian(xi + 3, J);
    vl_matmul(J, xi, p, 3, 3, 1);
}

void vl_se3_log(const double R[9], const double p[3], double xi[6])
{
    double Ji[9];
    vl_so3_log(R, xi + 3);
    vl_so3_left_jacobian_inverse(xi + 3, Ji);
    vl_matmul(Ji, p, xi, 3, 3, 1);
}

/* Writes the 3x3 block B at (row 3 bi, col 3 bj) of a 6x6 row-major matrix. */
static void vl_set_block(double M[36], int bi, int bj, const double B[9])
{
    int i, j;
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            M[(3 * bi + i) * 6 + 3 * bj + j] = B[3 * i + j];
        }
    }
}

void vl_se3_adjoint(const double R[9], const double p[3], double Ad[36])
{
    static const double Z[9] = {0.0};
    double P[9];
    double PR[9];
    vl_skew(p, P);
    vl_matmul(P, R, PR, 3, 3, 3);
    vl_set_block(Ad, 0, 0, R);
    vl_set_block(Ad, 0, 1, PR);
    vl_set_block(Ad, 1, 0, Z);
    vl_set_block(Ad, 1, 1, R);
}

void vl_se3_adjoint_inverse(const double R[9], const double p[3], double Ad_inv[36])
{
    double Rt[9];
    double pt[3];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            Rt[3 * i + j] = R[3 * j + i];
        }
    }
    vl_matmul(Rt, p, pt, 3, 3, 1);
    for (int i = 0; i < 3; ++i) {
        pt[i] = -pt[i];
    }
    vl_se3_adjoint(Rt, pt, Ad_inv);
}

void vl_se3_curly_hat(const double xi[6], double ad[36])
{
    static const double Z[9] = {0.0};
    double Rho[9];
    double Phi[9];
    vl_skew(xi, Rho);
    vl_skew(xi + 3, Phi);
    vl_set_block(ad, 0, 0, Phi);
    vl_set_block(ad, 0, 1, Rho);
    vl_set_block(ad, 1, 0, Z);
    vl_set_block(ad, 1, 1, Phi);
}

/*
 * Q(rho, phi), the top-right block of the SE(3) left Jacobian (Barfoot,
 * State Estimation for Robotics, eq. 7.86):
 *   Q = 1/2 P + a (F P + P F + F P F) + b (F F P + P F F - 3 F P F)
 *       + c (F P F F + F F P F)
 * with P = hat(rho), F = hat(phi), t = |phi| and
 *   a = (t - sin t) / t^3, b = (t^2 + 2 cos t - 2) / (2 t^4),
 *   c = (2 t - 3 sin t + t cos t) / (2 t^5).
 */
static void vl_se3_q(const double rho[3], const double phi[3], double Q[9])
{
    const double t = vl_norm3(phi);
    double a, b, c;
    double P[9], F[9], FP[9], PF[9], FPF[9], FFP[9], PFF[9], FPFF[9], FFPF[9];
    int i;

    if (t < VL_SERIES_ANGLE) {
        const double t2 = t * t;
        /* c = sum_k (-1)^k (k + 1) t^(2k) / (2k + 5)! */
        double term = 1.0 / 120.0;
        int k;
        a = vl_trig_series(t2, 3);
        b = vl_trig_series(t2, 4);
        c = term;
        for (k = 0; k < VL_SERIES_TERMS; ++k) {
            term *= -t2 / ((double)(2 * k + 6) * (double)(2 * k + 7));
            c += (double)(k + 2) * term;
        }
    } else {
        const double s = sin(t);
        const double co = cos(t);
        const double t2 = t * t;
        a = (t - s) / (t2 * t);
        b = (t2 + 2.0 * co - 2.0) / (2.0 * t2 * t2);
        c = (2.0 * t - 3.0 * s + t * co) / (2.0 * t2 * t2 * t);
    }

    vl_skew(rho, P);
    vl_skew(phi, F);
    vl_matmul(F, P, FP, 3, 3, 3);
    vl_matmul(P, F, PF, 3, 3, 3);
    vl_matmul(FP, F, FPF, 3, 3, 3);
    vl_matmul(F, FP, FFP, 3, 3, 3);
    vl_matmul(PF, F, PFF, 3, 3, 3);
    vl_matmul(FPF, F, FPFF, 3, 3, 3);
    vl_matmul(F, FPF, FFPF, 3, 3, 3);
    for (i = 0; i < 9; ++i) {
        Q[i] =
            0.5 * P[i] + a * (FP[i] + PF[i] + FPF[i]) + b * (FFP[i] + PFF[i] - 3.0 * FPF[i]) + c * (FPFF[i] + FFPF[i]);
    }
}

void vl_se3_left_jacobian(const double xi[6], double J[36])
{
    static const double Z[9] = {0.0};
    double Jr[9];
    double Q[9];
    vl_so3_left_jacobian(xi + 3, Jr);
    vl_se3_q(xi, xi + 3, Q);
    vl_set_block(J, 0, 0, Jr);
    vl_set_block(J, 0, 1, Q);
    vl_set_block(J, 1, 0, Z);
    vl_set_block(J, 1, 1, Jr);
}

void vl_se3_right_jacobian(const double xi[6], double J[36])
{
    double m[6];
    int i;
    for (i = 0; i < 6; ++i) {
        m[i] = -xi[i];
    }
    vl_se3_left_jacobian(m, J);
}

void vl_circle_dot(const double s[3], double D[18])
{
    int i;
    for (i = 0; i < 18; ++i) {
        D[i] = 0.0;
    }
    D[0] = 1.0;
    D[7] = 1.0;
    D[14] = 1.0;
    /* -hat(s) in columns 3..5 */
    D[4] = s[2];
    D[5] = -s[1];
    D[9] = -s[2];
    D[11] = s[0];
    D[15] = s[1];
    D[16] = -s[0];
}

void vl_rotation_to_quaternion(const double R[9], double q[4])
{
    /* Shepperd: solve from the largest of w^2, x^2, y^2, z^2 (each 4x the
     * corresponding diagonal combination) so the division is by >= 1/2. */
    const double tr = R[0] + R[4] + R[8];
    double n;
    int i;
    if (tr >= R[0] && tr >= R[4] && tr >= R[8]) {
        const double r = sqrt(1.0 + tr);
        q[0] = 0.5 * r;
        q[1] = 0.5 * (R[7] - R[5]) / r;
        q[2] = 0.5 * (R[2] - R[6]) / r;
        q[3] = 0.5 * (R[3] - R[1]) / r;
    } else if (R[0] >= R[4] && R[0] >= R[8]) {
        const double r = sqrt(1.0 + R[0] - R[4] - R[8]);
        q[0] = 0.5 * (R[7] - R[5]) / r;
        q[1] = 0.5 * r;
        q[2] = 0.5 * (R[1] + R[3]) / r;
        q[3] = 0.5 * (R[2] + R[6]) / r;
    } else if (R[4] >= R[8]) {
        const double r = sqrt(1.0 - R[0] + R[4] - R[8]);
        q[0] = 0.5 * (R[2] - R[6]) / r;
        q[1] = 0.5 * (R[1] + R[3]) / r;
        q[2] = 0.5 * r;
        q[3] = 0.5 * (R[5] + R[7]) / r;
    } else {
        const double r = sqrt(1.0 - R[0] - R[4] + R[8]);
        q[0] = 0.5 * (R[3] - R[1]) / r;
        q[1] = 0.5 * (R[2] + R[6]) / r;
        q[2] = 0.5 * (R[5] + R[7]) / r;
        q[3] = 0.5 * r;
    }
    if (q[0] < 0.0) {
        for (i = 0; i < 4; ++i) {
            q[i] = -q[i];
        }
    }
    n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (n > 0.0) {
        for (i = 0; i < 4; ++i) {
            q[i] /= n;
        }
    }
}

void vl_quaternion_to_rotation(const double q[4], double R[9])
{
    const double n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    /* Dividing by |q|^2 makes a slightly non-unit quaternion still give a rotation. */
    const double s = n2 > 0.0 ? 2.0 / n2 : 0.0;
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    R[0] = 1.0 - s * (y * y + z * z);
    R[1] = s * (x * y - w * z);
    R[2] = s * (x * z + w * y);
    R[3] = s * (x * y + w * z);
    R[4] = 1.0 - s * (x * x + z * z);
    R[5] = s * (y * z - w * x);
    R[6] = s * (x * z - w * y);
    R[7] = s * (y * z + w * x);
    R[8] = 1.0 - s * (x * x + y * y);
}

void vl_so3_normalize(double R[9])
{
    /* Newton iteration for the orthogonal polar factor, X <- (X + X^-T) / 2:
     * the nearest rotation in the Frobenius norm, converging quadratically
     * for the nearly orthonormal matrices that accumulated round-off produces. */
    int it, i;
    for (it = 0; it < 20; ++it) {
        double C[9];
        double det, change = 0.0;
        /* Cofactor matrix: X^-T = C / det(X). */
        C[0] = R[4] * R[8] - R[5] * R[7];
        C[1] = R[5] * R[6] - R[3] * R[8];
        C[2] = R[3] * R[7] - R[4] * R[6];
        C[3] = R[2] * R[7] - R[1] * R[8];
        C[4] = R[0] * R[8] - R[2] * R[6];
        C[5] = R[1] * R[6] - R[0] * R[7];
        C[6] = R[1] * R[5] - R[2] * R[4];
        C[7] = R[2] * R[3] - R[0] * R[5];
        C[8] = R[0] * R[4] - R[1] * R[3];
        det = R[0] * C[0] + R[1] * C[1] + R[2] * C[2];
        if (!(det > 1e-12) || !isfinite(det)) {
            /* Far from a rotation (reflection, singular or non-finite): the
             * quaternion route always lands on SO(3). */
            double q[4];
            vl_rotation_to_quaternion(R, q);
            if (!(isfinite(q[0]) && isfinite(q[1]) && isfinite(q[2]) && isfinite(q[3])) ||
                !(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] > 0.0)) {
                q[0] = 1.0;
                q[1] = q[2] = q[3] = 0.0;
            }
            vl_quaternion_to_rotation(q, R);
            return;
        }
        for (i = 0; i < 9; ++i) {
            const double next = 0.5 * (R[i] + C[i] / det);
            change += fabs(next - R[i]);
            R[i] = next;
        }
        if (change < 1e-15) {
            break;
        }
    }
}
