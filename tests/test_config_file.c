/* Tests of the INI configuration loader (platform/vl_config_file). */
#define _POSIX_C_SOURCE 200809L

#include <float.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "unity.h"
#include "vl_config_file.h"

static char g_path[64];
static char g_err[512];

void setUp(void)
{
    g_path[0] = '\0';
    g_err[0] = '\0';
}

void tearDown(void)
{
    if (g_path[0] != '\0') {
        unlink(g_path);
    }
}

/* Writes text to a fresh temporary file whose name goes to g_path. */
static const char *write_temp(const char *text)
{
    if (g_path[0] != '\0') {
        unlink(g_path);
    }
    snprintf(g_path, sizeof(g_path), "/tmp/vl_test_cfg_XXXXXX");
    int fd = mkstemp(g_path);
    TEST_ASSERT_TRUE_MESSAGE(fd >= 0, "mkstemp failed");
    FILE *f = fdopen(fd, "w");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_EQUAL_INT((int)strlen(text), (int)fwrite(text, 1, strlen(text), f));
    TEST_ASSERT_EQUAL_INT(0, fclose(f));
    return g_path;
}

/* Field by field: memcmp would also compare padding. */
static void assert_config_equal(const vl_config_t *a, const vl_config_t *b)
{
    TEST_ASSERT_EQUAL_INT(a->mode, b->mode);
    TEST_ASSERT_EQUAL_INT(a->estimate_input_offsets, b->estimate_input_offsets);
    TEST_ASSERT_EQUAL_DOUBLE(a->linear_velocity_noise, b->linear_velocity_noise);
    TEST_ASSERT_EQUAL_DOUBLE(a->angular_velocity_noise, b->angular_velocity_noise);
    TEST_ASSERT_EQUAL_DOUBLE(a->linear_offset_prior, b->linear_offset_prior);
    TEST_ASSERT_EQUAL_DOUBLE(a->angular_offset_prior, b->angular_offset_prior);
    TEST_ASSERT_EQUAL_DOUBLE(a->linear_offset_walk, b->linear_offset_walk);
    TEST_ASSERT_EQUAL_DOUBLE(a->angular_offset_walk, b->angular_offset_walk);
    TEST_ASSERT_EQUAL_DOUBLE(a->pixel_noise, b->pixel_noise);
    TEST_ASSERT_EQUAL_DOUBLE(a->min_disparity, b->min_disparity);
    TEST_ASSERT_EQUAL_DOUBLE(a->max_depth, b->max_depth);
    TEST_ASSERT_EQUAL_DOUBLE(a->gate_chi2, b->gate_chi2);
    TEST_ASSERT_EQUAL_DOUBLE(a->max_broken_fraction, b->max_broken_fraction);
    TEST_ASSERT_EQUAL_UINT32(a->ransac_hypotheses, b->ransac_hypotheses);
    TEST_ASSERT_EQUAL_DOUBLE(a->ransac_threshold, b->ransac_threshold);
    TEST_ASSERT_EQUAL_UINT32(a->min_track_length, b->min_track_length);
    TEST_ASSERT_EQUAL_UINT32(a->max_landmarks, b->max_landmarks);
    TEST_ASSERT_EQUAL_UINT32(a->max_unseen_frames, b->max_unseen_frames);
    TEST_ASSERT_EQUAL_DOUBLE(a->max_propagation_dt, b->max_propagation_dt);
    TEST_ASSERT_EQUAL_UINT32(a->max_update_observations, b->max_update_observations);
    TEST_ASSERT_EQUAL_DOUBLE(a->max_time_jump, b->max_time_jump);
    TEST_ASSERT_EQUAL_UINT32(a->new_timeline_samples, b->new_timeline_samples);
    TEST_ASSERT_EQUAL_DOUBLE(a->max_speed, b->max_speed);
    TEST_ASSERT_EQUAL_DOUBLE(a->max_rotation_rate, b->max_rotation_rate);
    TEST_ASSERT_EQUAL_DOUBLE(a->image_width, b->image_width);
    TEST_ASSERT_EQUAL_DOUBLE(a->image_height, b->image_height);
    TEST_ASSERT_EQUAL_DOUBLE(a->image_margin, b->image_margin);
    TEST_ASSERT_EQUAL_DOUBLE(a->max_disparity, b->max_disparity);
    TEST_ASSERT_EQUAL_DOUBLE(a->max_imu_silence, b->max_imu_silence);
    TEST_ASSERT_EQUAL_UINT32(a->divergence_frames, b->divergence_frames);
    TEST_ASSERT_EQUAL_DOUBLE(a->calibration.fx, b->calibration.fx);
    TEST_ASSERT_EQUAL_DOUBLE(a->calibration.fy, b->calibration.fy);
    TEST_ASSERT_EQUAL_DOUBLE(a->calibration.cx, b->calibration.cx);
    TEST_ASSERT_EQUAL_DOUBLE(a->calibration.cy, b->calibration.cy);
    TEST_ASSERT_EQUAL_DOUBLE(a->calibration.baseline, b->calibration.baseline);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(a->calibration.cam_T_imu, b->calibration.cam_T_imu, 16);
    TEST_ASSERT_EQUAL_PTR(a->landmark_sink, b->landmark_sink);
    TEST_ASSERT_EQUAL_PTR(a->landmark_sink_user, b->landmark_sink_user);
    TEST_ASSERT_EQUAL_PTR(a->log, b->log);
    TEST_ASSERT_EQUAL_PTR(a->log_user, b->log_user);
    TEST_ASSERT_EQUAL_PTR(a->parallel_for, b->parallel_for);
    TEST_ASSERT_EQUAL_PTR(a->parallel_ctx, b->parallel_ctx);
}

/* Loads text on top of the defaults and expects a failure whose message holds every needle. */
static void expect_error(const char *text, const char *needle1, const char *needle2)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_config_t before = cfg;
    vl_status_t s = vl_config_load_ini(write_temp(text), &cfg, g_err, sizeof(g_err));
    TEST_ASSERT_EQUAL_INT_MESSAGE(VL_ERR_CONFIG, s, g_err);
    TEST_ASSERT_TRUE_MESSAGE(strstr(g_err, g_path) != NULL, g_err);
    if (needle1 != NULL) {
        TEST_ASSERT_TRUE_MESSAGE(strstr(g_err, needle1) != NULL, g_err);
    }
    if (needle2 != NULL) {
        TEST_ASSERT_TRUE_MESSAGE(strstr(g_err, needle2) != NULL, g_err);
    }
    assert_config_equal(&before, &cfg); /* untouched on failure */
}

static const char *k_full = "; every key, none at its default\n"
                            "[estimator]\n"
                            "mode = mapping\n"
                            "estimate_input_offsets = false\n"
                            "max_propagation_dt = 0.25\n"
                            "max_update_observations = 20\n"
                            "\n"
                            "[noise]\n"
                            "linear_velocity = 0.7\n"
                            "angular_velocity = 0.07   ; inline comment\n"
                            "linear_offset_prior = 0.2\n"
                            "angular_offset_prior = 0.02\n"
                            "linear_offset_walk = 2e-3\n"
                            "angular_offset_walk = 2e-4\n"
                            "pixel = 2.5\n"
                            "\n"
                            "# hash comments too\n"
                            "[landmarks]\n"
                            "max_landmarks = 17\n"
                            "max_unseen_frames = 3\n"
                            "min_disparity = 0.5\n"
                            "max_depth = 80\n"
                            "min_track_length = 3\n"
                            "\n"
                            "[outliers]\n"
                            "gate_chi2 = 9.5\n"
                            "max_broken_fraction = 0.45\n"
                            "ransac_hypotheses = 12\n"
                            "ransac_threshold = 2.5\n"
                            "\n"
                            "[limits]\n"
                            "max_time_jump = 3.5\n"
                            "new_timeline_samples = 7\n"
                            "max_speed = 42\n"
                            "max_rotation_rate = 6.5\n"
                            "image_width = 1241\n"
                            "image_height = 376\n"
                            "image_margin = 8\n"
                            "max_disparity = 250\n"
                            "max_imu_silence = 0.75\n"
                            "divergence_frames = 0\n"
                            "\n"
                            "[calibration]\n"
                            "override_log = true\n"
                            "fx = 721.5\n"
                            "fy = 721.6\n"
                            "cx = 609.5\n"
                            "cy = 172.8\n"
                            "baseline = 0.537\n"
                            "cam_T_imu = 0 -1 0 0.1,\n"
                            "            0 0 -1 0.2,\n"
                            "            1 0 0 0.3,\n"
                            "            0 0 0 1\n";

void test_vl_config_load_ini_full_file_sets_every_key(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_config_file_info_t info;
    vl_status_t s = vl_config_load_ini_ex(write_temp(k_full), &cfg, &info, g_err, sizeof(g_err));
    TEST_ASSERT_EQUAL_INT_MESSAGE(VL_OK, s, g_err);
    TEST_ASSERT_EQUAL_INT(VL_MODE_MAPPING, cfg.mode);
    TEST_ASSERT_EQUAL_INT(0, cfg.estimate_input_offsets);
    TEST_ASSERT_EQUAL_DOUBLE(0.25, cfg.max_propagation_dt);
    TEST_ASSERT_EQUAL_UINT32(20, cfg.max_update_observations);
    TEST_ASSERT_EQUAL_DOUBLE(0.7, cfg.linear_velocity_noise);
    TEST_ASSERT_EQUAL_DOUBLE(0.07, cfg.angular_velocity_noise);
    TEST_ASSERT_EQUAL_DOUBLE(0.2, cfg.linear_offset_prior);
    TEST_ASSERT_EQUAL_DOUBLE(0.02, cfg.angular_offset_prior);
    TEST_ASSERT_EQUAL_DOUBLE(2e-3, cfg.linear_offset_walk);
    TEST_ASSERT_EQUAL_DOUBLE(2e-4, cfg.angular_offset_walk);
    TEST_ASSERT_EQUAL_DOUBLE(2.5, cfg.pixel_noise);
    TEST_ASSERT_EQUAL_UINT32(17, cfg.max_landmarks);
    TEST_ASSERT_EQUAL_UINT32(3, cfg.max_unseen_frames);
    TEST_ASSERT_EQUAL_DOUBLE(0.5, cfg.min_disparity);
    TEST_ASSERT_EQUAL_DOUBLE(80.0, cfg.max_depth);
    TEST_ASSERT_EQUAL_UINT32(3, cfg.min_track_length);
    TEST_ASSERT_EQUAL_DOUBLE(9.5, cfg.gate_chi2);
    TEST_ASSERT_EQUAL_DOUBLE(0.45, cfg.max_broken_fraction);
    TEST_ASSERT_EQUAL_UINT32(12, cfg.ransac_hypotheses);
    TEST_ASSERT_EQUAL_DOUBLE(2.5, cfg.ransac_threshold);
    TEST_ASSERT_EQUAL_DOUBLE(3.5, cfg.max_time_jump);
    TEST_ASSERT_EQUAL_UINT32(7, cfg.new_timeline_samples);
    TEST_ASSERT_EQUAL_DOUBLE(42.0, cfg.max_speed);
    TEST_ASSERT_EQUAL_DOUBLE(6.5, cfg.max_rotation_rate);
    TEST_ASSERT_EQUAL_DOUBLE(1241.0, cfg.image_width);
    TEST_ASSERT_EQUAL_DOUBLE(376.0, cfg.image_height);
    TEST_ASSERT_EQUAL_DOUBLE(8.0, cfg.image_margin);
    TEST_ASSERT_EQUAL_DOUBLE(250.0, cfg.max_disparity);
    TEST_ASSERT_EQUAL_DOUBLE(0.75, cfg.max_imu_silence);
    TEST_ASSERT_EQUAL_UINT32(0, cfg.divergence_frames);
    TEST_ASSERT_EQUAL_DOUBLE(721.5, cfg.calibration.fx);
    TEST_ASSERT_EQUAL_DOUBLE(721.6, cfg.calibration.fy);
    TEST_ASSERT_EQUAL_DOUBLE(609.5, cfg.calibration.cx);
    TEST_ASSERT_EQUAL_DOUBLE(172.8, cfg.calibration.cy);
    TEST_ASSERT_EQUAL_DOUBLE(0.537, cfg.calibration.baseline);
    const double T[16] = {0, -1, 0, 0.1, 0, 0, -1, 0.2, 1, 0, 0, 0.3, 0, 0, 0, 1};
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(T, cfg.calibration.cam_T_imu, 16);
    TEST_ASSERT_TRUE(info.has_calibration);
    TEST_ASSERT_TRUE(info.override_log);
    TEST_ASSERT_EQUAL_INT(VL_PRESET_NONE, info.preset);
    TEST_ASSERT_EQUAL_UINT(37, info.keys_set); /* all but preset */
}

void test_vl_config_load_ini_example_file_equals_defaults(void)
{
    char path[1024];
    if (VL_MAX_LANDMARKS != 128) {
        TEST_IGNORE_MESSAGE("tools/vislam.ini sets max_landmarks = 128, the default capacity; this build differs");
    }
    snprintf(path, sizeof(path), "%s/tools/vislam.ini", VL_SOURCE_DIR);
    vl_config_t def;
    vl_config_default(&def);
    vl_config_t cfg = def;
    vl_config_file_info_t info;
    vl_status_t s = vl_config_load_ini_ex(path, &cfg, &info, g_err, sizeof(g_err));
    TEST_ASSERT_EQUAL_INT_MESSAGE(VL_OK, s, g_err);
    TEST_ASSERT_FALSE(info.has_calibration);
    assert_config_equal(&def, &cfg);
}

void test_vl_config_load_ini_without_calibration_keeps_callers_rig(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_config_file_info_t info;
    vl_status_t s = vl_config_load_ini_ex(write_temp("[noise]\npixel = 3\n"), &cfg, &info, g_err, sizeof(g_err));
    TEST_ASSERT_EQUAL_INT_MESSAGE(VL_OK, s, g_err);
    TEST_ASSERT_EQUAL_DOUBLE(3.0, cfg.pixel_noise);
    TEST_ASSERT_FALSE(info.has_calibration);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.calibration.fx); /* still the default: the log supplies it */
}

void test_vl_config_load_ini_preset_is_applied_before_other_keys(void)
{
    vl_config_t seed;
    vl_config_preset_seed(&seed);
    vl_config_t cfg;
    vl_config_default(&cfg);
    cfg.log_user = &cfg; /* callbacks survive a preset */
    cfg.parallel_ctx = &seed;
    vl_config_file_info_t info;
    /* preset after a key: the key still wins */
    vl_status_t s = vl_config_load_ini_ex(write_temp("[noise]\npixel = 9\n[estimator]\npreset = seed\n"), &cfg, &info,
                                          g_err, sizeof(g_err));
    TEST_ASSERT_EQUAL_INT_MESSAGE(VL_OK, s, g_err);
    TEST_ASSERT_EQUAL_INT(VL_PRESET_SEED, info.preset);
    TEST_ASSERT_EQUAL_DOUBLE(9.0, cfg.pixel_noise);
    TEST_ASSERT_EQUAL_DOUBLE(seed.linear_velocity_noise, cfg.linear_velocity_noise);
    TEST_ASSERT_EQUAL_UINT32(seed.ransac_hypotheses, cfg.ransac_hypotheses);
    TEST_ASSERT_EQUAL_PTR(&cfg, cfg.log_user);
    TEST_ASSERT_EQUAL_PTR(&seed, cfg.parallel_ctx);
}

void test_vl_config_load_ini_unknown_key_names_file_line_key(void)
{
    expect_error("[noise]\npixel = 2\npixle = 2\n", ":3:", "pixle");
    TEST_ASSERT_NOT_NULL(strstr(g_err, "unknown key"));
}

void test_vl_config_load_ini_unknown_section_fails(void)
{
    expect_error("[estimator]\nmode = slam\n[filter]\nmode = slam\n", ":4:", "[filter]");
}

void test_vl_config_load_ini_key_outside_section_fails(void)
{
    expect_error("pixel = 2\n", ":1:", "pixel");
}

void test_vl_config_load_ini_bad_number_fails(void)
{
    expect_error("[noise]\npixel = 1.5px\n", ":2:", "'1.5px'");
    expect_error("[noise]\npixel =\n", ":2:", "pixel");
    expect_error("[noise]\npixel = nan\n", ":2:", "not a finite number");
    expect_error("[noise]\npixel = inf\n", ":2:", "not a finite number");
    expect_error("[noise]\npixel = 1e999\n", ":2:", "pixel");
    expect_error("[landmarks]\nmax_landmarks = 12.5\n", ":2:", "not an integer");
    expect_error("[estimator]\nestimate_input_offsets = yes\n", ":2:", "true or false");
    expect_error("[estimator]\nmode = full\n", ":2:", "mode");
    expect_error("[outliers]\nransac_hypotheses = many\n", ":2:", "ransac_hypotheses");
    expect_error("[estimator]\npreset = fancy\n", ":2:", "preset");
}

void test_vl_config_load_ini_out_of_range_fails(void)
{
    expect_error("[noise]\n\npixel = -1\n", ":3:", "out of range");
    expect_error("[noise]\nlinear_velocity = 0\n", ":2:", "linear_velocity");
    expect_error("[noise]\nlinear_offset_walk = -1e-3\n", ":2:", "linear_offset_walk");
    expect_error("[landmarks]\nmax_landmarks = 0\n", ":2:", "max_landmarks");
    char text[128];
    snprintf(text, sizeof(text), "[landmarks]\nmax_landmarks = %d\n", VL_MAX_LANDMARKS + 1);
    expect_error(text, ":2:", "out of range");
    expect_error("[landmarks]\nmax_unseen_frames = -1\n", ":2:", "max_unseen_frames");
    expect_error("[limits]\nmax_time_jump = 0\n", ":2:", "max_time_jump");
    expect_error("[limits]\nmax_time_jump = 2e9\n", ":2:", "max_time_jump");
    expect_error("[limits]\nnew_timeline_samples = 1\n", ":2:", "new_timeline_samples");
    expect_error("[limits]\nmax_speed = 0\n", ":2:", "max_speed");
    expect_error("[limits]\nimage_margin = -1\n", ":2:", "image_margin");
    expect_error("[limits]\nmax_imu_silence = 0\n", ":2:", "max_imu_silence");
    expect_error("[landmarks]\nmin_disparity = 0\n", ":2:", "min_disparity");
    expect_error("[estimator]\nmax_propagation_dt = 0\n", ":2:", "max_propagation_dt");
    expect_error("[outliers]\nmax_broken_fraction = 1.5\n", ":2:", "max_broken_fraction");
    expect_error("[landmarks]\nmin_track_length = 0\n", ":2:", "min_track_length");
}

void test_vl_config_load_ini_repeated_key_fails(void)
{
    expect_error("[noise]\npixel = 2\n[noise]\npixel = 3\n", ":4:", "first on line 2");
}

void test_vl_config_load_ini_continuation_of_scalar_fails(void)
{
    expect_error("[noise]\npixel = 2\n  3\n", ":3:", "continuation");
}

void test_vl_config_load_ini_syntax_error_names_line(void)
{
    expect_error("[noise]\npixel 2\n", ":2:", "syntax");
}

void test_vl_config_load_ini_missing_file_fails(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_status_t s = vl_config_load_ini("/tmp/vl_test_no_such_dir/none.ini", &cfg, g_err, sizeof(g_err));
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, s);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_err, "/tmp/vl_test_no_such_dir/none.ini"), g_err);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_err, "cannot open"), g_err);
}

void test_vl_config_load_ini_null_arguments_fail(void)
{
    vl_config_t cfg;
    TEST_ASSERT_EQUAL_INT(VL_ERR_NULL, vl_config_load_ini(NULL, &cfg, g_err, sizeof(g_err)));
    TEST_ASSERT_EQUAL_INT(VL_ERR_NULL, vl_config_load_ini("/tmp/x.ini", NULL, NULL, 0));
}

void test_vl_config_load_ini_incomplete_calibration_fails(void)
{
    expect_error("[calibration]\nfx = 700\nfy = 700\n", "incomplete", "cx");
}

void test_vl_config_load_ini_override_without_calibration_fails(void)
{
    expect_error("[calibration]\noverride_log = true\n", ":2:", "override_log");
}

void test_vl_config_load_ini_bad_cam_T_imu_fails(void)
{
    const char *head = "[calibration]\nfx = 700\nfy = 700\ncx = 600\ncy = 170\nbaseline = 0.5\n";
    char text[512];
    snprintf(text, sizeof(text), "%scam_T_imu = 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0\n", head);
    expect_error(text, ":7:", "15 numbers");
    snprintf(text, sizeof(text), "%scam_T_imu = 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1 0\n", head);
    expect_error(text, ":7:", "more than 16");
    snprintf(text, sizeof(text), "%scam_T_imu = 2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n", head);
    expect_error(text, ":7:", "rigid");
    snprintf(text, sizeof(text), "%scam_T_imu = 1 0 0 0 0 1 0 0 0 0 -1 0 0 0 0 1\n", head);
    expect_error(text, ":7:", "rigid");
    snprintf(text, sizeof(text), "%scam_T_imu = 1 0 0 0 0 1 0 0 0 0 1 x 0 0 0 1\n", head);
    expect_error(text, ":7:", "'x'");
}

void test_vl_config_load_ini_overlong_line_fails(void)
{
    char text[600];
    int n = snprintf(text, sizeof(text), "[noise]\npixel = 2 ;");
    memset(text + n, 'x', 300);
    snprintf(text + n + 300, sizeof(text) - (size_t)n - 300, "\n[noise]\n");
    expect_error(text, ":2:", "too long");
}

/* Writes cfg with writer into a fresh temporary file (g_path), reads it back and checks it equals. */
static void assert_round_trip(int (*writer)(FILE *, const vl_config_t *, int), const vl_config_t *cfg)
{
    if (g_path[0] != '\0') {
        unlink(g_path);
    }
    snprintf(g_path, sizeof(g_path), "/tmp/vl_test_cfg_XXXXXX");
    int fd = mkstemp(g_path);
    TEST_ASSERT_TRUE(fd >= 0);
    FILE *f = fdopen(fd, "w");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_EQUAL_INT(0, writer(f, cfg, 1));
    TEST_ASSERT_EQUAL_INT(0, fclose(f));
    vl_config_t back;
    vl_config_default(&back);
    vl_config_file_info_t info;
    TEST_ASSERT_EQUAL_INT_MESSAGE(VL_OK, vl_config_load_ini_ex(g_path, &back, &info, g_err, sizeof(g_err)), g_err);
    TEST_ASSERT_TRUE(info.has_calibration);
    assert_config_equal(cfg, &back);
}

void test_vl_config_write_ini_round_trips(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    TEST_ASSERT_EQUAL_INT_MESSAGE(VL_OK, vl_config_load_ini(write_temp(k_full), &cfg, g_err, sizeof(g_err)), g_err);
    cfg.pixel_noise = 1.0 / 3.0; /* needs more than 15 digits */
    assert_round_trip(vl_config_write_ini, &cfg);
}

void test_vl_mode_names_round_trip(void)
{
    const vl_mode_t modes[3] = {VL_MODE_IMU_ONLY, VL_MODE_MAPPING, VL_MODE_SLAM};
    for (int i = 0; i < 3; ++i) {
        vl_mode_t m;
        TEST_ASSERT_EQUAL_INT(0, vl_mode_from_name(vl_mode_name(modes[i]), &m));
        TEST_ASSERT_EQUAL_INT(modes[i], m);
    }
    vl_mode_t m;
    TEST_ASSERT_EQUAL_INT(-1, vl_mode_from_name("SLAM", &m));
    TEST_ASSERT_EQUAL_STRING("seed", vl_preset_name(VL_PRESET_SEED));
}

/* The schema's rows, for the tests below to walk. */
typedef struct {
    const char *section;
    const char *key;
    vl_config_type_t type;
    size_t offset;
    size_t size;
    double min;
    double max;
    int min_open;
} schema_row_t;

#define SCHEMA_ROW(section, key, field, type, def, min, max, min_open, units, meaning)                                \
    {section,       key,           VL_CONFIG_##type, offsetof(vl_config_t, field), sizeof(((vl_config_t *)0)->field), \
     (double)(min), (double)(max), min_open},
static const schema_row_t k_rows[] = {VL_CONFIG_KEYS(SCHEMA_ROW)};
#undef SCHEMA_ROW
#define NUM_ROWS (sizeof(k_rows) / sizeof(k_rows[0]))

/* Writes cfg with vl_config_write_ini to a fresh temporary file (g_path). */
static void write_config_temp(const vl_config_t *cfg, int with_calibration)
{
    if (g_path[0] != '\0') {
        unlink(g_path);
    }
    snprintf(g_path, sizeof(g_path), "/tmp/vl_test_cfg_XXXXXX");
    int fd = mkstemp(g_path);
    TEST_ASSERT_TRUE(fd >= 0);
    FILE *f = fdopen(fd, "w");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_EQUAL_INT(0, vl_config_write_ini(f, cfg, with_calibration));
    TEST_ASSERT_EQUAL_INT(0, fclose(f));
}

/* Reads a whole file into a malloc'ed, NUL-terminated buffer. */
static char *read_whole(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (f == NULL) {
        return NULL;
    }
    size_t cap = 4096, n = 0;
    char *buf = (char *)malloc(cap);
    size_t got;
    while (buf != NULL && (got = fread(buf + n, 1, cap - n - 1, f)) > 0) {
        n += got;
        if (cap - n - 1 == 0) {
            cap *= 2;
            buf = (char *)realloc(buf, cap);
        }
    }
    fclose(f);
    if (buf != NULL) {
        buf[n] = '\0';
    }
    *len = n;
    return buf;
}

void test_vl_config_default_equals_documented_values(void)
{
    /* The values README "Configuration" documents, written out: the table must give them. */
    vl_config_t cfg;
    vl_config_default(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_MODE_SLAM, cfg.mode);
    TEST_ASSERT_EQUAL_INT(1, cfg.estimate_input_offsets);
    TEST_ASSERT_EQUAL_INT(1, cfg.adaptive_noise);
    TEST_ASSERT_EQUAL_INT(1, cfg.interpolate_velocities);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.velocity_sensor_x);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.velocity_sensor_y);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.velocity_sensor_z);
    TEST_ASSERT_EQUAL_DOUBLE(2.0, cfg.velocity_sensor_std_x);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.velocity_sensor_std_y);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.velocity_sensor_std_z);
    TEST_ASSERT_EQUAL_DOUBLE(0.5, cfg.max_propagation_dt);
    TEST_ASSERT_EQUAL_UINT32(64, cfg.max_update_observations);
    TEST_ASSERT_EQUAL_DOUBLE(18.5, cfg.max_update_work);
    TEST_ASSERT_EQUAL_INT(1, cfg.rotate_deferred);
    TEST_ASSERT_EQUAL_INT(1, cfg.apply_deferred);
    TEST_ASSERT_EQUAL_DOUBLE(18.5, cfg.max_deferred_work);
    TEST_ASSERT_EQUAL_DOUBLE(0.5, cfg.linear_velocity_noise);
    TEST_ASSERT_EQUAL_DOUBLE(0.05, cfg.angular_velocity_noise);
    TEST_ASSERT_EQUAL_DOUBLE(0.1, cfg.linear_offset_prior);
    TEST_ASSERT_EQUAL_DOUBLE(0.01, cfg.angular_offset_prior);
    TEST_ASSERT_EQUAL_DOUBLE(1e-3, cfg.linear_offset_walk);
    TEST_ASSERT_EQUAL_DOUBLE(1e-4, cfg.angular_offset_walk);
    TEST_ASSERT_EQUAL_DOUBLE(100.0, cfg.offset_correlation_time);
    TEST_ASSERT_EQUAL_DOUBLE(1.5, cfg.pixel_noise);
    TEST_ASSERT_EQUAL_DOUBLE(0.35, cfg.repeat_anchor_noise);
    TEST_ASSERT_EQUAL_DOUBLE(0.2, cfg.repeat_track_walk);
    TEST_ASSERT_EQUAL_UINT32(VL_MAX_LANDMARKS, cfg.max_landmarks);
    TEST_ASSERT_EQUAL_UINT32(0, cfg.max_unseen_frames);
    TEST_ASSERT_EQUAL_UINT32(0, cfg.max_admissions);
    TEST_ASSERT_EQUAL_DOUBLE(1.0, cfg.min_disparity);
    TEST_ASSERT_EQUAL_DOUBLE(150.0, cfg.max_depth);
    TEST_ASSERT_EQUAL_UINT32(2, cfg.min_track_length);
    TEST_ASSERT_EQUAL_UINT32(24, cfg.first_sight_below);
    TEST_ASSERT_EQUAL_DOUBLE(11.34, cfg.gate_chi2);
    TEST_ASSERT_EQUAL_DOUBLE(0.3, cfg.max_broken_fraction);
    TEST_ASSERT_EQUAL_UINT32(32, cfg.ransac_hypotheses);
    TEST_ASSERT_EQUAL_DOUBLE(3.0, cfg.ransac_threshold);
    TEST_ASSERT_EQUAL_DOUBLE(10.0, cfg.max_time_jump);
    TEST_ASSERT_EQUAL_UINT32(5, cfg.new_timeline_samples);
    TEST_ASSERT_EQUAL_DOUBLE(100.0, cfg.max_speed);
    TEST_ASSERT_EQUAL_DOUBLE(35.0, cfg.max_rotation_rate);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.image_width);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.image_height);
    TEST_ASSERT_EQUAL_DOUBLE(64.0, cfg.image_margin);
    TEST_ASSERT_EQUAL_DOUBLE(400.0, cfg.max_disparity);
    TEST_ASSERT_EQUAL_DOUBLE(0.5, cfg.max_imu_silence);
    TEST_ASSERT_EQUAL_UINT32(20, cfg.divergence_frames);
    /* No rig until one arrives, an identity cam_T_imu, no callbacks. */
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.calibration.fx);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, cfg.calibration.baseline);
    const double I[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(I, cfg.calibration.cam_T_imu, 16);
    TEST_ASSERT_NULL(cfg.landmark_sink);
    TEST_ASSERT_NULL(cfg.log);
    /* Every member before the calibration is a row of the table: 47 rows, and they tile it. */
    TEST_ASSERT_EQUAL_UINT(47, NUM_ROWS);
    size_t end = 0;
    for (size_t i = 0; i < NUM_ROWS; ++i) {
        TEST_ASSERT_TRUE_MESSAGE(k_rows[i].offset >= end, k_rows[i].key);
        TEST_ASSERT_TRUE_MESSAGE(k_rows[i].offset - end < 8, k_rows[i].key); /* padding only */
        end = k_rows[i].offset + k_rows[i].size;
    }
    TEST_ASSERT_TRUE(offsetof(vl_config_t, calibration) - end < 8);
}

void test_vl_config_schema_sections_are_contiguous(void)
{
    /* The writer opens a section when the section changes: each must come in one run. */
    for (size_t i = 1; i < NUM_ROWS; ++i) {
        if (strcmp(k_rows[i].section, k_rows[i - 1].section) == 0) {
            continue;
        }
        for (size_t j = 0; j < i; ++j) {
            TEST_ASSERT_TRUE_MESSAGE(strcmp(k_rows[i].section, k_rows[j].section) != 0, k_rows[i].key);
        }
    }
}

/* An in-range value of a row that differs from the default and needs many digits. */
static void set_other_value(vl_config_t *cfg, const schema_row_t *r)
{
    char *member = (char *)cfg + r->offset;
    const double base = r->min == -DBL_MAX ? 0.0 : r->min;
    switch (r->type) {
    case VL_CONFIG_DOUBLE:
        *(double *)member = r->max == DBL_MAX ? base + 7.0 / 3.0 : base + (r->max - base) / 3.0;
        break;
    case VL_CONFIG_UINT32:
        *(uint32_t *)member = (uint32_t)(r->max == (double)UINT32_MAX ? base + 7.0 : base + (r->max - base) / 3.0);
        break;
    case VL_CONFIG_BOOL:
        *(int *)member = !*(int *)member;
        break;
    case VL_CONFIG_MODE:
        *(vl_mode_t *)member = (vl_mode_t)(((int)*(vl_mode_t *)member + 1) % 3);
        break;
    }
}

void test_vl_config_every_key_round_trips(void)
{
    for (size_t i = 0; i < NUM_ROWS; ++i) {
        const schema_row_t *r = &k_rows[i];
        vl_config_t def, cfg;
        vl_config_default(&def);
        cfg = def;
        set_other_value(&cfg, r);
        TEST_ASSERT_TRUE_MESSAGE(memcmp((char *)&cfg + r->offset, (char *)&def + r->offset, r->size) != 0, r->key);
        write_config_temp(&cfg, 0);

        /* The key is written under its section, by its name. */
        size_t len = 0;
        char *text = read_whole(g_path, &len);
        TEST_ASSERT_NOT_NULL(text);
        char needle[96];
        snprintf(needle, sizeof(needle), "[%s]\n", r->section);
        const char *sec = strstr(text, needle);
        TEST_ASSERT_NOT_NULL_MESSAGE(sec, r->key);
        snprintf(needle, sizeof(needle), "\n%s = ", r->key);
        const char *line = strstr(sec, needle);
        const char *next_sec = strstr(sec + 1, "\n[");
        TEST_ASSERT_TRUE_MESSAGE(line != NULL && (next_sec == NULL || line < next_sec), r->key);
        free(text);

        vl_config_t back;
        vl_config_default(&back);
        vl_config_file_info_t info;
        vl_status_t s = vl_config_load_ini_ex(g_path, &back, &info, g_err, sizeof(g_err));
        TEST_ASSERT_EQUAL_INT_MESSAGE(VL_OK, s, g_err);
        TEST_ASSERT_EQUAL_UINT(NUM_ROWS, info.keys_set);
        TEST_ASSERT_TRUE_MESSAGE(memcmp((char *)&cfg + r->offset, (char *)&back + r->offset, r->size) == 0, r->key);
        assert_config_equal(&cfg, &back);
    }
}

void test_vl_config_ranges_agree_between_check_and_reader(void)
{
    /* Just outside each row's range: vl_config_check refuses it, and so does the reader,
       naming the key. */
    for (size_t i = 0; i < NUM_ROWS; ++i) {
        const schema_row_t *r = &k_rows[i];
        if (r->type == VL_CONFIG_BOOL || r->type == VL_CONFIG_MODE) {
            continue;
        }
        for (int side = 0; side < 2; ++side) {
            double v;
            if (side == 0) {
                v = r->min_open ? r->min : (r->type == VL_CONFIG_UINT32 ? r->min - 1.0 : -1e-3 + r->min);
                if (r->type == VL_CONFIG_UINT32 && v < 0.0) {
                    continue; /* no uint32 below 0 */
                }
            } else {
                if (r->max == DBL_MAX || r->max == (double)UINT32_MAX) {
                    continue;
                }
                v = r->type == VL_CONFIG_UINT32 ? r->max + 1.0 : r->max * 2.0;
            }
            vl_config_t cfg;
            vl_config_default(&cfg);
            cfg.calibration.fx = cfg.calibration.fy = cfg.calibration.baseline = 1.0;
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_config_check(&cfg));
            if (r->type == VL_CONFIG_DOUBLE) {
                *(double *)((char *)&cfg + r->offset) = v;
            } else {
                *(uint32_t *)((char *)&cfg + r->offset) = (uint32_t)v;
            }
            TEST_ASSERT_EQUAL_INT_MESSAGE(VL_ERR_CONFIG, vl_config_check(&cfg), r->key);

            char text[160];
            snprintf(text, sizeof(text), "[%s]\n%s = %.17g\n", r->section, r->key, v);
            expect_error(text, ":2:", r->key);
            TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_err, "out of range"), g_err);
        }
    }
}

void test_vl_config_write_ini_prints_shortest_numbers(void)
{
    vl_config_t cfg;
    vl_config_preset_seed(&cfg);
    write_config_temp(&cfg, 0);
    size_t len = 0;
    char *text = read_whole(g_path, &len);
    TEST_ASSERT_NOT_NULL(text);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(text, "\nlinear_offset_prior = 0.1\n"), text); /* not 0.10000000000000001 */
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(text, "\nmin_disparity = 1e-06\n"), text);     /* not 9.99...95e-07 */
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(text, "\nangular_velocity = 0.09999999999999999\n"), text); /* 16 digits */
    free(text);
    vl_config_t back;
    vl_config_default(&back);
    TEST_ASSERT_EQUAL_INT_MESSAGE(VL_OK, vl_config_load_ini(g_path, &back, g_err, sizeof(g_err)), g_err);
    assert_config_equal(&cfg, &back);
}

void test_vl_config_write_ini_annotated_reads_back(void)
{
    vl_config_t cfg;
    vl_config_preset_seed(&cfg);
    cfg.calibration.fx = cfg.calibration.fy = 718.856;
    cfg.calibration.cx = 607.1928;
    cfg.calibration.cy = 185.2157;
    cfg.calibration.baseline = 0.5371657;
    const double T[16] = {0, -1, 0, 0.1, 0, 0, -1, 0.2, 1, 0, 0, 0.3, 0, 0, 0, 1};
    memcpy(cfg.calibration.cam_T_imu, T, sizeof(T));
    assert_round_trip(vl_config_write_ini_annotated, &cfg);
}

void test_vl_config_example_file_is_generated_from_schema(void)
{
    if (VL_MAX_LANDMARKS != 128) {
        TEST_IGNORE_MESSAGE("tools/vislam.ini is generated for the default capacity of 128 landmarks");
    }
    char path[1024];
    snprintf(path, sizeof(path), "%s/tools/vislam.ini", VL_SOURCE_DIR);
    size_t committed_len = 0;
    char *committed = read_whole(path, &committed_len);
    TEST_ASSERT_NOT_NULL_MESSAGE(committed, path);

    char *generated = NULL;
    size_t generated_len = 0;
    FILE *f = open_memstream(&generated, &generated_len);
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_EQUAL_INT(0, vl_config_write_example(f));
    TEST_ASSERT_EQUAL_INT(0, fclose(f));

    if (committed_len != generated_len || memcmp(committed, generated, generated_len) != 0) {
        /* Name the first line that differs. */
        int line = 1;
        size_t i = 0, start = 0;
        while (i < committed_len && i < generated_len && committed[i] == generated[i]) {
            if (committed[i] == '\n') {
                ++line;
                start = i + 1;
            }
            ++i;
        }
        char msg[4096];
        snprintf(msg, sizeof(msg),
                 "tools/vislam.ini is not what the schema (core/include/vislam/vl_config_schema.h) gives, "
                 "first at line %d: committed \"%.*s\", generated \"%.*s\". Regenerate it with: "
                 "%s/bin/test_config_file --write-example %s",
                 line, (int)strcspn(committed + start, "\n"), committed + start, (int)strcspn(generated + start, "\n"),
                 generated + start, VL_BINARY_DIR, path);
        free(committed);
        free(generated);
        TEST_FAIL_MESSAGE(msg);
    }
    free(committed);
    free(generated);
}

void test_vl_counters_list_names_every_counter_once(void)
{
    /* Distinct values per member, so the list must pair each name with its own member. */
    vl_counters_t c;
    memset(&c, 0, sizeof(c));
    uint64_t next = 1000;
#define SET_COUNTER(type, field, meaning) c.field = (type)(next++);
    VL_COUNTERS(SET_COUNTER)
#undef SET_COUNTER
    vl_counter_entry_t e[VL_NUM_COUNTERS];
    TEST_ASSERT_EQUAL_UINT(VL_NUM_COUNTERS, vl_counters_list(&c, e));
    TEST_ASSERT_EQUAL_UINT(36, VL_NUM_COUNTERS);
    TEST_ASSERT_EQUAL_STRING("imu_accepted", e[0].name);
    TEST_ASSERT_EQUAL_STRING("window_peak", e[VL_NUM_COUNTERS - 1].name);
    for (size_t i = 0; i < VL_NUM_COUNTERS; ++i) {
        TEST_ASSERT_EQUAL_UINT64(1000 + i, e[i].value);
        TEST_ASSERT_NOT_NULL(e[i].meaning);
        TEST_ASSERT_TRUE_MESSAGE(strlen(e[i].meaning) > 0, e[i].name);
        for (size_t j = 0; j < i; ++j) {
            TEST_ASSERT_TRUE_MESSAGE(strcmp(e[i].name, e[j].name) != 0, e[i].name);
        }
    }
}

/* With "--write-example FILE" this program writes tools/vislam.ini instead of testing. */
static int write_example(const char *path)
{
    FILE *f = fopen(path, "w");
    if (f == NULL) {
        fprintf(stderr, "test_config_file: cannot write %s\n", path);
        return 1;
    }
    int rc = vl_config_write_example(f);
    if (fclose(f) != 0) {
        rc = -1;
    }
    if (rc != 0) {
        fprintf(stderr, "test_config_file: write error on %s\n", path);
        return 1;
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 3 && strcmp(argv[1], "--write-example") == 0) {
        return write_example(argv[2]);
    }
    UNITY_BEGIN();
    RUN_TEST(test_vl_config_load_ini_full_file_sets_every_key);
    RUN_TEST(test_vl_config_load_ini_example_file_equals_defaults);
    RUN_TEST(test_vl_config_load_ini_without_calibration_keeps_callers_rig);
    RUN_TEST(test_vl_config_load_ini_preset_is_applied_before_other_keys);
    RUN_TEST(test_vl_config_load_ini_unknown_key_names_file_line_key);
    RUN_TEST(test_vl_config_load_ini_unknown_section_fails);
    RUN_TEST(test_vl_config_load_ini_key_outside_section_fails);
    RUN_TEST(test_vl_config_load_ini_bad_number_fails);
    RUN_TEST(test_vl_config_load_ini_out_of_range_fails);
    RUN_TEST(test_vl_config_load_ini_repeated_key_fails);
    RUN_TEST(test_vl_config_load_ini_continuation_of_scalar_fails);
    RUN_TEST(test_vl_config_load_ini_syntax_error_names_line);
    RUN_TEST(test_vl_config_load_ini_missing_file_fails);
    RUN_TEST(test_vl_config_load_ini_null_arguments_fail);
    RUN_TEST(test_vl_config_load_ini_incomplete_calibration_fails);
    RUN_TEST(test_vl_config_load_ini_override_without_calibration_fails);
    RUN_TEST(test_vl_config_load_ini_bad_cam_T_imu_fails);
    RUN_TEST(test_vl_config_load_ini_overlong_line_fails);
    RUN_TEST(test_vl_config_write_ini_round_trips);
    RUN_TEST(test_vl_mode_names_round_trip);
    RUN_TEST(test_vl_config_default_equals_documented_values);
    RUN_TEST(test_vl_config_schema_sections_are_contiguous);
    RUN_TEST(test_vl_config_every_key_round_trips);
    RUN_TEST(test_vl_config_ranges_agree_between_check_and_reader);
    RUN_TEST(test_vl_config_write_ini_prints_shortest_numbers);
    RUN_TEST(test_vl_config_write_ini_annotated_reads_back);
    RUN_TEST(test_vl_config_example_file_is_generated_from_schema);
    RUN_TEST(test_vl_counters_list_names_every_counter_once);
    return UNITY_END();
}
