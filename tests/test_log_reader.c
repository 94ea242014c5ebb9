/* Tests of the LCM log reader and the message conversions (platform/vl_log_reader, vl_msg). */
#define _POSIX_C_SOURCE 200809L

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <lcm/eventlog.h>

#include "unity.h"
#include "vl_log_reader.h"
#include "vl_msg.h"
#include "vl_trajectory_file.h"

#define VL_TEST_PI 3.14159265358979323846

static char g_path[64];
static vl_log_reader_t g_reader;
static vl_log_event_t g_ev;
static lcm_eventlog_t *g_log;
static int64_t g_stamp;

void setUp(void)
{
    snprintf(g_path, sizeof(g_path), "/tmp/vl_test_log_XXXXXX");
    int fd = mkstemp(g_path);
    TEST_ASSERT_TRUE_MESSAGE(fd >= 0, "mkstemp failed");
    close(fd);
    g_log = lcm_eventlog_create(g_path, "w");
    TEST_ASSERT_NOT_NULL(g_log);
    g_stamp = 1000;
    memset(&g_reader, 0, sizeof(g_reader));
}

void tearDown(void)
{
    if (g_log != NULL) {
        lcm_eventlog_destroy(g_log);
        g_log = NULL;
    }
    vl_log_reader_close(&g_reader);
    unlink(g_path);
}

static void write_raw(const char *channel, const void *data, int len)
{
    lcm_eventlog_event_t le;
    memset(&le, 0, sizeof(le));
    le.timestamp = g_stamp++;
    le.channellen = (int32_t)strlen(channel);
    le.datalen = len;
    le.channel = (char *)channel;
    le.data = (void *)data;
    TEST_ASSERT_EQUAL_INT(0, lcm_eventlog_write_event(g_log, &le));
}

static unsigned char g_buf[16384];

static void write_imu(const char *channel, const vislam_imu_t *m)
{
    int n = vislam_imu_t_encode(g_buf, 0, (int)sizeof(g_buf), m);
    TEST_ASSERT_TRUE(n > 0);
    write_raw(channel, g_buf, n);
}

static void write_frame(const char *channel, const vislam_stereo_frame_t *m)
{
    int n = vislam_stereo_frame_t_encode(g_buf, 0, (int)sizeof(g_buf), m);
    TEST_ASSERT_TRUE(n > 0);
    write_raw(channel, g_buf, n);
}

static void write_calibration(const char *channel, const vislam_calibration_t *m)
{
    int n = vislam_calibration_t_encode(g_buf, 0, (int)sizeof(g_buf), m);
    TEST_ASSERT_TRUE(n > 0);
    write_raw(channel, g_buf, n);
}

static void close_writer(void)
{
    lcm_eventlog_destroy(g_log);
    g_log = NULL;
}

static void open_reader(const vl_log_channels_t *channels)
{
    char err[256];
    TEST_ASSERT_EQUAL_INT_MESSAGE(0, vl_log_reader_open(&g_reader, g_path, channels, err, sizeof(err)), err);
}

static vislam_imu_t make_imu(int64_t utime)
{
    vislam_imu_t m;
    memset(&m, 0, sizeof(m));
    m.utime = utime;
    for (int i = 0; i < 3; ++i) {
        m.linear_velocity[i] = 0.25 * (double)(i + 1) + (double)utime * 1e-9;
        m.angular_velocity[i] = -0.01 * (double)(i + 1);
    }
    return m;
}

static vislam_stereo_frame_t g_frame_msg;

static void make_frame(int64_t utime, int32_t n)
{
    memset(&g_frame_msg, 0, sizeof(g_frame_msg));
    g_frame_msg.utime = utime;
    g_frame_msg.num_features = n;
    for (int i = 0; i < VISLAM_STEREO_FRAME_T_MAX_FEATURES; ++i) {
        g_frame_msg.id[i] = 1000 + i;
        g_frame_msg.u_left[i] = 100.0 + i + 0.125;
        g_frame_msg.v_left[i] = 50.0 + i + 0.25;
        g_frame_msg.u_right[i] = 90.0 + i + 0.375;
        g_frame_msg.v_right[i] = 50.0 + i + 0.5;
    }
}

static vislam_calibration_t make_calibration(void)
{
    vislam_calibration_t c;
    memset(&c, 0, sizeof(c));
    c.utime = 77;
    c.fx = 700.5;
    c.fy = 701.25;
    c.cx = 600.125;
    c.cy = 180.0625;
    c.baseline = 0.5;
    const double T[16] = {0, -1, 0, 0.1, 0, 0, -1, 0.2, 1, 0, 0, 0.3, 0, 0, 0, 1};
    memcpy(c.cam_T_imu, T, sizeof(T));
    return c;
}

static void assert_imu_equal(const vislam_imu_t *m, const vl_imu_sample_t *s)
{
    TEST_ASSERT_EQUAL_INT64(m->utime, s->utime);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(m->linear_velocity, s->linear_velocity, 3);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(m->angular_velocity, s->angular_velocity, 3);
}

static void assert_frame_equal(const vislam_stereo_frame_t *m, const vl_stereo_frame_t *f)
{
    TEST_ASSERT_EQUAL_INT64(m->utime, f->utime);
    TEST_ASSERT_EQUAL_UINT32((uint32_t)m->num_features, f->count);
    for (int i = 0; i < m->num_features && i < VL_MAX_FRAME_FEATURES; ++i) {
        TEST_ASSERT_EQUAL_INT32(m->id[i], f->obs[i].id);
        TEST_ASSERT_EQUAL_DOUBLE(m->u_left[i], f->obs[i].u_left);
        TEST_ASSERT_EQUAL_DOUBLE(m->v_left[i], f->obs[i].v_left);
        TEST_ASSERT_EQUAL_DOUBLE(m->u_right[i], f->obs[i].u_right);
        TEST_ASSERT_EQUAL_DOUBLE(m->v_right[i], f->obs[i].v_right);
    }
}

void test_vl_log_reader_next_round_trips_every_field(void)
{
    vislam_calibration_t cal = make_calibration();
    vislam_imu_t imu1 = make_imu(2000);
    vislam_imu_t imu2 = make_imu(102000);
    write_calibration(VL_CHANNEL_CALIBRATION, &cal);
    write_imu(VL_CHANNEL_IMU, &imu1);
    make_frame(52000, 137);
    write_frame(VL_CHANNEL_FEATURES, &g_frame_msg);
    write_imu(VL_CHANNEL_IMU, &imu2);
    close_writer();

    open_reader(NULL);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_CALIBRATION, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_INT64(77, g_ev.calibration_utime);
    TEST_ASSERT_EQUAL_STRING(VL_CHANNEL_CALIBRATION, g_ev.channel);
    TEST_ASSERT_EQUAL_INT64(1000, g_ev.log_utime);
    TEST_ASSERT_EQUAL_DOUBLE(cal.fx, g_ev.calibration.fx);
    TEST_ASSERT_EQUAL_DOUBLE(cal.fy, g_ev.calibration.fy);
    TEST_ASSERT_EQUAL_DOUBLE(cal.cx, g_ev.calibration.cx);
    TEST_ASSERT_EQUAL_DOUBLE(cal.cy, g_ev.calibration.cy);
    TEST_ASSERT_EQUAL_DOUBLE(cal.baseline, g_ev.calibration.baseline);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(cal.cam_T_imu, g_ev.calibration.cam_T_imu, 16);

    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_IMU, vl_log_reader_next(&g_reader, &g_ev));
    assert_imu_equal(&imu1, &g_ev.imu);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_FRAME, vl_log_reader_next(&g_reader, &g_ev));
    assert_frame_equal(&g_frame_msg, &g_ev.frame);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_IMU, vl_log_reader_next(&g_reader, &g_ev));
    assert_imu_equal(&imu2, &g_ev.imu);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&g_reader, &g_ev));

    const vl_log_reader_stats_t *st = vl_log_reader_stats(&g_reader);
    TEST_ASSERT_EQUAL_UINT64(4, st->events);
    TEST_ASSERT_EQUAL_UINT64(2, st->imu);
    TEST_ASSERT_EQUAL_UINT64(1, st->frames);
    TEST_ASSERT_EQUAL_UINT64(1, st->calibrations);
    TEST_ASSERT_EQUAL_UINT64(0, st->decode_errors);
    TEST_ASSERT_EQUAL_UINT64(0, st->skipped);
    TEST_ASSERT_FALSE(vl_log_reader_truncated(&g_reader));
}

void test_vl_log_reader_next_full_and_empty_frames(void)
{
    make_frame(1, VISLAM_STEREO_FRAME_T_MAX_FEATURES);
    write_frame(VL_CHANNEL_FEATURES, &g_frame_msg);
    make_frame(2, 0);
    write_frame(VL_CHANNEL_FEATURES, &g_frame_msg);
    close_writer();
    open_reader(NULL);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_FRAME, vl_log_reader_next(&g_reader, &g_ev));
    make_frame(1, VISLAM_STEREO_FRAME_T_MAX_FEATURES);
    assert_frame_equal(&g_frame_msg, &g_ev.frame);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_FRAME, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_UINT32(0, g_ev.frame.count);
    TEST_ASSERT_EQUAL_INT64(2, g_ev.frame.utime);
}

void test_vl_log_reader_next_corrupt_payloads_are_counted_and_skipped(void)
{
    vislam_imu_t imu = make_imu(5000);
    int n = vislam_imu_t_encode(g_buf, 0, (int)sizeof(g_buf), &imu);
    write_raw(VL_CHANNEL_IMU, g_buf, n - 5); /* cut payload */
    g_buf[0] ^= 0xff;                        /* wrong fingerprint */
    write_raw(VL_CHANNEL_IMU, g_buf, n);
    g_buf[0] ^= 0xff;
    unsigned char longer[512];
    memcpy(longer, g_buf, (size_t)n);
    memset(longer + n, 0, 8);
    write_raw(VL_CHANNEL_IMU, longer, n + 8); /* trailing bytes */
    make_frame(6000, 257);                    /* count too large */
    write_frame(VL_CHANNEL_FEATURES, &g_frame_msg);
    make_frame(6000, -1); /* negative count */
    write_frame(VL_CHANNEL_FEATURES, &g_frame_msg);
    write_imu(VL_CHANNEL_FEATURES, &imu);     /* wrong type on the channel */
    write_raw(VL_CHANNEL_CALIBRATION, "", 0); /* empty payload */
    write_imu(VL_CHANNEL_IMU, &imu);          /* and a good one: reading went on */
    close_writer();

    open_reader(NULL);
    for (int i = 0; i < 7; ++i) {
        TEST_ASSERT_EQUAL_INT_MESSAGE(VL_LOG_EVENT_DECODE_ERROR, vl_log_reader_next(&g_reader, &g_ev), g_ev.channel);
        TEST_ASSERT_TRUE(strlen(g_ev.error) > 0);
    }
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_ev.error, VL_CHANNEL_CALIBRATION), g_ev.error);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_IMU, vl_log_reader_next(&g_reader, &g_ev));
    assert_imu_equal(&imu, &g_ev.imu);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&g_reader, &g_ev));
    const vl_log_reader_stats_t *st = vl_log_reader_stats(&g_reader);
    TEST_ASSERT_EQUAL_UINT64(8, st->events);
    TEST_ASSERT_EQUAL_UINT64(7, st->decode_errors);
    TEST_ASSERT_EQUAL_UINT64(1, st->imu);
    TEST_ASSERT_EQUAL_UINT64(0, st->frames);
}

void test_vl_log_reader_next_bad_count_message_names_the_count(void)
{
    make_frame(6000, 300);
    write_frame(VL_CHANNEL_FEATURES, &g_frame_msg);
    close_writer();
    open_reader(NULL);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_DECODE_ERROR, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_ev.error, "num_features 300"), g_ev.error);
}

void test_vl_log_reader_next_skips_unknown_channels(void)
{
    vislam_imu_t imu = make_imu(1);
    write_imu("OTHER_IMU", &imu);
    write_raw("POSE", "xyz", 3);
    write_imu(VL_CHANNEL_IMU, &imu);
    write_raw("STATUS", "abc", 3);
    close_writer();
    open_reader(NULL);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_IMU, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&g_reader, &g_ev));
    const vl_log_reader_stats_t *st = vl_log_reader_stats(&g_reader);
    TEST_ASSERT_EQUAL_UINT64(4, st->events);
    TEST_ASSERT_EQUAL_UINT64(3, st->skipped);
    TEST_ASSERT_EQUAL_UINT64(0, st->decode_errors);
}

void test_vl_log_reader_open_custom_channels(void)
{
    vislam_imu_t imu = make_imu(1);
    write_imu(VL_CHANNEL_IMU, &imu);
    write_imu("ROBOT_IMU", &imu);
    close_writer();
    vl_log_channels_t ch;
    vl_log_channels_default(&ch);
    ch.imu = "ROBOT_IMU";
    open_reader(&ch);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_IMU, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_STRING("ROBOT_IMU", g_ev.channel);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_UINT64(1, vl_log_reader_stats(&g_reader)->skipped);
}

void test_vl_log_reader_next_cut_log_reports_truncation(void)
{
    vislam_imu_t imu = make_imu(1);
    write_imu(VL_CHANNEL_IMU, &imu);
    imu.utime = 2;
    write_imu(VL_CHANNEL_IMU, &imu);
    close_writer();
    FILE *f = fopen(g_path, "rb");
    TEST_ASSERT_NOT_NULL(f);
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fclose(f);
    TEST_ASSERT_EQUAL_INT(0, truncate(g_path, size - 10));

    open_reader(NULL);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_IMU, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_INT64(1, g_ev.imu.utime);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_CORRUPT, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_TRUE(vl_log_reader_truncated(&g_reader));
}

/* ---- damaged logs: every header is checked before liblcm reads the event ---- */

/* Byte offset of event @p k (0-based) in a log of @p n IMU events at utimes 1..n, and the log's size. */
static long g_offsets[16];
static long g_size;

static void write_imu_log(int n)
{
    TEST_ASSERT_TRUE(n <= 16);
    for (int k = 0; k < n; ++k) {
        vislam_imu_t imu = make_imu(k + 1);
        g_offsets[k] = ftell(g_log->f);
        write_imu(VL_CHANNEL_IMU, &imu);
    }
    close_writer();
    FILE *f = fopen(g_path, "rb");
    TEST_ASSERT_NOT_NULL(f);
    fseek(f, 0, SEEK_END);
    g_size = ftell(f);
    fclose(f);
}

static void patch(long offset, const void *bytes, size_t n)
{
    FILE *f = fopen(g_path, "r+b");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_EQUAL_INT(0, fseek(f, offset, SEEK_SET));
    TEST_ASSERT_TRUE(fwrite(bytes, 1, n, f) == n);
    fclose(f);
}

static void write_file(const void *bytes, size_t n)
{
    if (g_log != NULL) {
        close_writer();
    }
    FILE *f = fopen(g_path, "wb");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_TRUE(fwrite(bytes, 1, n, f) == n);
    fclose(f);
}

static char g_last_error[256];

/* Reads to the end; returns the IMU utimes seen (as a decimal-digit string) and counts the rest. */
static void read_all(char *utimes, size_t len, int *corrupt_events)
{
    size_t used = 0;
    utimes[0] = '\0';
    *corrupt_events = 0;
    for (int guard = 0; guard < 100; ++guard) {
        vl_log_event_kind_t k = vl_log_reader_next(&g_reader, &g_ev);
        if (k == VL_LOG_EVENT_END) {
            return;
        }
        if (k == VL_LOG_EVENT_CORRUPT) {
            (*corrupt_events)++;
            TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_ev.error, "offset "), g_ev.error);
            snprintf(g_last_error, sizeof(g_last_error), "%s", g_ev.error);
        } else if (k == VL_LOG_EVENT_IMU && used + 2 < len) {
            utimes[used++] = (char)('0' + g_ev.imu.utime % 10);
            utimes[used] = '\0';
        }
    }
    TEST_FAIL_MESSAGE("the reader never ended");
}

void test_vl_log_reader_next_length_0x7fffffff_is_reported_not_read(void)
{
    write_imu_log(5);
    const unsigned char huge[4] = {0x7f, 0xff, 0xff, 0xff};
    patch(g_offsets[2] + 24, huge, 4); /* data length of event 3 */
    open_reader(NULL);
    char seen[32];
    int corrupt = 0;
    /* The first damaged spot also says where and what. */
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_IMU, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_IMU, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_CORRUPT, vl_log_reader_next(&g_reader, &g_ev));
    char where[32];
    snprintf(where, sizeof(where), "offset %ld:", g_offsets[2]);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_ev.error, where), g_ev.error);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_ev.error, "data length"), g_ev.error);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_ev.error, "2147483647"), g_ev.error);
    read_all(seen, sizeof(seen), &corrupt);
    TEST_ASSERT_EQUAL_STRING("45", seen); /* resynchronized on event 4 */
    TEST_ASSERT_EQUAL_INT(0, corrupt);
    const vl_log_reader_stats_t *st = vl_log_reader_stats(&g_reader);
    TEST_ASSERT_EQUAL_UINT64(1, st->corrupt);
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(g_offsets[3] - g_offsets[2]), st->bytes_skipped);
    TEST_ASSERT_EQUAL_UINT64(4, st->imu);
    TEST_ASSERT_FALSE(vl_log_reader_truncated(&g_reader));
}

void test_vl_log_reader_next_negative_and_huge_channel_lengths(void)
{
    write_imu_log(4);
    const unsigned char neg[4] = {0xff, 0xff, 0xff, 0xf0};
    const unsigned char big[4] = {0x00, 0x00, 0x10, 0x00};
    patch(g_offsets[1] + 20, big, 4);
    patch(g_offsets[2] + 24, neg, 4);
    open_reader(NULL);
    char seen[32];
    int corrupt = 0;
    read_all(seen, sizeof(seen), &corrupt);
    /* Two damaged events in a row are one damaged spot. */
    TEST_ASSERT_EQUAL_STRING("14", seen);
    TEST_ASSERT_EQUAL_INT(1, corrupt);
    TEST_ASSERT_EQUAL_UINT64(1, vl_log_reader_stats(&g_reader)->corrupt);
}

void test_vl_log_reader_next_bad_sync_resynchronizes(void)
{
    write_imu_log(4);
    const unsigned char bad[1] = {0x00};
    patch(g_offsets[2], bad, 1);
    open_reader(NULL);
    char seen[32];
    int corrupt = 0;
    read_all(seen, sizeof(seen), &corrupt);
    /* Event 2 is dropped too (no sync word follows it, so its length cannot be trusted): one spot. */
    TEST_ASSERT_EQUAL_STRING("14", seen);
    TEST_ASSERT_EQUAL_INT(1, corrupt);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_last_error, "no sync word after the event"), g_last_error);
    TEST_ASSERT_FALSE(vl_log_reader_truncated(&g_reader));
}

void test_vl_log_reader_next_damaged_length_does_not_misframe(void)
{
    write_imu_log(3);
    /* A plausible but wrong data length: one byte short. */
    FILE *f = fopen(g_path, "rb");
    unsigned char len[4];
    fseek(f, g_offsets[1] + 24, SEEK_SET);
    TEST_ASSERT_TRUE(fread(len, 1, 4, f) == 4);
    fclose(f);
    len[3]--;
    patch(g_offsets[1] + 24, len, 4);
    open_reader(NULL);
    char seen[32];
    int corrupt = 0;
    read_all(seen, sizeof(seen), &corrupt);
    TEST_ASSERT_EQUAL_STRING("13", seen);
    TEST_ASSERT_EQUAL_INT(1, corrupt);
    TEST_ASSERT_EQUAL_UINT64(0, vl_log_reader_stats(&g_reader)->decode_errors);
}

void test_vl_log_reader_next_cut_header(void)
{
    write_imu_log(3);
    TEST_ASSERT_EQUAL_INT(0, truncate(g_path, g_offsets[2] + 10));
    open_reader(NULL);
    char seen[32];
    int corrupt = 0;
    read_all(seen, sizeof(seen), &corrupt);
    TEST_ASSERT_EQUAL_STRING("12", seen);
    TEST_ASSERT_EQUAL_INT(1, corrupt);
    TEST_ASSERT_TRUE(vl_log_reader_truncated(&g_reader));
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_last_error, "header"), g_last_error);
    TEST_ASSERT_EQUAL_UINT64(10, vl_log_reader_stats(&g_reader)->bytes_skipped);
}

void test_vl_log_reader_next_cut_payload(void)
{
    write_imu_log(3);
    TEST_ASSERT_EQUAL_INT(0, truncate(g_path, g_size - 1));
    open_reader(NULL);
    char seen[32];
    int corrupt = 0;
    read_all(seen, sizeof(seen), &corrupt);
    TEST_ASSERT_EQUAL_STRING("12", seen);
    TEST_ASSERT_EQUAL_INT(1, corrupt);
    TEST_ASSERT_TRUE(vl_log_reader_truncated(&g_reader));
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_last_error, "longer than what is left"), g_last_error);
}

void test_vl_log_reader_next_empty_file(void)
{
    close_writer();
    open_reader(NULL);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&g_reader, &g_ev));
    const vl_log_reader_stats_t *st = vl_log_reader_stats(&g_reader);
    TEST_ASSERT_EQUAL_UINT64(0, st->events);
    TEST_ASSERT_EQUAL_UINT64(0, st->corrupt);
    TEST_ASSERT_FALSE(vl_log_reader_truncated(&g_reader));
}

void test_vl_log_reader_next_garbage_file(void)
{
    static unsigned char junk[100000];
    uint32_t x = 12345u;
    for (size_t i = 0; i < sizeof(junk); ++i) {
        x = x * 1103515245u + 12345u;
        junk[i] = (unsigned char)(x >> 24);
    }
    /* Sync words inside the junk, whose headers are junk too: none may be taken for an event. */
    const unsigned char sync[4] = {0xED, 0xA1, 0xDA, 0x01};
    for (size_t i = 0; i + 4 < sizeof(junk); i += 997) {
        memcpy(junk + i, sync, 4);
    }
    write_file(junk, sizeof(junk));
    open_reader(NULL);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_CORRUPT, vl_log_reader_next(&g_reader, &g_ev));
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(g_ev.error, "offset 0:"), g_ev.error);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&g_reader, &g_ev));
    const vl_log_reader_stats_t *st = vl_log_reader_stats(&g_reader);
    TEST_ASSERT_EQUAL_UINT64(0, st->events);
    TEST_ASSERT_EQUAL_UINT64(1, st->corrupt);
    TEST_ASSERT_EQUAL_UINT64(sizeof(junk), st->bytes_skipped);
}

void test_vl_log_reader_next_junk_between_events(void)
{
    write_imu_log(2);
    /* Rebuild: event 1, 333 junk bytes, event 2. */
    static unsigned char file[4096];
    FILE *f = fopen(g_path, "rb");
    const size_t n = fread(file, 1, sizeof(file), f);
    fclose(f);
    static unsigned char out[4096];
    const size_t first = (size_t)g_offsets[1];
    memcpy(out, file, first);
    memset(out + first, 0xA5, 333);
    memcpy(out + first + 333, file + first, n - first);
    write_file(out, n + 333);
    open_reader(NULL);
    char seen[32];
    int corrupt = 0;
    read_all(seen, sizeof(seen), &corrupt);
    /* Event 1 has no sync word after it: dropped with the junk. */
    TEST_ASSERT_EQUAL_STRING("2", seen);
    TEST_ASSERT_EQUAL_INT(1, corrupt);
    TEST_ASSERT_EQUAL_UINT64(first + 333, vl_log_reader_stats(&g_reader)->bytes_skipped);
}

void test_vl_log_check_event_reports_each_problem(void)
{
    write_imu_log(1);
    FILE *f = fopen(g_path, "rb");
    TEST_ASSERT_NOT_NULL(f);
    vl_log_header_t h;
    TEST_ASSERT_EQUAL_INT(VL_LOG_CHECK_OK, vl_log_check_event(f, 0, g_size, &h));
    TEST_ASSERT_EQUAL_INT64(1000, h.timestamp);
    TEST_ASSERT_EQUAL_INT32((int32_t)strlen(VL_CHANNEL_IMU), h.channel_bytes);
    TEST_ASSERT_EQUAL_INT(VL_LOG_CHECK_END, vl_log_check_event(f, g_size, g_size, &h));
    TEST_ASSERT_EQUAL_INT(VL_LOG_CHECK_CUT_HEADER, vl_log_check_event(f, 0, 20, &h));
    TEST_ASSERT_EQUAL_INT(VL_LOG_CHECK_CUT_EVENT, vl_log_check_event(f, 0, g_size - 1, &h));
    TEST_ASSERT_EQUAL_INT(VL_LOG_CHECK_BAD_SYNC, vl_log_check_event(f, 1, g_size, &h));
    fclose(f);
}

void test_vl_log_reader_open_missing_file_fails(void)
{
    char err[256];
    vl_log_reader_t r;
    TEST_ASSERT_EQUAL_INT(-1, vl_log_reader_open(&r, "/tmp/vl_test_no_such_dir/x.lcmlog", NULL, err, sizeof(err)));
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(err, "/tmp/vl_test_no_such_dir/x.lcmlog"), err);
    vl_log_reader_close(&r);
    TEST_ASSERT_EQUAL_INT(VL_LOG_EVENT_END, vl_log_reader_next(&r, &g_ev));
}

void test_vl_msg_to_stereo_frame_clamps_bad_counts(void)
{
    static vl_stereo_frame_t f;
    make_frame(1, -5);
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_COUNT, vl_msg_to_stereo_frame(&g_frame_msg, &f));
    TEST_ASSERT_EQUAL_UINT32(0, f.count);
    make_frame(1, 1000);
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_COUNT, vl_msg_to_stereo_frame(&g_frame_msg, &f));
    TEST_ASSERT_EQUAL_UINT32(VISLAM_STEREO_FRAME_T_MAX_FEATURES, f.count);
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_NULL, vl_msg_to_stereo_frame(NULL, &f));
}

void test_vl_msg_frame_round_trip(void)
{
    static vl_stereo_frame_t f;
    static vislam_stereo_frame_t back;
    make_frame(42, 10);
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_to_stereo_frame(&g_frame_msg, &f));
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_from_stereo_frame(&f, &back));
    TEST_ASSERT_EQUAL_INT32(10, back.num_features);
    TEST_ASSERT_EQUAL_INT_ARRAY(g_frame_msg.id, back.id, 10);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(g_frame_msg.v_right, back.v_right, 10);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, back.u_left[10]); /* unused tail zeroed */
}

void test_vl_msg_calibration_round_trip(void)
{
    vislam_calibration_t m = make_calibration();
    vl_calibration_t c;
    int64_t utime = 0;
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_to_calibration(&m, &c, &utime));
    vislam_calibration_t back;
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_from_calibration(&c, utime, &back));
    TEST_ASSERT_EQUAL_INT64(m.utime, back.utime);
    TEST_ASSERT_EQUAL_DOUBLE(m.fx, back.fx);
    TEST_ASSERT_EQUAL_DOUBLE(m.cy, back.cy);
    TEST_ASSERT_EQUAL_DOUBLE(m.baseline, back.baseline);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(m.cam_T_imu, back.cam_T_imu, 16);
}

void test_vl_msg_landmark_batch_round_trip_and_capacity(void)
{
    static vislam_landmarks_t batch;
    memset(&batch, 0, sizeof(batch));
    vl_landmark_t lm, back;
    memset(&lm, 0, sizeof(lm));
    lm.id = 41;
    lm.position[0] = 1.5;
    lm.position[1] = -2.25;
    lm.position[2] = 30.0;
    const double cov[9] = {4.0, 0.5, -0.25, 0.5, 9.0, 0.125, -0.25, 0.125, 16.0}; /* symmetric */
    memcpy(lm.covariance, cov, sizeof(cov));
    lm.observations = 7;
    lm.first_utime = 1317384000000000;
    lm.last_utime = 1317384000600000;
    for (int32_t i = 0; i < VISLAM_LANDMARKS_T_MAX_LANDMARKS; ++i) {
        lm.id = 41 + i;
        TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_add_landmark(&lm, &batch));
    }
    TEST_ASSERT_EQUAL_INT32(VISLAM_LANDMARKS_T_MAX_LANDMARKS, batch.count);
    /* Full: refused, nothing written. */
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_COUNT, vl_msg_add_landmark(&lm, &batch));
    TEST_ASSERT_EQUAL_INT32(VISLAM_LANDMARKS_T_MAX_LANDMARKS, batch.count);
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_to_landmark(&batch, 3, &back));
    TEST_ASSERT_EQUAL_INT32(44, back.id);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(lm.position, back.position, 3);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(cov, back.covariance, 9);
    TEST_ASSERT_EQUAL_UINT32(7, back.observations);
    TEST_ASSERT_EQUAL_INT64(lm.first_utime, back.first_utime);
    TEST_ASSERT_EQUAL_INT64(lm.last_utime, back.last_utime);
    batch.world = 2;
    /* Through the wire: encode, decode, the same entry. */
    static uint8_t buf[8192];
    static vislam_landmarks_t decoded;
    const int len = vislam_landmarks_t_encode(buf, 0, (int)sizeof(buf), &batch);
    TEST_ASSERT_TRUE(len > 0);
    TEST_ASSERT_TRUE(vl_msg_decoded_whole(vislam_landmarks_t_decode(buf, 0, len, &decoded), len));
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_to_landmark(&decoded, VISLAM_LANDMARKS_T_MAX_LANDMARKS - 1, &back));
    TEST_ASSERT_EQUAL_INT32(41 + VISLAM_LANDMARKS_T_MAX_LANDMARKS - 1, back.id);
    TEST_ASSERT_EQUAL_INT64(2, decoded.world);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(cov, back.covariance, 9);
    /* Entries outside the batch, and a corrupt count, are refused. */
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_COUNT, vl_msg_to_landmark(&batch, -1, &back));
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_COUNT, vl_msg_to_landmark(&batch, VISLAM_LANDMARKS_T_MAX_LANDMARKS, &back));
    decoded.count = VISLAM_LANDMARKS_T_MAX_LANDMARKS + 1;
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_COUNT, vl_msg_to_landmark(&decoded, 0, &back));
    decoded.count = -1;
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_COUNT, vl_msg_add_landmark(&lm, &decoded));
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_NULL, vl_msg_add_landmark(NULL, &batch));
    TEST_ASSERT_EQUAL_INT(VL_MSG_ERR_NULL, vl_msg_to_landmark(&batch, 0, NULL));
}

/* Rotation about a unit axis by angle, row-major. */
static void axis_angle(const double a[3], double th, double R[9])
{
    double c = cos(th), s = sin(th), v = 1.0 - c;
    R[0] = c + a[0] * a[0] * v;
    R[1] = a[0] * a[1] * v - a[2] * s;
    R[2] = a[0] * a[2] * v + a[1] * s;
    R[3] = a[1] * a[0] * v + a[2] * s;
    R[4] = c + a[1] * a[1] * v;
    R[5] = a[1] * a[2] * v - a[0] * s;
    R[6] = a[2] * a[0] * v - a[1] * s;
    R[7] = a[2] * a[1] * v + a[0] * s;
    R[8] = c + a[2] * a[2] * v;
}

void test_vl_rotation_to_quaternion_matches_axis_angle(void)
{
    const double n = 1.0 / sqrt(14.0);
    const double axis[3] = {1.0 * n, -2.0 * n, 3.0 * n};
    /* Angles near 0, pi/2, and near pi exercise every branch. */
    const double angles[5] = {1e-3, 0.7, VL_TEST_PI / 2, 3.0, VL_TEST_PI - 1e-6};
    for (int k = 0; k < 5; ++k) {
        double R[9], q[4];
        axis_angle(axis, angles[k], R);
        vl_rotation_to_quaternion(R, q);
        double h = angles[k] / 2.0;
        TEST_ASSERT_DOUBLE_WITHIN(1e-9, cos(h), q[0]);
        for (int i = 0; i < 3; ++i) {
            TEST_ASSERT_DOUBLE_WITHIN(1e-9, sin(h) * axis[i], q[1 + i]);
        }
    }
    /* 180 degrees about x: w = 0, x = +-1 */
    const double Rx[9] = {1, 0, 0, 0, -1, 0, 0, 0, -1};
    double q[4];
    vl_rotation_to_quaternion(Rx, q);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, 0.0, q[0]);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, 1.0, fabs(q[1]));
}

void test_vl_msg_from_pose_fills_both_messages(void)
{
    vl_pose_t pose;
    memset(&pose, 0, sizeof(pose));
    pose.utime = 123;
    const double axis[3] = {0, 0, 1};
    axis_angle(axis, VL_TEST_PI / 2, pose.rotation);
    pose.position[0] = 1;
    pose.position[1] = 2;
    pose.position[2] = 3;
    pose.covariance[0] = 0.5;
    pose.covariance[35] = 0.25;
    pose.linear_velocity[0] = 4;
    pose.angular_velocity[2] = 0.1;

    vislam_pose_t m;
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_from_pose(&pose, VISLAM_POSE_T_SOURCE_FEATURES, 9, &m));
    TEST_ASSERT_EQUAL_INT64(123, m.utime);
    TEST_ASSERT_EQUAL_INT8(VISLAM_POSE_T_SOURCE_FEATURES, m.source);
    TEST_ASSERT_EQUAL_INT64(9, m.sequence);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, sqrt(0.5), m.orientation[0]);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, sqrt(0.5), m.orientation[3]);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(pose.position, m.position, 3);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(pose.covariance, m.covariance, 36);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(pose.linear_velocity, m.linear_velocity, 3);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(pose.angular_velocity, m.angular_velocity, 3);

    bot_core_pose_t b;
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_from_pose_bot(&pose, &b));
    TEST_ASSERT_EQUAL_INT64(123, b.utime);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(m.orientation, b.orientation, 4);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(pose.position, b.pos, 3);
}

/* libbot2's pose_t has vel and rotation_rate in the local (world) frame: R times the body-frame values. */
void test_vl_msg_from_pose_bot_rotates_velocities_into_the_world(void)
{
    vl_pose_t pose;
    memset(&pose, 0, sizeof(pose));
    const double n = 1.0 / sqrt(14.0);
    const double axis[3] = {1.0 * n, -2.0 * n, 3.0 * n};
    axis_angle(axis, 2.0, pose.rotation);
    const double v[3] = {10.0, -0.5, 0.25};
    const double w[3] = {0.02, -0.3, 0.1};
    memcpy(pose.linear_velocity, v, sizeof(v));
    memcpy(pose.angular_velocity, w, sizeof(w));

    bot_core_pose_t b;
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_from_pose_bot(&pose, &b));
    const double *R = pose.rotation;
    for (int i = 0; i < 3; ++i) {
        const double vw = R[3 * i] * v[0] + R[3 * i + 1] * v[1] + R[3 * i + 2] * v[2];
        const double ww = R[3 * i] * w[0] + R[3 * i + 1] * w[1] + R[3 * i + 2] * w[2];
        TEST_ASSERT_DOUBLE_WITHIN(1e-12, vw, b.vel[i]);
        TEST_ASSERT_DOUBLE_WITHIN(1e-12, ww, b.rotation_rate[i]);
        TEST_ASSERT_EQUAL_DOUBLE(0.0, b.accel[i]);
    }
    /* A rotation keeps lengths, and this one moves every axis: the body values would fail above. */
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]),
                              sqrt(b.vel[0] * b.vel[0] + b.vel[1] * b.vel[1] + b.vel[2] * b.vel[2]));
    TEST_ASSERT_TRUE(fabs(b.vel[0] - v[0]) > 1.0);
    /* The world-frame velocity brought back through R^T is the body velocity the vislam message carries. */
    vislam_pose_t m;
    TEST_ASSERT_EQUAL_INT(VL_MSG_OK, vl_msg_from_pose(&pose, VISLAM_POSE_T_SOURCE_IMU, 0, &m));
    for (int j = 0; j < 3; ++j) {
        const double back = R[j] * b.vel[0] + R[3 + j] * b.vel[1] + R[6 + j] * b.vel[2];
        TEST_ASSERT_DOUBLE_WITHIN(1e-12, m.linear_velocity[j], back);
    }
}

void test_vl_trajectory_open_append_keeps_earlier_lines(void)
{
    static vl_trajectory_file_t t;
    char err[256];
    vl_pose_t pose;
    memset(&pose, 0, sizeof(pose));
    pose.rotation[0] = pose.rotation[4] = pose.rotation[8] = 1.0;
    close_writer();
    TEST_ASSERT_EQUAL_INT(0, truncate(g_path, 0));
    /* A new (empty) file: no comment, exactly the lines. */
    int appended = -1;
    TEST_ASSERT_EQUAL_INT_MESSAGE(0, vl_trajectory_open_append(&t, g_path, "run 2", &appended, err, sizeof(err)), err);
    TEST_ASSERT_EQUAL_INT(0, appended);
    TEST_ASSERT_EQUAL_INT(0, vl_trajectory_write(&t, 1000000, &pose));
    TEST_ASSERT_EQUAL_INT(0, vl_trajectory_close(&t));
    /* A crash cut the next line: the restart ends it, marks the new run and keeps everything. */
    FILE *f = fopen(g_path, "ab");
    fputs("2.000000 0.1", f);
    fclose(f);
    TEST_ASSERT_EQUAL_INT(0, vl_trajectory_open_append(&t, g_path, "run 2", &appended, err, sizeof(err)));
    TEST_ASSERT_EQUAL_INT(1, appended);
    TEST_ASSERT_EQUAL_INT(0, vl_trajectory_write(&t, 3000000, &pose));
    TEST_ASSERT_EQUAL_INT(0, vl_trajectory_close(&t));
    static char text[1024];
    f = fopen(g_path, "rb");
    const size_t n = fread(text, 1, sizeof(text) - 1, f);
    fclose(f);
    text[n] = '\0';
    TEST_ASSERT_EQUAL_STRING(
        "1.000000 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 1.000000000\n"
        "2.000000 0.1\n"
        "# run 2\n"
        "3.000000 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 1.000000000\n",
        text);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_vl_log_reader_next_round_trips_every_field);
    RUN_TEST(test_vl_log_reader_next_full_and_empty_frames);
    RUN_TEST(test_vl_log_reader_next_corrupt_payloads_are_counted_and_skipped);
    RUN_TEST(test_vl_log_reader_next_bad_count_message_names_the_count);
    RUN_TEST(test_vl_log_reader_next_skips_unknown_channels);
    RUN_TEST(test_vl_log_reader_open_custom_channels);
    RUN_TEST(test_vl_log_reader_next_cut_log_reports_truncation);
    RUN_TEST(test_vl_log_reader_open_missing_file_fails);
    RUN_TEST(test_vl_log_reader_next_length_0x7fffffff_is_reported_not_read);
    RUN_TEST(test_vl_log_reader_next_negative_and_huge_channel_lengths);
    RUN_TEST(test_vl_log_reader_next_bad_sync_resynchronizes);
    RUN_TEST(test_vl_log_reader_next_damaged_length_does_not_misframe);
    RUN_TEST(test_vl_log_reader_next_cut_header);
    RUN_TEST(test_vl_log_reader_next_cut_payload);
    RUN_TEST(test_vl_log_reader_next_empty_file);
    RUN_TEST(test_vl_log_reader_next_garbage_file);
    RUN_TEST(test_vl_log_reader_next_junk_between_events);
    RUN_TEST(test_vl_log_check_event_reports_each_problem);
    RUN_TEST(test_vl_trajectory_open_append_keeps_earlier_lines);
    RUN_TEST(test_vl_msg_to_stereo_frame_clamps_bad_counts);
    RUN_TEST(test_vl_msg_frame_round_trip);
    RUN_TEST(test_vl_msg_calibration_round_trip);
    RUN_TEST(test_vl_rotation_to_quaternion_matches_axis_angle);
    RUN_TEST(test_vl_msg_from_pose_fills_both_messages);
    RUN_TEST(test_vl_msg_from_pose_bot_rotates_velocities_into_the_world);
    RUN_TEST(test_vl_msg_landmark_batch_round_trip_and_capacity);
    return UNITY_END();
}
