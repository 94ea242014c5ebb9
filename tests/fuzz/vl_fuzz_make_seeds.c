/*
 * Makes the fuzzers' seed corpora from an LCM log (the build runs it on data/sample.lcmlog):
 *
 *   vl_fuzz_make_seeds LOG OUT_DIR
 *
 * writes OUT_DIR/messages/ (inputs of fuzz_messages, format in vl_fuzz.h) and
 * OUT_DIR/log_reader/ (small LCM logs for fuzz_log_reader). The seeds are the log's own
 * events: the calibration, then IMU samples and frames in log order, so every seed starts
 * from what a real run looks like and the fuzzer mutates from there. They are kept small
 * (a few steps) so that each fuzzer execution stays fast.
 */
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include <lcm/eventlog.h>

#include "vl_fuzz.h"
#include "vl_log_reader.h"

/* The first events of the log kept in memory: enough for the longest seed. */
#define VL_SEED_MAX_EVENTS 64
/* Steps (an IMU sample and a frame) in the longest messages seed. */
#define VL_SEED_MAX_STEPS 8

typedef struct {
    int channel; /* VL_FUZZ_CH_*, or -1 for a channel the harnesses do not decode */
    lcm_eventlog_event_t *le;
} vl_seed_event_t;

static vl_seed_event_t g_events[VL_SEED_MAX_EVENTS];
static int g_num_events;
static const char *g_out;

static int vl_seed_channel(const char *name)
{
    if (strcmp(name, VL_CHANNEL_IMU) == 0) {
        return VL_FUZZ_CH_IMU;
    }
    if (strcmp(name, VL_CHANNEL_FEATURES) == 0) {
        return VL_FUZZ_CH_FEATURES;
    }
    if (strcmp(name, VL_CHANNEL_CALIBRATION) == 0) {
        return VL_FUZZ_CH_CALIBRATION;
    }
    return -1;
}

static void vl_seed_die(const char *what, const char *path)
{
    fprintf(stderr, "vl_fuzz_make_seeds: %s: %s%s%s\n", what, path, errno != 0 ? ": " : "",
            errno != 0 ? strerror(errno) : "");
    exit(1);
}

static void vl_seed_mkdir(const char *path)
{
    errno = 0;
    if (mkdir(path, 0777) != 0 && errno != EEXIST) {
        vl_seed_die("cannot create directory", path);
    }
}

static FILE *vl_seed_open(const char *kind, const char *name, char *path, size_t path_len)
{
    snprintf(path, path_len, "%s/%s/%s", g_out, kind, name);
    errno = 0;
    FILE *f = fopen(path, "wb");
    if (f == NULL) {
        vl_seed_die("cannot write", path);
    }
    return f;
}

static void vl_seed_close(FILE *f, const char *path)
{
    errno = 0;
    if (fclose(f) != 0) {
        vl_seed_die("write failed", path);
    }
}

static void vl_seed_put_record(FILE *f, int channel, const lcm_eventlog_event_t *le)
{
    const uint8_t header[VL_FUZZ_RECORD_HEADER] = {(uint8_t)channel, (uint8_t)(le->datalen & 0xff),
                                                   (uint8_t)((le->datalen >> 8) & 0xff)};
    fwrite(header, 1, sizeof(header), f);
    fwrite(le->data, 1, (size_t)le->datalen, f);
}

/*
 * A fuzz_messages seed: configuration byte, then the log's events in order up to `steps`
 * frames; `calibration` 0 leaves the calibration out, 1 puts it first, 2 puts it last
 * (after inputs, where vislamd ignores a new one).
 */
static void vl_seed_messages(const char *name, uint8_t config, int steps, int calibration)
{
    char path[4096];
    FILE *f = vl_seed_open("messages", name, path, sizeof(path));
    fputc(config, f);
    const vl_seed_event_t *calib = NULL;
    for (int i = 0; i < g_num_events; ++i) {
        if (g_events[i].channel == VL_FUZZ_CH_CALIBRATION && calib == NULL) {
            calib = &g_events[i];
        }
    }
    if (calibration == 1 && calib != NULL) {
        vl_seed_put_record(f, VL_FUZZ_CH_CALIBRATION, calib->le);
    }
    int frames = 0;
    for (int i = 0; i < g_num_events && frames < steps; ++i) {
        const vl_seed_event_t *ev = &g_events[i];
        if (ev->channel == VL_FUZZ_CH_IMU || ev->channel == VL_FUZZ_CH_FEATURES) {
            vl_seed_put_record(f, ev->channel, ev->le);
            frames += ev->channel == VL_FUZZ_CH_FEATURES;
        }
    }
    if (calibration == 2 && calib != NULL) {
        vl_seed_put_record(f, VL_FUZZ_CH_CALIBRATION, calib->le);
    }
    vl_seed_close(f, path);
}

/* A fuzz_log_reader seed: the first `count` events of the log, rewritten as an LCM log. */
static void vl_seed_log(const char *name, int count, const lcm_eventlog_event_t *extra)
{
    char path[4096];
    FILE *f = vl_seed_open("log_reader", name, path, sizeof(path));
    fclose(f);
    lcm_eventlog_t *log = lcm_eventlog_create(path, "w");
    if (log == NULL) {
        vl_seed_die("cannot write", path);
    }
    for (int i = 0; i < count && i < g_num_events; ++i) {
        if (lcm_eventlog_write_event(log, g_events[i].le) != 0) {
            vl_seed_die("write failed", path);
        }
        if (i == 0 && extra != NULL && lcm_eventlog_write_event(log, (lcm_eventlog_event_t *)extra) != 0) {
            vl_seed_die("write failed", path);
        }
    }
    lcm_eventlog_destroy(log);
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s LOG OUT_DIR\n", argv[0]);
        return 2;
    }
    g_out = argv[2];
    errno = 0;
    lcm_eventlog_t *log = lcm_eventlog_create(argv[1], "r");
    if (log == NULL) {
        vl_seed_die("cannot open", argv[1]);
    }
    int have[VL_FUZZ_NUM_CHANNELS] = {0};
    while (g_num_events < VL_SEED_MAX_EVENTS) {
        lcm_eventlog_event_t *le = lcm_eventlog_read_next_event(log);
        if (le == NULL) {
            break;
        }
        const int channel = vl_seed_channel(le->channel);
        if (le->datalen > 0xffff) {
            fprintf(stderr, "vl_fuzz_make_seeds: event %lld on %s: %d bytes do not fit a record\n",
                    (long long)le->eventnum, le->channel, (int)le->datalen);
            return 1;
        }
        if (channel >= 0) {
            have[channel] = 1;
        }
        g_events[g_num_events].channel = channel;
        g_events[g_num_events].le = le;
        g_num_events++;
    }
    lcm_eventlog_destroy(log);
    if (!have[VL_FUZZ_CH_IMU] || !have[VL_FUZZ_CH_FEATURES] || !have[VL_FUZZ_CH_CALIBRATION]) {
        fprintf(stderr, "vl_fuzz_make_seeds: %s: the first %d events lack a calibration, IMU sample or frame\n",
                argv[1], VL_SEED_MAX_EVENTS);
        return 1;
    }

    vl_seed_mkdir(g_out);
    char dir[4096];
    snprintf(dir, sizeof(dir), "%s/messages", g_out);
    vl_seed_mkdir(dir);
    snprintf(dir, sizeof(dir), "%s/log_reader", g_out);
    vl_seed_mkdir(dir);

    /* fuzz_messages: the default configuration over 1, 3 and 8 steps ... */
    vl_seed_messages("default_1_step", 0x00, 1, 1);
    vl_seed_messages("default_3_steps", 0x00, 3, 1);
    vl_seed_messages("default_8_steps", 0x00, VL_SEED_MAX_STEPS, 1);
    /* ... each configuration bit over a few steps (small windows keep runs fast) ... */
    vl_seed_messages("mapping_window16", 0x01 | 0x10, 4, 1);
    vl_seed_messages("imu_only", 0x02, 4, 1);
    vl_seed_messages("seed_preset_window4", VL_FUZZ_CFG_PRESET_SEED | 0x20, 4, 1);
    vl_seed_messages("adaptive_window1", VL_FUZZ_CFG_ADAPTIVE | 0x30, 4, 1);
    vl_seed_messages("no_offsets_no_outliers", VL_FUZZ_CFG_NO_OFFSETS | VL_FUZZ_CFG_NO_OUTLIERS | 0x10, 4, 1);
    /* ... and the calibration policy: inputs before any calibration, a calibration after inputs. */
    vl_seed_messages("no_calibration", 0x00, 2, 0);
    vl_seed_messages("calibration_after_inputs", 0x10, 2, 2);

    /* fuzz_log_reader: the log's first events, and an event on a channel the reader skips. */
    static char other_channel[] = "OTHER_CHANNEL";
    static uint8_t other_data[] = {1, 2, 3, 4};
    lcm_eventlog_event_t other;
    memset(&other, 0, sizeof(other));
    other.timestamp = g_events[0].le->timestamp;
    other.channellen = (int32_t)strlen(other_channel);
    other.channel = other_channel;
    other.datalen = (int32_t)sizeof(other_data);
    other.data = other_data;
    vl_seed_log("first_event", 1, NULL);
    vl_seed_log("first_3_events", 3, NULL);
    vl_seed_log("first_7_events_and_other_channel", 7, &other);

    for (int i = 0; i < g_num_events; ++i) {
        lcm_eventlog_free_event(g_events[i].le);
    }
    printf("vl_fuzz_make_seeds: 10 messages seeds, 3 log seeds from %s in %s\n", argv[1], g_out);
    return 0;
}
