/*
 * vl_init's agreement check between the caller's build and the library's: a
 * caller compiled with another capacity or another vislam.h (other sizes, or the
 * same sizes laid out otherwise) is refused with VL_ERR_ABI_MISMATCH before the
 * library reads its configuration or writes its estimator. (install_consumer
 * checks the same through separately compiled programs: one with
 * -DVL_MAX_LANDMARKS=64, one against headers with two configuration keys swapped.)
 */
#include <string.h>

#include "unity.h"
#include "vislam/vislam.h"
#include "vl_test_util.h"

static vl_estimator_t est;

/* Marks the start of the estimator, where vl_init's first write lands. */
#define SENTINEL 0xA5

static vl_config_t kitti_config(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_test_kitti_calibration(&cfg.calibration, 1);
    return cfg;
}

/* True when the first bytes of the estimator still hold the sentinel. */
static int untouched(void)
{
    const unsigned char *b = (const unsigned char *)&est;
    for (size_t i = 0; i < sizeof(vl_config_t) + sizeof(vl_counters_t); ++i) {
        if (b[i] != SENTINEL) {
            return 0;
        }
    }
    return 1;
}

void setUp(void)
{
    memset(&est, SENTINEL, sizeof(est));
}

void tearDown(void)
{
}

void test_matching_build_initializes(void)
{
    const vl_config_t cfg = kitti_config();
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    TEST_ASSERT_FALSE(untouched());
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init_checked(&est, &cfg, sizeof(vl_estimator_t), sizeof(vl_config_t),
                                                 sizeof(vl_stereo_frame_t), VL_MAX_LANDMARKS, vl_abi_layout()));
}

void test_other_capacity_is_refused_untouched(void)
{
    const vl_config_t cfg = kitti_config();
    TEST_ASSERT_EQUAL_INT(VL_ERR_ABI_MISMATCH,
                          vl_init_checked(&est, &cfg, sizeof(vl_estimator_t), sizeof(vl_config_t),
                                          sizeof(vl_stereo_frame_t), VL_MAX_LANDMARKS / 2, vl_abi_layout()));
    TEST_ASSERT_TRUE(untouched());
    TEST_ASSERT_EQUAL_INT(VL_ERR_ABI_MISMATCH,
                          vl_init_checked(&est, &cfg, sizeof(vl_estimator_t), sizeof(vl_config_t),
                                          sizeof(vl_stereo_frame_t), VL_MAX_LANDMARKS + 1, vl_abi_layout()));
    TEST_ASSERT_TRUE(untouched());
}

void test_other_sizes_are_refused_untouched(void)
{
    const vl_config_t cfg = kitti_config();
    /* A smaller estimator: what a caller with a smaller VL_MAX_LANDMARKS allocates. */
    TEST_ASSERT_EQUAL_INT(VL_ERR_ABI_MISMATCH,
                          vl_init_checked(&est, &cfg, sizeof(vl_estimator_t) / 2, sizeof(vl_config_t),
                                          sizeof(vl_stereo_frame_t), VL_MAX_LANDMARKS, vl_abi_layout()));
    TEST_ASSERT_TRUE(untouched());
    /* A configuration from another vislam.h (one key more or less). */
    TEST_ASSERT_EQUAL_INT(VL_ERR_ABI_MISMATCH,
                          vl_init_checked(&est, &cfg, sizeof(vl_estimator_t), sizeof(vl_config_t) - sizeof(double),
                                          sizeof(vl_stereo_frame_t), VL_MAX_LANDMARKS, vl_abi_layout()));
    TEST_ASSERT_TRUE(untouched());
    /* Frames of another VL_MAX_FRAME_FEATURES. */
    TEST_ASSERT_EQUAL_INT(VL_ERR_ABI_MISMATCH, vl_init_checked(&est, &cfg, sizeof(vl_estimator_t), sizeof(vl_config_t),
                                                               sizeof(vl_stereo_frame_t) + sizeof(vl_stereo_obs_t),
                                                               VL_MAX_LANDMARKS, vl_abi_layout()));
    TEST_ASSERT_TRUE(untouched());
}

void test_other_layout_is_refused_untouched(void)
{
    /* Every size agrees, the layout does not: a vislam.h with two keys swapped or a member
     * renamed (install_consumer compiles such a caller for real). */
    const vl_config_t cfg = kitti_config();
    TEST_ASSERT_EQUAL_INT(VL_ERR_ABI_MISMATCH,
                          vl_init_checked(&est, &cfg, sizeof(vl_estimator_t), sizeof(vl_config_t),
                                          sizeof(vl_stereo_frame_t), VL_MAX_LANDMARKS, vl_abi_layout() ^ 1u));
    TEST_ASSERT_TRUE(untouched());
}

void test_layout_depends_on_names_offsets_and_sizes(void)
{
    /* The hash of one member changes with each of the three, so a swap of two members of one
     * size (same offsets and sizes, other names) or a rename changes the layout's. */
    const uint32_t h = 2166136261u;
    const uint32_t base = vl_abi_mix_(h, "vl_config_t.gate_chi2 DOUBLE", 8, 8);
    TEST_ASSERT_NOT_EQUAL(base, vl_abi_mix_(h, "vl_config_t.ransac_threshold DOUBLE", 8, 8));
    TEST_ASSERT_NOT_EQUAL(base, vl_abi_mix_(h, "vl_config_t.gate_chi2 UINT32", 8, 8));
    TEST_ASSERT_NOT_EQUAL(base, vl_abi_mix_(h, "vl_config_t.gate_chi2 DOUBLE", 16, 8));
    TEST_ASSERT_NOT_EQUAL(base, vl_abi_mix_(h, "vl_config_t.gate_chi2 DOUBLE", 8, 4));
    TEST_ASSERT_NOT_EQUAL(base, vl_abi_mix_(h, "vl_config_t.gate_chi2 DOUBLE", 8u + (1u << 16), 8));
    /* Two members swapped: the same multiset of (name, offset, size) pairs in another order. */
    const uint32_t ab = vl_abi_mix_(vl_abi_mix_(h, "a", 0, 8), "b", 8, 8);
    const uint32_t ba = vl_abi_mix_(vl_abi_mix_(h, "b", 0, 8), "a", 8, 8);
    TEST_ASSERT_NOT_EQUAL(ab, ba);
    TEST_ASSERT_EQUAL_UINT32(vl_abi_layout(), vl_abi_layout());
}

void test_null_comes_first_and_status_has_a_text(void)
{
    const vl_config_t cfg = kitti_config();
    TEST_ASSERT_EQUAL_INT(VL_ERR_NULL, vl_init_checked(NULL, &cfg, 0, 0, 0, 0, 0));
    TEST_ASSERT_EQUAL_INT(VL_ERR_NULL, vl_init_checked(&est, NULL, 0, 0, 0, 0, 0));
    TEST_ASSERT_TRUE(untouched());
    TEST_ASSERT_TRUE(strcmp("unknown status", vl_status_str(VL_ERR_ABI_MISMATCH)) != 0);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_matching_build_initializes);
    RUN_TEST(test_other_capacity_is_refused_untouched);
    RUN_TEST(test_other_sizes_are_refused_untouched);
    RUN_TEST(test_other_layout_is_refused_untouched);
    RUN_TEST(test_layout_depends_on_names_offsets_and_sizes);
    RUN_TEST(test_null_comes_first_and_status_has_a_text);
    return UNITY_END();
}
