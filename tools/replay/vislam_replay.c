/*
 * vislam-replay: plays an LCM log over LCM at its recorded rate.
 *
 * Every event is sent at an absolute CLOCK_MONOTONIC deadline computed from
 * its log timestamp (clock_nanosleep TIMER_ABSTIME), so sleeping and sending
 * costs do not accumulate into drift. --lockstep waits after each feature
 * frame for the daemon's pose of that frame (same utime, source FEATURES):
 * the deterministic mode, which also measures the end-to-end latency from
 * publishing the frame to receiving its pose. The schedule pauses while it
 * waits, so the spacing of later events is kept.
 *
 * Robustness: every event header is checked before liblcm reads it
 * (vl_log_guard), so a damaged or cut log is reported and skipped, never a
 * crash. The log's calibration is re-published every --calib-period-ms of log
 * time, and at once when the daemon restarts or a lockstep pose does not come,
 * as a latched message would be, so a daemon started late resumes. A pose is
 * only counted as an answer when it answers an input this replay published
 * (its utime and source), its sequence increases and its values are finite;
 * anything else on the pose channel is counted as foreign.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <lcm/lcm.h>

#include "vl_channels.h"
#include "vl_cli.h"
#include "vl_clock.h"
#include "vl_latency.h"
#include "vl_lcm_rx.h"
#include "vl_log_guard.h"
#include "vl_log_reader.h"
#include "vl_msg.h"
#include "vl_signal.h"

#include "vislam_imu_t.h"
#include "vislam_pose_t.h"
#include "vislam_status_t.h"
#include "vislam_stereo_frame_t.h"

#define EXIT_INCOMPLETE 1
#define EXIT_USAGE 2
#define EXIT_LOG_DAMAGED 3

#define CALIB_MAX 4096     /* bytes of the largest calibration payload kept for re-publication */
#define RECENT_INPUTS 1024 /* published inputs a pose may answer */
#define REPORTS_MAX 5      /* damaged spots and foreign poses described on stderr; then only counted */

#define MAX_FILTER 16
#define MAX_CHANNELS 32
#define CHANNEL_MAX 64
#define PROGRESS_PERIOD_US 250000
#define MAX_CONSECUTIVE_TIMEOUTS 3

typedef struct {
    const char *log_path;
    const char *lcm_url;
    const char *pose_channel;
    const char *features_channel;
    const char *wait_for;
    const char *summary_json;
    const char *latency_samples;
    const char *imu_channel;
    const char *calib_channel;
    const char *status_channel;
    long calib_period_ms;
    long max_timeouts;
    const char *filter[MAX_FILTER];
    int num_filter;
    int all_channels; /* every channel of the log, not only the inputs */
    double speed;
    int max;
    int lockstep;
    long timeout_ms;
    long busy_poll_us;      /* lockstep: spin on the socket this long for the pose before sleeping */
    int lcm_receive_thread; /* receive through liblcm's thread rather than on the socket directly */
    long wait_timeout_ms;   /* --wait-for; negative: timeout_ms */
    long linger_ms;
    int quiet;
} options_t;

typedef struct {
    char name[CHANNEL_MAX];
    uint64_t events; /* sent, or skipped */
} channel_count_t;

/* An input this replay published, which a pose may answer. */
typedef struct {
    int64_t utime;
    int8_t source; /* VISLAM_POSE_T_SOURCE_* */
} published_t;

typedef struct {
    options_t opt;
    lcm_t *lcm;
    int direct;     /* received on the socket in this thread (vl_lcm_rx), not through liblcm's */
    vl_lcm_rx_t rx; /* the direct receiver */
    vl_log_guard_t guard;
    /* the log's latest calibration, re-published like a latched message */
    uint8_t calib_buf[CALIB_MAX];
    unsigned calib_len;
    int have_calib;
    int calib_too_large;
    int64_t calib_published_log_utime;
    int resend_calib;
    uint64_t calib_resent;
    /* pose provenance */
    published_t recent[RECENT_INPUTS];
    unsigned recent_next, recent_count;
    int64_t last_sequence;
    uint64_t poses_accepted, poses_foreign, poses_non_finite, daemon_restarts;
    vislam_status_t status_msg;
    /* sending */
    channel_count_t channels[MAX_CHANNELS];
    int num_channels;
    channel_count_t skipped[MAX_CHANNELS]; /* events of the channels not replayed */
    int num_skipped;
    uint64_t sent, other_sent, publish_errors, filtered, events_read;
    int64_t first_log_utime, last_log_utime;
    /* receiving */
    uint64_t poses, poses_imu, poses_features, pose_decode_errors;
    int waiting;
    int64_t expected_utime;
    int64_t publish_mono_us;
    int64_t publish_real_ns; /* the same instant on CLOCK_REALTIME, ns: compared with vislamd's stamps */
    int matched;
    uint64_t expected, returned, missing;
    vl_latency_t latency;
    FILE *samples; /* --latency-samples: per frame, its end-to-end latency (us), utime (us), stamps (ns) */
    vislam_pose_t pose_msg;
    /* inputs decoded with the receivers' checks (vl_log_event_decode), for their utime */
    vl_log_decoder_t decoder;
    vl_log_event_t input;
    int saw_wait_for;
} replay_t;

static replay_t g;

static void usage(FILE *f)
{
    fprintf(f,
            "usage: vislam-replay LOG [options]\n"
            "Publishes the events of an LCM log on their channels at the recorded rate, sleeping to\n"
            "absolute CLOCK_MONOTONIC deadlines so that it does not drift.\n"
            "\n"
            "  --speed X             play X times faster than recorded (default 1)\n"
            "  --max                 as fast as possible (no sleeping)\n"
            "  --lockstep            after each frame on the features channel, wait for the pose with\n"
            "                        that frame's utime and source FEATURES before going on; measures\n"
            "                        the end-to-end latency (frame published -> pose received)\n"
            "  --timeout-ms N        lockstep and --wait-for: how long to wait (default 5000)\n"
            "  --max-timeouts N      lockstep: give up after N timeouts in a row (default %d; 0 = never,\n"
            "                        to see whether the daemon recovers from a fault)\n"
            "  --channels A,B,...    publish only these channels (default: the input channels, those of\n"
            "                        --imu-channel, --features-channel and --calib-channel)\n"
            "  --all-channels        publish every channel of the log, also the recorded outputs of a\n"
            "                        daemon (a log from lcm-logger holds its " VL_CHANNEL_POSE ", " VL_CHANNEL_BOT_POSE
            ", ...)\n"
            "  --features-channel C  frames that lockstep waits for (default " VL_CHANNEL_FEATURES ")\n"
            "  --pose-channel C      poses counted and awaited (default " VL_CHANNEL_POSE ")\n"
            "  --wait-for C          before playing, wait until a message arrives on C (e.g.\n"
            "                        " VL_CHANNEL_STATUS ": the daemon publishes one as soon as it is up)\n"
            "  --wait-timeout-ms N   how long --wait-for waits (default: --timeout-ms)\n"
            "  --linger-ms N         after the last event, keep counting poses for N ms (default 500)\n"
            "  --imu-channel C       IMU samples whose poses count as answers (default " VL_CHANNEL_IMU ")\n"
            "  --calib-channel C     the calibration re-published (default " VL_CHANNEL_CALIBRATION ")\n"
            "  --calib-period-ms N   re-publish the log's latest calibration every N ms of log time,\n"
            "                        and at once after a daemon restart or a lockstep timeout, as a\n"
            "                        latched message would be (default 1000; 0 = never)\n"
            "  --status-channel C    the daemon's status: a pose count going back there is a daemon\n"
            "                        restart, whose sequence numbers start again (default " VL_CHANNEL_STATUS ")\n"
            "  --lcm-url URL         LCM provider (default: $LCM_DEFAULT_URL, else LCM's default)\n"
            "  --busy-poll-us N      lockstep: spin on the socket up to N us for the pose before sleeping\n"
            "                        (default 0): trades a CPU for the wake-up\n"
            "  --lcm-receive-thread  receive through liblcm's thread, queue and pipe instead of reading the\n"
            "                        multicast socket directly (other LCM providers than udpm:// always do)\n"
            "  --summary-json FILE   also write the summary as JSON\n"
            "  --latency-samples FILE  lockstep: a line per frame answered: its end-to-end latency (us),\n"
            "                        its utime (us), then CLOCK_REALTIME ns: frame published, the pose's\n"
            "                        kernel receive stamp, pose handler called\n"
            "  --quiet               no progress line and no summary on stderr\n"
            "  --version             print the version and exit\n"
            "  --help                this text\n"
            "\n"
            "By default only the inputs of the estimator are replayed: a log recorded with lcm-logger\n"
            "also holds the poses and statuses of the daemon that ran then, which would mislead a\n"
            "listener (and could answer --lockstep in place of the daemon). The events skipped are\n"
            "counted per channel in the summary.\n"
            "A progress line is shown when stderr is a terminal. The summary gives the messages sent,\n"
            "poses received and, in lockstep, the end-to-end latency percentiles.\n"
            "A pose counts as an answer only if it answers an input this replay published (same utime\n"
            "and source), its sequence increases and its values are finite; others are foreign.\n"
            "Every event header is checked before it is read: damaged spots (bad sync word, absurd\n"
            "length, junk) are reported with their file offset and skipped to the next valid event.\n"
            "Exit status: 0 the log was played (and, in lockstep, every expected pose came back);\n"
            "1 incomplete (missing poses, foreign poses, publish errors, nothing on --wait-for,\n"
            "interrupted); 2 usage error, unreadable log or LCM unavailable; 3 the log is damaged\n"
            "(unreadable spots, cut inside an event, or no event at all).\n",
            MAX_CONSECUTIVE_TIMEOUTS);
}

static int parse_args(int argc, char **argv, options_t *o)
{
    memset(o, 0, sizeof(*o));
    o->speed = 1.0;
    o->timeout_ms = 5000;
    o->wait_timeout_ms = -1;
    o->linger_ms = 500;
    o->pose_channel = VL_CHANNEL_POSE;
    o->features_channel = VL_CHANNEL_FEATURES;
    o->imu_channel = VL_CHANNEL_IMU;
    o->calib_channel = VL_CHANNEL_CALIBRATION;
    o->status_channel = VL_CHANNEL_STATUS;
    o->calib_period_ms = 1000;
    o->max_timeouts = MAX_CONSECUTIVE_TIMEOUTS;
    static char filter_buf[1024];
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            exit(0);
        } else if (strcmp(a, "--version") == 0) {
            exit(vl_cli_print_version(stdout, "vislam-replay") == 0 ? 0 : EXIT_INCOMPLETE);
        } else if (strcmp(a, "--max") == 0) {
            o->max = 1;
            continue;
        } else if (strcmp(a, "--lockstep") == 0) {
            o->lockstep = 1;
            continue;
        } else if (strcmp(a, "--lcm-receive-thread") == 0) {
            o->lcm_receive_thread = 1;
            continue;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = 1;
            continue;
        } else if (strcmp(a, "--all-channels") == 0) {
            o->all_channels = 1;
            continue;
        } else if (a[0] != '-' || a[1] == '\0') {
            if (o->log_path != NULL) {
                fprintf(stderr, "vislam-replay: more than one log given (%s, %s)\n", o->log_path, a);
                return -1;
            }
            o->log_path = a;
            continue;
        }
        static const char *const with_value[] = {
            "--speed",           "--timeout-ms",       "--linger-ms",       "--channels",     "--lcm-url",
            "--pose-channel",    "--features-channel", "--wait-for",        "--summary-json", "--imu-channel",
            "--calib-channel",   "--status-channel",   "--calib-period-ms", "--max-timeouts", "--wait-timeout-ms",
            "--latency-samples", "--busy-poll-us"};
        int known = 0;
        for (size_t k = 0; k < sizeof(with_value) / sizeof(with_value[0]); ++k) {
            known |= strcmp(a, with_value[k]) == 0;
        }
        if (!known) {
            fprintf(stderr, "vislam-replay: unknown option %s (see --help)\n", a);
            return -1;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "vislam-replay: %s needs a value\n", a);
            return -1;
        }
        const char *v = argv[++i];
        char *end = NULL;
        errno = 0;
        if (strcmp(a, "--speed") == 0) {
            o->speed = strtod(v, &end);
            if (end == v || *end != '\0' || errno != 0 || !(o->speed > 0.0) || !isfinite(o->speed)) {
                fprintf(stderr, "vislam-replay: --speed %s: expected a number > 0\n", v);
                return -1;
            }
        } else if (strcmp(a, "--timeout-ms") == 0 || strcmp(a, "--linger-ms") == 0 ||
                   strcmp(a, "--calib-period-ms") == 0 || strcmp(a, "--wait-timeout-ms") == 0) {
            const long n = strtol(v, &end, 10);
            if (end == v || *end != '\0' || errno != 0 || n < 0 || n > 3600000L) {
                fprintf(stderr, "vislam-replay: %s %s: expected an integer in 0..3600000\n", a, v);
                return -1;
            }
            long *dst = &o->calib_period_ms;
            if (strcmp(a, "--timeout-ms") == 0) {
                dst = &o->timeout_ms;
            } else if (strcmp(a, "--linger-ms") == 0) {
                dst = &o->linger_ms;
            } else if (strcmp(a, "--wait-timeout-ms") == 0) {
                dst = &o->wait_timeout_ms;
            }
            *dst = n;
        } else if (strcmp(a, "--max-timeouts") == 0 || strcmp(a, "--busy-poll-us") == 0) {
            const long n = strtol(v, &end, 10);
            if (end == v || *end != '\0' || errno != 0 || n < 0 || n > 1000000L) {
                fprintf(stderr, "vislam-replay: %s %s: expected an integer in 0..1000000\n", a, v);
                return -1;
            }
            if (strcmp(a, "--busy-poll-us") == 0) {
                o->busy_poll_us = n;
            } else {
                o->max_timeouts = n;
            }
        } else if (strcmp(a, "--imu-channel") == 0) {
            o->imu_channel = v;
        } else if (strcmp(a, "--calib-channel") == 0) {
            o->calib_channel = v;
        } else if (strcmp(a, "--status-channel") == 0) {
            o->status_channel = v;
        } else if (strcmp(a, "--channels") == 0) {
            snprintf(filter_buf, sizeof(filter_buf), "%s", v);
            o->num_filter = 0;
            for (char *tok = strtok(filter_buf, ","); tok != NULL; tok = strtok(NULL, ",")) {
                if (o->num_filter == MAX_FILTER) {
                    fprintf(stderr, "vislam-replay: --channels: at most %d channels\n", MAX_FILTER);
                    return -1;
                }
                o->filter[o->num_filter++] = tok;
            }
            if (o->num_filter == 0) {
                fprintf(stderr, "vislam-replay: --channels: no channel given\n");
                return -1;
            }
        } else if (strcmp(a, "--lcm-url") == 0) {
            o->lcm_url = v;
        } else if (strcmp(a, "--pose-channel") == 0) {
            o->pose_channel = v;
        } else if (strcmp(a, "--features-channel") == 0) {
            o->features_channel = v;
        } else if (strcmp(a, "--wait-for") == 0) {
            o->wait_for = v;
        } else if (strcmp(a, "--summary-json") == 0) {
            o->summary_json = v;
        } else if (strcmp(a, "--latency-samples") == 0) {
            o->latency_samples = v;
        } else {
            fprintf(stderr, "vislam-replay: unknown option %s (see --help)\n", a);
            return -1;
        }
    }
    if (o->log_path == NULL) {
        fprintf(stderr, "vislam-replay: no LOG given (see --help)\n");
        return -1;
    }
    if (o->all_channels && o->num_filter > 0) {
        fprintf(stderr, "vislam-replay: --all-channels and --channels exclude each other\n");
        return -1;
    }
    if (o->max && o->speed != 1.0) {
        fprintf(stderr, "vislam-replay: --max and --speed exclude each other\n");
        return -1;
    }
    return 0;
}

/* --channels if given, else every channel with --all-channels, else the three inputs. */
static int channel_selected(const options_t *o, const char *channel)
{
    if (o->num_filter == 0) {
        return o->all_channels || strcmp(channel, o->imu_channel) == 0 || strcmp(channel, o->features_channel) == 0 ||
               strcmp(channel, o->calib_channel) == 0;
    }
    for (int i = 0; i < o->num_filter; ++i) {
        if (strcmp(o->filter[i], channel) == 0) {
            return 1;
        }
    }
    return 0;
}

/* One more event on channel in counts; 0, or -1 when the table is full (then counted elsewhere). */
static int count_channel(channel_count_t *counts, int *num, const char *channel)
{
    for (int i = 0; i < *num; ++i) {
        if (strcmp(counts[i].name, channel) == 0) {
            counts[i].events++;
            return 0;
        }
    }
    if (*num == MAX_CHANNELS) {
        return -1;
    }
    channel_count_t *c = &counts[(*num)++];
    snprintf(c->name, sizeof(c->name), "%s", channel);
    c->events = 1;
    return 0;
}

static void count_sent(replay_t *r, const char *channel)
{
    r->sent++;
    if (count_channel(r->channels, &r->num_channels, channel) != 0) {
        r->other_sent++;
    }
}

/* What is replayed, said before anything is sent (the warning even with --quiet). */
static void print_selection(const options_t *o)
{
    if (o->quiet) {
        /* nothing but the warning below */
    } else if (o->num_filter > 0) {
        fprintf(stderr, "vislam-replay: replaying the channels given by --channels; skipping the others\n");
    } else if (o->all_channels) {
        fprintf(stderr, "vislam-replay: replaying every channel of the log (--all-channels)\n");
    } else {
        fprintf(stderr,
                "vislam-replay: replaying the input channels %s, %s, %s; skipping events on other channels "
                "(--all-channels replays them)\n",
                o->imu_channel, o->features_channel, o->calib_channel);
    }
    if (o->lockstep && channel_selected(o, o->pose_channel)) {
        fprintf(stderr,
                "vislam-replay: warning: the log's own poses on %s are replayed too and can answer "
                "--lockstep in place of the daemon\n",
                o->pose_channel);
    }
}

/* ---- receiving ---- */

static void remember_input(replay_t *r, int64_t utime, int8_t source)
{
    r->recent[r->recent_next].utime = utime;
    r->recent[r->recent_next].source = source;
    r->recent_next = (r->recent_next + 1) % RECENT_INPUTS;
    if (r->recent_count < RECENT_INPUTS) {
        r->recent_count++;
    }
}

static int answers_an_input(const replay_t *r, int64_t utime, int8_t source)
{
    for (unsigned i = 0; i < r->recent_count; ++i) {
        if (r->recent[i].utime == utime && r->recent[i].source == source) {
            return 1;
        }
    }
    return 0;
}

static int pose_finite(const vislam_pose_t *p)
{
    /* One sum: any NaN or infinity makes it non-finite (finite values this large do not occur). */
    double sum = 0.0;
    for (int i = 0; i < 3; ++i) {
        sum += p->position[i] + p->linear_velocity[i] + p->angular_velocity[i];
    }
    for (int i = 0; i < 4; ++i) {
        sum += p->orientation[i];
    }
    for (int i = 0; i < 36; ++i) {
        sum += p->covariance[i];
    }
    return isfinite(sum);
}

static void report_foreign(replay_t *r, const char *why)
{
    r->poses_foreign++;
    if (r->poses_foreign <= REPORTS_MAX) {
        fprintf(stderr,
                "vislam-replay: foreign pose on %s (utime %" PRId64 ", source %d, sequence %" PRId64 "): %s%s\n",
                r->opt.pose_channel, r->pose_msg.utime, (int)r->pose_msg.source, r->pose_msg.sequence, why,
                r->poses_foreign == REPORTS_MAX ? " (further ones only counted)" : "");
    }
}

static void on_pose(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    (void)channel;
    replay_t *r = (replay_t *)user;
    const int64_t now = vl_clock_monotonic_us();
    const int64_t now_real_ns = vl_clock_realtime_ns();
    if (!vl_msg_decoded_whole(vislam_pose_t_decode(rbuf->data, 0, (int)rbuf->data_size, &r->pose_msg),
                              (int)rbuf->data_size)) {
        r->pose_decode_errors++;
        r->poses_foreign++;
        return;
    }
    r->poses++;
    const vislam_pose_t *m = &r->pose_msg;
    if (m->source == VISLAM_POSE_T_SOURCE_FEATURES) {
        r->poses_features++;
    } else if (m->source == VISLAM_POSE_T_SOURCE_IMU) {
        r->poses_imu++;
    }
    if (!pose_finite(m)) {
        r->poses_non_finite++;
        report_foreign(r, "non-finite values");
        return;
    }
    if (!answers_an_input(r, m->utime, m->source)) {
        report_foreign(r, "answers no input this replay published");
        return;
    }
    if (m->sequence <= r->last_sequence) {
        report_foreign(r, "sequence not increasing");
        return;
    }
    r->last_sequence = m->sequence;
    r->poses_accepted++;
    if (r->waiting && !r->matched && m->source == VISLAM_POSE_T_SOURCE_FEATURES && m->utime == r->expected_utime) {
        r->matched = 1;
        vl_latency_record(&r->latency, now - r->publish_mono_us);
        if (r->samples != NULL) {
            fprintf(r->samples, "%" PRId64 " %" PRId64 " %" PRId64 " %" PRId64 " %" PRId64 "\n",
                    now - r->publish_mono_us, m->utime, r->publish_real_ns, rbuf->recv_utime * 1000, now_real_ns);
        }
    }
}

/* The daemon's pose count going back means a new daemon: its sequence numbers start again, and
   it needs the calibration the log sent once. */
static void on_status(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    (void)channel;
    replay_t *r = (replay_t *)user;
    if (!vl_msg_decoded_whole(vislam_status_t_decode(rbuf->data, 0, (int)rbuf->data_size, &r->status_msg),
                              (int)rbuf->data_size)) {
        return;
    }
    if (r->status_msg.poses_out <= r->last_sequence) {
        r->daemon_restarts++;
        r->last_sequence = r->status_msg.poses_out - 1;
        r->resend_calib = 1;
        fprintf(stderr, "vislam-replay: the daemon restarted (its pose count went back to %" PRId64 ")\n",
                r->status_msg.poses_out);
    }
}

static void on_wait_for(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    (void)rbuf;
    (void)channel;
    ((replay_t *)user)->saw_wait_for = 1;
}

static void publish_calibration(replay_t *r)
{
    if (lcm_publish(r->lcm, r->opt.calib_channel, r->calib_buf, r->calib_len) != 0) {
        r->publish_errors++;
    }
    r->calib_resent++;
}

/* A re-publication asked for by a restart or a timeout, if there is a calibration to send. */
static void resend_calibration_if_asked(replay_t *r)
{
    if (r->resend_calib && r->have_calib && r->opt.calib_period_ms > 0) {
        publish_calibration(r);
    }
    r->resend_calib = 0;
}

/* Handles whatever has arrived, without blocking. */
static void poll_incoming(replay_t *r)
{
    vl_lcm_rx_poll(&r->rx, 10000);
}

/* Handles messages until *flag is set, the deadline passes or a stop is requested. */
static int wait_until_flag(replay_t *r, const int *flag, int64_t deadline_us)
{
    /* --busy-poll-us: the first part of the wait reads the socket without sleeping. */
    const int64_t spin_until = vl_clock_monotonic_us() + (r->direct ? r->opt.busy_poll_us : 0);
    while (!*flag && !vl_signal_stop_requested()) {
        const int64_t now = vl_clock_monotonic_us();
        const int64_t left = deadline_us - now;
        if (left <= 0) {
            break;
        }
        if (now < spin_until || vl_signal_wait_fd(vl_lcm_rx_fd(&r->rx), left > 100000 ? 100000 : left) > 0) {
            poll_incoming(r);
        }
        resend_calibration_if_asked(r);
    }
    return *flag;
}

/* ---- progress and summary ---- */

static void progress(const replay_t *r, long pos, long size, int final)
{
    const double log_s = (double)(r->last_log_utime - r->first_log_utime) * 1e-6;
    fprintf(stderr, "\rvislam-replay: %5.1f%%  log %8.2f s  sent %8" PRIu64 "  poses %8" PRIu64 "%s",
            size > 0 ? 100.0 * (double)pos / (double)size : 0.0, log_s, r->sent, r->poses, final ? "\n" : "");
}

static void print_summary(const replay_t *r, double wall_s, int interrupted)
{
    const double log_s = (double)(r->last_log_utime - r->first_log_utime) * 1e-6;
    fprintf(stderr, "vislam-replay: %s: %" PRIu64 " messages sent in %.2f s (log span %.2f s, %.2fx)%s\n",
            r->opt.log_path, r->sent, wall_s, log_s, wall_s > 0 ? log_s / wall_s : 0.0,
            interrupted ? " - interrupted" : "");
    for (int i = 0; i < r->num_channels; ++i) {
        fprintf(stderr, "  %-24s %8" PRIu64 "\n", r->channels[i].name, r->channels[i].events);
    }
    if (r->filtered != 0) {
        fprintf(stderr, "  skipped %" PRIu64 " events on other channels (%s):", r->filtered,
                r->opt.num_filter > 0 ? "not in --channels" : "not inputs; --all-channels replays them");
        for (int i = 0; i < r->num_skipped; ++i) {
            fprintf(stderr, " %s %" PRIu64, r->skipped[i].name, r->skipped[i].events);
        }
        fputc('\n', stderr);
    }
    if (r->publish_errors != 0) {
        fprintf(stderr, "  publish errors: %" PRIu64 "\n", r->publish_errors);
    }
    fprintf(stderr, "  poses received on %s: %" PRIu64 " (imu %" PRIu64 ", features %" PRIu64 ")%s\n",
            r->opt.pose_channel, r->poses, r->poses_imu, r->poses_features,
            r->pose_decode_errors != 0 ? " plus undecodable ones" : "");
    fprintf(stderr,
            "  answers accepted %" PRIu64 ", foreign poses %" PRIu64 " (non-finite %" PRIu64
            "), daemon restarts %" PRIu64 ", calibrations re-published %" PRIu64 "\n",
            r->poses_accepted, r->poses_foreign, r->poses_non_finite, r->daemon_restarts, r->calib_resent);
    if (r->direct && (r->rx.fragments != 0 || r->rx.malformed != 0)) {
        /* The direct receiver hands on single-datagram messages only: the rest is counted. */
        fprintf(stderr, "  lcm receive: fragmented (dropped) %" PRIu64 ", malformed %" PRIu64 "\n", r->rx.fragments,
                r->rx.malformed);
    }
    if (vl_log_guard_damaged(&r->guard) || r->guard.events == 0) {
        fprintf(stderr, "  log damaged: %" PRIu64 " unreadable spot(s), %" PRIu64 " bytes skipped, %s%s\n",
                r->guard.damaged, r->guard.bytes_skipped, r->guard.truncated ? "cut inside an event" : "not cut",
                r->guard.events == 0 ? ", no event at all" : "");
    }
    if (r->opt.lockstep) {
        fprintf(stderr, "  lockstep: %" PRIu64 " frames, %" PRIu64 " poses came back, %" PRIu64 " missing\n",
                r->expected, r->returned, r->missing);
        vl_latency_print(&r->latency, stderr, "  end-to-end latency (frame published -> pose received)");
    }
}

static int write_json(const replay_t *r, double wall_s, int interrupted)
{
    FILE *f = fopen(r->opt.summary_json, "w");
    if (f == NULL) {
        fprintf(stderr, "vislam-replay: cannot write %s: %s\n", r->opt.summary_json, strerror(errno));
        return -1;
    }
    fprintf(f, "{\n  \"messages_sent\": %" PRIu64 ",\n  \"channels\": {", r->sent);
    for (int i = 0; i < r->num_channels; ++i) {
        fprintf(f, "%s\n    \"%s\": %" PRIu64, i == 0 ? "" : ",", r->channels[i].name, r->channels[i].events);
    }
    fprintf(f, "\n  },\n  \"events_skipped\": %" PRIu64 ",\n  \"channels_skipped\": {", r->filtered);
    for (int i = 0; i < r->num_skipped; ++i) {
        fprintf(f, "%s\n    \"%s\": %" PRIu64, i == 0 ? "" : ",", r->skipped[i].name, r->skipped[i].events);
    }
    fprintf(f, "\n  },\n  \"publish_errors\": %" PRIu64 ",\n", r->publish_errors);
    fprintf(f,
            "  \"poses_received\": %" PRIu64 ",\n  \"poses_imu\": %" PRIu64 ",\n  \"poses_features\": %" PRIu64 ",\n",
            r->poses, r->poses_imu, r->poses_features);
    fprintf(f,
            "  \"poses_accepted\": %" PRIu64 ",\n  \"poses_foreign\": %" PRIu64 ",\n  \"poses_non_finite\": %" PRIu64
            ",\n  \"pose_decode_errors\": %" PRIu64 ",\n  \"daemon_restarts\": %" PRIu64
            ",\n  \"calibrations_resent\": %" PRIu64 ",\n",
            r->poses_accepted, r->poses_foreign, r->poses_non_finite, r->pose_decode_errors, r->daemon_restarts,
            r->calib_resent);
    fprintf(f,
            "  \"log_events\": %" PRIu64 ",\n  \"log_damaged\": %" PRIu64 ",\n  \"log_bytes_skipped\": %" PRIu64
            ",\n  \"log_truncated\": %s,\n  \"log_read_failed\": %s,\n",
            r->guard.events, r->guard.damaged, r->guard.bytes_skipped, r->guard.truncated ? "true" : "false",
            r->guard.failed ? "true" : "false");
    fprintf(f,
            "  \"lockstep\": %s,\n  \"frames_expected\": %" PRIu64 ",\n  \"frames_returned\": %" PRIu64
            ",\n  \"frames_missing\": %" PRIu64 ",\n",
            r->opt.lockstep ? "true" : "false", r->expected, r->returned, r->missing);
    fprintf(f,
            "  \"latency_us\": {\"count\": %" PRIu64 ", \"p50\": %" PRId64 ", \"p90\": %" PRId64 ", \"p99\": %" PRId64
            ", \"max\": %" PRId64 ", \"mean\": %.1f},\n",
            vl_latency_count(&r->latency), vl_latency_percentile(&r->latency, 50.0),
            vl_latency_percentile(&r->latency, 90.0), vl_latency_percentile(&r->latency, 99.0),
            vl_latency_max(&r->latency), vl_latency_mean(&r->latency));
    fprintf(f, "  \"wall_s\": %.6f,\n  \"log_s\": %.6f,\n  \"interrupted\": %s\n}\n", wall_s,
            (double)(r->last_log_utime - r->first_log_utime) * 1e-6, interrupted ? "true" : "false");
    const int bad = ferror(f);
    if (fclose(f) != 0 || bad) {
        fprintf(stderr, "vislam-replay: write error on %s\n", r->opt.summary_json);
        return -1;
    }
    return 0;
}

/* ---- main ---- */

int main(int argc, char **argv)
{
    replay_t *r = &g;
    if (parse_args(argc, argv, &r->opt) != 0) {
        return EXIT_USAGE;
    }
    const options_t *o = &r->opt;
    vl_latency_reset(&r->latency);

    lcm_eventlog_t *log = lcm_eventlog_create(o->log_path, "r");
    if (log == NULL) {
        fprintf(stderr, "vislam-replay: cannot read %s: %s\n", o->log_path, strerror(errno));
        return EXIT_USAGE;
    }
    struct stat st;
    const long log_size = stat(o->log_path, &st) == 0 ? (long)st.st_size : -1;
    if (vl_log_guard_init(&r->guard, log->f) != 0) {
        fprintf(stderr, "vislam-replay: cannot seek in %s (the log must be a regular file)\n", o->log_path);
        lcm_eventlog_destroy(log);
        return EXIT_USAGE;
    }
    r->last_sequence = -1;
    if (o->latency_samples != NULL && (r->samples = fopen(o->latency_samples, "w")) == NULL) {
        fprintf(stderr, "vislam-replay: cannot write %s: %s\n", o->latency_samples, strerror(errno));
        lcm_eventlog_destroy(log);
        return EXIT_USAGE;
    }

    if (vl_signal_install() != 0) {
        fprintf(stderr, "vislam-replay: cannot install signal handlers: %s\n", strerror(errno));
    }
    r->lcm = lcm_create(o->lcm_url);
    if (r->lcm == NULL) {
        fprintf(stderr, "vislam-replay: cannot create LCM (url %s)\n", o->lcm_url != NULL ? o->lcm_url : "default");
        lcm_eventlog_destroy(log);
        return EXIT_USAGE;
    }
    /* A udpm:// URL is read on its socket here (vl_lcm_rx), so a pose wakes this thread once. */
    char err[256];
    int rx = 1;
    if (o->lcm_receive_thread) {
        vl_lcm_rx_use_lcm(&r->rx, r->lcm);
    } else {
        rx = vl_lcm_rx_open(&r->rx, o->lcm_url, r->lcm, err, sizeof(err));
    }
    if (rx < 0) {
        fprintf(stderr, "vislam-replay: %s\n", err);
        lcm_destroy(r->lcm);
        lcm_eventlog_destroy(log);
        return EXIT_USAGE;
    }
    r->direct = rx == 0;
    if (vl_lcm_rx_subscribe(&r->rx, o->pose_channel, on_pose, r) != 0 ||
        vl_lcm_rx_subscribe(&r->rx, o->status_channel, on_status, r) != 0) {
        fprintf(stderr, "vislam-replay: cannot subscribe to %s and %s\n", o->pose_channel, o->status_channel);
        lcm_destroy(r->lcm);
        lcm_eventlog_destroy(log);
        return EXIT_USAGE;
    }

    int incomplete = 0;
    if (o->wait_for != NULL) {
        if (vl_lcm_rx_subscribe(&r->rx, o->wait_for, on_wait_for, r) != 0) {
            fprintf(stderr, "vislam-replay: cannot subscribe to %s\n", o->wait_for);
            lcm_destroy(r->lcm);
            lcm_eventlog_destroy(log);
            return EXIT_USAGE;
        }
        const long wait_ms = o->wait_timeout_ms >= 0 ? o->wait_timeout_ms : o->timeout_ms;
        if (!wait_until_flag(r, &r->saw_wait_for, vl_clock_monotonic_us() + wait_ms * 1000)) {
            fprintf(stderr, "vislam-replay: nothing on %s within %ld ms%s\n", o->wait_for, wait_ms,
                    vl_signal_stop_requested() ? " (interrupted)" : "; is the daemon running on this LCM url?");
            lcm_destroy(r->lcm);
            lcm_eventlog_destroy(log);
            return EXIT_INCOMPLETE;
        }
    }

    print_selection(o);
    const int show_progress = !o->quiet && isatty(STDERR_FILENO);
    const int64_t wall_start = vl_clock_monotonic_us();
    int64_t start = 0;  /* monotonic time of the first event */
    int64_t paused = 0; /* us the schedule waited on lockstep */
    int64_t next_progress = wall_start;
    int have_first = 0;
    int consecutive_timeouts = 0;
    lcm_eventlog_event_t *ev;
    while (!vl_signal_stop_requested()) {
        /* liblcm trusts the lengths it reads (an absurd one crashes it): the guard checks first. */
        const vl_log_guard_result_t gr = vl_log_guard_next(&r->guard, log->f);
        if (gr == VL_LOG_GUARD_DAMAGED) {
            if (r->guard.damaged <= REPORTS_MAX) {
                fprintf(stderr, "%svislam-replay: %s: %s\n", show_progress ? "\n" : "", o->log_path, r->guard.error);
            }
            continue;
        }
        if (gr == VL_LOG_GUARD_END) {
            break;
        }
        if ((ev = lcm_eventlog_read_next_event(log)) == NULL) {
            r->guard.failed = 1; /* the file changed under us */
            break;
        }
        r->events_read++;
        if (!channel_selected(o, ev->channel)) {
            r->filtered++;
            count_channel(r->skipped, &r->num_skipped, ev->channel);
            lcm_eventlog_free_event(ev);
            continue;
        }
        if (!have_first) {
            have_first = 1;
            r->first_log_utime = ev->timestamp;
            start = vl_clock_monotonic_us();
        }
        r->last_log_utime = ev->timestamp;
        if (!o->max) {
            const double offset_us = (double)(ev->timestamp - r->first_log_utime) / o->speed;
            const int64_t deadline = start + paused + (int64_t)llround(offset_us);
            poll_incoming(r);
            while (vl_clock_sleep_until_us(deadline) != 0 && !vl_signal_stop_requested()) {
            }
            if (vl_signal_stop_requested()) {
                lcm_eventlog_free_event(ev);
                break;
            }
        }
        /* The latest calibration, re-published every period of log time like a latched message. */
        const int is_calib = strcmp(ev->channel, o->calib_channel) == 0;
        if (is_calib) {
            if (ev->datalen >= 0 && (unsigned)ev->datalen <= sizeof(r->calib_buf)) {
                memcpy(r->calib_buf, ev->data, (size_t)ev->datalen);
                r->calib_len = (unsigned)ev->datalen;
                r->have_calib = 1;
            } else if (!r->calib_too_large) {
                r->calib_too_large = 1;
                fprintf(stderr, "vislam-replay: calibration event of %d bytes is too large to re-publish\n",
                        (int)ev->datalen);
            }
            r->calib_published_log_utime = ev->timestamp;
        } else if (r->have_calib && o->calib_period_ms > 0 &&
                   (ev->timestamp - r->calib_published_log_utime >= o->calib_period_ms * 1000 ||
                    ev->timestamp < r->calib_published_log_utime)) {
            publish_calibration(r);
            r->calib_published_log_utime = ev->timestamp;
        }
        resend_calibration_if_asked(r);
        const int is_frame_channel = strcmp(ev->channel, o->features_channel) == 0;
        const int is_frame = o->lockstep && is_frame_channel;
        int64_t frame_utime = 0;
        if (is_frame_channel) {
            if (vl_log_event_decode(&r->decoder, VL_LOG_EVENT_FRAME, ev->data, ev->datalen, &r->input) !=
                VL_LOG_EVENT_FRAME) {
                if (o->lockstep) {
                    fprintf(stderr,
                            "vislam-replay: event %" PRId64 " on %s is not a vislam.stereo_frame_t; not awaited\n",
                            ev->eventnum, ev->channel);
                }
            } else {
                frame_utime = r->input.frame.utime;
                remember_input(r, frame_utime, VISLAM_POSE_T_SOURCE_FEATURES);
            }
        } else if (strcmp(ev->channel, o->imu_channel) == 0 &&
                   vl_log_event_decode(&r->decoder, VL_LOG_EVENT_IMU, ev->data, ev->datalen, &r->input) ==
                       VL_LOG_EVENT_IMU) {
            remember_input(r, r->input.imu.utime, VISLAM_POSE_T_SOURCE_IMU);
        }
        r->publish_mono_us = vl_clock_monotonic_us();
        r->publish_real_ns = vl_clock_realtime_ns();
        if (is_frame) {
            r->waiting = 1;
            r->matched = 0;
            r->expected_utime = frame_utime;
        }
        if (lcm_publish(r->lcm, ev->channel, ev->data, (unsigned int)ev->datalen) != 0) {
            r->publish_errors++;
        }
        count_sent(r, ev->channel);
        lcm_eventlog_free_event(ev);
        if (is_frame) {
            r->expected++;
            const int64_t t_wait = vl_clock_monotonic_us();
            if (wait_until_flag(r, &r->matched, t_wait + o->timeout_ms * 1000)) {
                r->returned++;
                consecutive_timeouts = 0;
            } else if (!vl_signal_stop_requested()) {
                r->missing++;
                fprintf(stderr, "%svislam-replay: no pose for the frame at utime %" PRId64 " within %ld ms\n",
                        show_progress ? "\n" : "", frame_utime, o->timeout_ms);
                /* A daemon that restarted, or came late, may be waiting for the calibration. */
                r->resend_calib = 1;
                resend_calibration_if_asked(r);
                if (++consecutive_timeouts >= o->max_timeouts && o->max_timeouts > 0) {
                    fprintf(stderr, "vislam-replay: %d timeouts in a row; giving up\n", consecutive_timeouts);
                    incomplete = 1;
                    break;
                }
            }
            r->waiting = 0;
            paused += vl_clock_monotonic_us() - t_wait;
        }
        if (show_progress) {
            const int64_t now = vl_clock_monotonic_us();
            if (now >= next_progress) {
                progress(r, log->f != NULL ? ftell(log->f) : 0, log_size, 0);
                next_progress = now + PROGRESS_PERIOD_US;
            }
        }
    }
    const int interrupted = vl_signal_stop_requested();
    /* Playing time, without the wait for the last poses. */
    const double wall_s = (double)(vl_clock_monotonic_us() - wall_start) * 1e-6;
    /* Poses of the last inputs may still be on their way. */
    int never = 0;
    wait_until_flag(r, &never, vl_clock_monotonic_us() + (interrupted ? 0 : o->linger_ms * 1000));
    poll_incoming(r);
    if (show_progress) {
        progress(r, log_size, log_size, 1);
    }
    if (!o->quiet) {
        print_summary(r, wall_s, interrupted);
    }
    if (o->summary_json != NULL && write_json(r, wall_s, interrupted) != 0) {
        incomplete = 1;
    }
    if (r->samples != NULL && (ferror(r->samples) | fclose(r->samples)) != 0) {
        fprintf(stderr, "vislam-replay: write error on %s\n", o->latency_samples);
        incomplete = 1;
    }
    vl_lcm_rx_close(&r->rx);
    lcm_destroy(r->lcm);
    lcm_eventlog_destroy(log);
    /* Said even with --quiet: a damaged log or someone else's poses must not pass unnoticed. */
    const int damaged = vl_log_guard_damaged(&r->guard) || r->guard.events == 0;
    if (damaged && !interrupted) {
        fprintf(
            stderr, "vislam-replay: %s is damaged: %" PRIu64 " unreadable spot(s) (%" PRIu64 " bytes skipped)%s%s%s\n",
            o->log_path, r->guard.damaged, r->guard.bytes_skipped, r->guard.truncated ? ", cut inside an event" : "",
            r->guard.failed ? ", a read failed" : "", r->guard.events == 0 ? ", no event at all" : "");
    }
    if (r->poses_foreign != 0) {
        fprintf(stderr,
                "vislam-replay: %" PRIu64 " foreign pose(s) on %s (%" PRIu64 " non-finite): not answers to this "
                "replay's inputs\n",
                r->poses_foreign, o->pose_channel, r->poses_non_finite);
    }
    if (damaged && !interrupted) {
        return EXIT_LOG_DAMAGED;
    }
    if (interrupted || r->publish_errors != 0 || r->missing != 0 || r->poses_foreign != 0 || incomplete) {
        return EXIT_INCOMPLETE;
    }
    return 0;
}
