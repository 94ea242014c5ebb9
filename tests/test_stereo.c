/**
 * @file test_stereo.c
 * @brief Unity tests of the stereo camera model in core/src/vl_stereo.c.
 *
 * Calibration is fixed to KITTI's rectified values (sequence 00-02 style) with
 * cam_T_imu = identity, which the model functions do not use anyway.
 */
#include "unity.h"
#include "vl_test_util.h"
#include "vl_se3.h"
#include "vl_stereo.h"

#include <math.h>
#include <string.h>

static vl_calibration_t cal;

/* Points spanning near/far, left/right/up/down and off-axis. */
static const double k_points[][3] = {{0.0, 0.0, 5.0},   {1.2, -0.8, 3.0}, {-4.0, 1.5, 12.0},
                                     {10.0, 2.0, 60.0}, {0.3, 0.2, 0.8},  {-25.0, -3.0, 80.0}};
#define N_POINTS ((int)(sizeof(k_points) / sizeof(k_points[0])))

void setUp(void)
{
    vl_test_kitti_calibration(&cal, 0);
}

void tearDown(void)
{
}

static double max_abs(const double *a, int n)
{
    double m = 0.0;
    int i;
    for (i = 0; i < n; ++i) {
        if (fabs(a[i]) > m) {
            m = fabs(a[i]);
        }
    }
    return m;
}

void test_stereo_project_known_values(void)
{
    /* A point on the left optical axis projects to the principal point, and
     * the right image sees it shifted left by the disparity fx b / z. */
    const double c[3] = {0.0, 0.0, 5.0};
    double y[3];
    vl_stereo_project(&cal, c, y, NULL);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, cal.cx, y[0]);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, cal.cy, y[1]);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, cal.cx - cal.fx * cal.baseline / 5.0, y[2]);
}

void test_stereo_project_jacobian_finite_difference(void)
{
    int k, i, r;
    for (k = 0; k < N_POINTS; ++k) {
        double y[3], J[9], Jfd[9];
        const double h = 1e-6 * k_points[k][2];
        vl_stereo_project(&cal, k_points[k], y, J);
        for (i = 0; i < 3; ++i) {
            double cp[3], cm[3], yp[3], ym[3];
            memcpy(cp, k_points[k], sizeof(cp));
            memcpy(cm, k_points[k], sizeof(cm));
            cp[i] += h;
            cm[i] -= h;
            vl_stereo_project(&cal, cp, yp, NULL);
            vl_stereo_project(&cal, cm, ym, NULL);
            for (r = 0; r < 3; ++r) {
                Jfd[3 * r + i] = (yp[r] - ym[r]) / (2.0 * h);
            }
        }
        /* Entries reach ~900 px/m at z = 0.8 m; relative accuracy ~1e-9. */
        VL_TEST_ASSERT_CLOSE(J, Jfd, 9, 1e-6);
    }
}

void test_stereo_project_null_jacobian_gives_same_projection(void)
{
    double y1[3], y2[3], J[9];
    vl_stereo_project(&cal, k_points[1], y1, NULL);
    vl_stereo_project(&cal, k_points[1], y2, J);
    VL_TEST_ASSERT_CLOSE(y1, y2, 3, 0.0);
}

void test_stereo_matrix_matches_projection(void)
{
    /* M pi(q): rows 1..3 are the compressed projection and row 4 equals row 2. */
    double M[16];
    int k;
    vl_stereo_matrix(&cal, M);
    TEST_ASSERT_DOUBLE_WITHIN(0.0, -cal.fx * cal.baseline, M[11]);
    for (k = 0; k < N_POINTS; ++k) {
        const double *c = k_points[k];
        const double q[4] = {c[0] / c[2], c[1] / c[2], 1.0, 1.0 / c[2]};
        double z[4], y[3];
        vl_matmul(M, q, z, 4, 4, 1);
        vl_stereo_project(&cal, c, y, NULL);
        VL_TEST_ASSERT_CLOSE(z, y, 3, 1e-10);
        TEST_ASSERT_DOUBLE_WITHIN(0.0, z[1], z[3]);
    }
}

void test_stereo_compress_averages_rows(void)
{
    const vl_stereo_obs_t obs = {7, 650.25, 200.5, 610.75, 201.5};
    double y[3];
    vl_stereo_compress(&obs, y);
    TEST_ASSERT_DOUBLE_WITHIN(0.0, 650.25, y[0]);
    TEST_ASSERT_DOUBLE_WITHIN(0.0, 201.0, y[1]);
    TEST_ASSERT_DOUBLE_WITHIN(0.0, 610.75, y[2]);
}

void test_stereo_compress_preserves_information(void)
{
    /* The header's claim: with V = s^2 I4 on the 4-row model, J4^T J4 / s^2
     * equals J3^T diag(1, 2, 1) J3 / s^2 for the compressed model. */
    double M[16], J3[9], y[3], J4[12], I4[9], I3[9], W3J[9];
    const double *c = k_points[2];
    int i, j;
    vl_stereo_matrix(&cal, M);
    vl_stereo_project(&cal, c, y, J3);
    /* d(M pi(q))/dc with q = [c; 1]: dpi/dc = [[1/z, 0, -x/z^2], [0, 1/z, -y/z^2], [0, 0, 0], [0, 0, -1/z^2]] */
    {
        const double z = c[2];
        const double dpi[12] = {1.0 / z, 0.0, -c[0] / (z * z), 0.0, 1.0 / z, -c[1] / (z * z), 0.0, 0.0, 0.0,
                                0.0,     0.0, -1.0 / (z * z)};
        vl_matmul(M, dpi, J4, 4, 4, 3);
    }
    VL_TEST_ASSERT_CLOSE(J4, J3, 9, 1e-9); /* rows 1..3 are the compressed Jacobian */
    vl_matmul_at(J4, J4, I4, 3, 4, 3);
    memcpy(W3J, J3, sizeof(W3J));
    for (j = 0; j < 3; ++j) {
        W3J[3 + j] *= 2.0;
    }
    vl_matmul_at(J3, W3J, I3, 3, 3, 3);
    for (i = 0; i < 9; ++i) {
        TEST_ASSERT_DOUBLE_WITHIN(1e-9 * fabs(I4[i]) + 1e-9, I4[i], I3[i]);
    }
}

void test_stereo_triangulate_round_trip(void)
{
    int k;
    for (k = 0; k < N_POINTS; ++k) {
        double y[3], c[3], y2[3];
        vl_stereo_project(&cal, k_points[k], y, NULL);
        vl_stereo_triangulate(&cal, y, c, NULL);
        TEST_ASSERT_DOUBLE_WITHIN(1e-12 * k_points[k][2] * k_points[k][2], 0.0,
                                  vl_test_max_abs_diff(c, k_points[k], 3));
        vl_stereo_project(&cal, c, y2, NULL);
        VL_TEST_ASSERT_CLOSE(y2, y, 3, 1e-9);
    }
}

void test_stereo_triangulate_known_values(void)
{
    /* Disparity fx b / z at the principal point gives depth z on the optical axis. */
    const double z = 20.0;
    const double y[3] = {cal.cx, cal.cy, cal.cx - cal.fx * cal.baseline / z};
    double c[3];
    vl_stereo_triangulate(&cal, y, c, NULL);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, 0.0, c[0]);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, 0.0, c[1]);
    TEST_ASSERT_DOUBLE_WITHIN(1e-11, z, c[2]);
}

void test_stereo_triangulate_jacobian_finite_difference(void)
{
    const double h = 1e-4; /* px */
    int k, i, r;
    for (k = 0; k < N_POINTS; ++k) {
        double y[3], c[3], J[9], Jfd[9];
        vl_stereo_project(&cal, k_points[k], y, NULL);
        vl_stereo_triangulate(&cal, y, c, J);
        for (i = 0; i < 3; ++i) {
            double yp[3], ym[3], cp[3], cm[3];
            memcpy(yp, y, sizeof(yp));
            memcpy(ym, y, sizeof(ym));
            yp[i] += h;
            ym[i] -= h;
            vl_stereo_triangulate(&cal, yp, cp, NULL);
            vl_stereo_triangulate(&cal, ym, cm, NULL);
            for (r = 0; r < 3; ++r) {
                Jfd[3 * r + i] = (cp[r] - cm[r]) / (2.0 * h);
            }
        }
        /* Entries reach ~20 m/px at 80 m; the O(h^2) error scales with z^3. */
        TEST_ASSERT_DOUBLE_WITHIN(1e-7 * (1.0 + max_abs(J, 9)), 0.0, vl_test_max_abs_diff(J, Jfd, 9));
    }
}

void test_stereo_triangulate_jacobian_inverts_projection_jacobian(void)
{
    int k, i;
    for (k = 0; k < N_POINTS; ++k) {
        double y[3], c[3], Jp[9], Jt[9], P[9];
        const double I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
        vl_stereo_project(&cal, k_points[k], y, Jp);
        vl_stereo_triangulate(&cal, y, c, Jt);
        vl_matmul(Jt, Jp, P, 3, 3, 3);
        for (i = 0; i < 9; ++i) {
            TEST_ASSERT_DOUBLE_WITHIN(1e-10, I[i], P[i]);
        }
    }
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_stereo_project_known_values);
    RUN_TEST(test_stereo_project_jacobian_finite_difference);
    RUN_TEST(test_stereo_project_null_jacobian_gives_same_projection);
    RUN_TEST(test_stereo_matrix_matches_projection);
    RUN_TEST(test_stereo_compress_averages_rows);
    RUN_TEST(test_stereo_compress_preserves_information);
    RUN_TEST(test_stereo_triangulate_round_trip);
    RUN_TEST(test_stereo_triangulate_known_values);
    RUN_TEST(test_stereo_triangulate_jacobian_finite_difference);
    RUN_TEST(test_stereo_triangulate_jacobian_inverts_projection_jacobian);
    return UNITY_END();
}
