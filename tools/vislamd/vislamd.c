/*
 * vislamd: the estimator as a real-time LCM daemon.
 *
 * Inputs: VISLAM_IMU (vislam.imu_t), VISLAM_FEATURES (vislam.stereo_frame_t),
 * VISLAM_CALIB (vislam.calibration_t). Outputs after every step: VISLAM_POSE
 * (vislam.pose_t) and POSE (bot_core.pose_t); after a step that marginalized
 * landmarks, and at exit for the window's, VISLAM_LANDMARKS (vislam.landmarks_t,
 * the map); VISLAM_STATUS (vislam.status_t) once a second and at exit;
 * optionally a TUM trajectory, one line per frame, the same lines vislam-run
 * writes.
 *
 * Real time: after start-up the message loop does not allocate. Messages are
 * received through lcm_subscribe's raw handler and decoded into static storage
 * (the message types are fixed-size), poses are encoded into static buffers and
 * sent with lcm_publish, and every step is timed with CLOCK_MONOTONIC into
 * fixed-memory histograms (and, with --step-samples, into an array allocated at
 * start-up and written at exit). Memory is locked as the last step of start-up.
 * Whether the loop allocates, LCM included, is measured from outside by a
 * preloaded counter (tests/support/vl_alloc_counter.c); the daemon knows
 * nothing of it.
 *
 * Between the messages and the core sits the session (vl_session): the
 * calibration policy, counters, health bits and core logger that vislam-run
 * uses too, so a lockstep replay gives the same trajectory as the offline run.
 *
 * Under systemd (Type=notify) it reports readiness, feeds the watchdog from this loop while it is
 * healthy, and publishes a status line (vl_notify); run by hand, none of that happens.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <inttypes.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <lcm/lcm.h>

#include "vislam/vislam.h"
#include "vl_awake.h"
#include "vl_bytes.h"
#include "vl_channels.h"
#include "vl_cli.h"
#include "vl_clock.h"
#include "vl_config_file.h"
#include "vl_latency.h"
#include "vl_lcm_rx.h"
#include "vl_log_reader.h"
#include "vl_msg.h"
#include "vl_notify.h"
#include "vl_rt.h"
#include "vl_session.h"
#include "vl_signal.h"
#include "vl_stats_json.h"
#include "vl_trajectory_file.h"
#include "vl_warm.h"

#include "bot_core_pose_t.h"
#include "vislam_calibration_t.h"
#include "vislam_imu_t.h"
#include "vislam_landmarks_t.h"
#include "vislam_pose_t.h"
#include "vislam_status_t.h"
#include "vislam_stereo_frame_t.h"

#define EXIT_RUNTIME 1
#define EXIT_USAGE 2

#define CHANNEL_MAX 64
#define DEFAULT_BUDGET_US 100000
#define STATUS_PERIOD_US 1000000
#define STATUS_LOG_EVERY 10 /* statuses between two status lines on stderr */
#define OVERRUN_LOG_PERIOD_US 1000000
#define INTERVAL_WINDOW 32 /* IMU intervals the automatic budget takes the median of */
#define STACK_PREFAULT_BYTES (256 * 1024)
#define DRAIN_MAX 1000     /* messages already queued that are still processed at shutdown */
#define LCM_ERRORS_MAX 100 /* consecutive receive failures (lcm_handle or the socket) before giving up */
#define RX_BATCH 64        /* datagrams one wake-up of the direct receiver reads at most */
#define BUSY_POLL_MAX_US 1000000
#define ENCODE_BUF 1024
#define MAP_ENCODE_BUF 8192    /* one vislam.landmarks_t batch: 6.2 KB */
#define STEP_SAMPLES_MAX 65536 /* --step-samples: frames kept (3.5 MiB; 1.8 h at 10 Hz), later ones counted */
#define SUPERSEDE_WAIT_US 1000 /* --supersede-imu-poses: how long an IMU pose at a frame's due time waits for it */
#define STEP_SAMPLES_BUF 65536 /* its stdio buffer, given at start-up so that writing it does not allocate */

enum { CH_IMU, CH_FEATURES, CH_CALIB, CH_POSE, CH_BOT_POSE, CH_STATUS, CH_LANDMARKS, CH_COUNT };

static const char *const channel_default[CH_COUNT] = {VL_CHANNEL_IMU,      VL_CHANNEL_FEATURES, VL_CHANNEL_CALIBRATION,
                                                      VL_CHANNEL_POSE,     VL_CHANNEL_BOT_POSE, VL_CHANNEL_STATUS,
                                                      VL_CHANNEL_LANDMARKS};
static const char *const channel_option[CH_COUNT] = {"--imu-channel",      "--features-channel", "--calib-channel",
                                                     "--pose-channel",     "--bot-pose-channel", "--status-channel",
                                                     "--landmarks-channel"};

typedef struct {
    const char *config_path;
    const char *lcm_url;
    const char *trajectory_path;
    const char *step_samples_path;
    const char *stats_json_path;
    const char *prefix;
    const char *channel[CH_COUNT];
    long budget_us;          /* 0: automatic */
    long busy_poll_us;       /* direct receive: spin on the socket this long before sleeping; 0: never */
    int lcm_receive_thread;  /* receive through liblcm's thread and pipe, not on the socket directly */
    int rt_priority;         /* 0: leave the scheduler alone */
    int cpu;                 /* -1: no affinity */
    int cpu_dma_latency_us;  /* PM QoS request held from start-up to exit; -1: none */
    int keep_awake;          /* a SCHED_IDLE spinner on cpu from start-up to exit */
    int supersede_imu_poses; /* an IMU sample's pose is held for a frame of its time or later, dropped when it comes */
    long warm_us;            /* the predictive wake: warm this long before a frame is due; 0: off */
    int no_mlock;
    int quiet;
    int print_config;
    vl_worker_options_t worker;
} options_t;

typedef enum { STEP_PROPAGATE = 0, STEP_UPDATE = 1 } step_kind_t;

/* One frame's step for --step-samples: the session step less its output sink, the code
   vislam-latency's in-process pass times, so that end to end minus this is LCM's share; and
   CLOCK_REALTIME stamps of the frame's way through the daemon, which vislam-latency sets against
   the replay's own (same host, same clock) to say where that share goes. */
typedef struct {
    int64_t utime;      /**< the frame's utime, us (the pose's utime) */
    int64_t ns;         /**< vl_session_input less its publishing (sink_ns), CLOCK_MONOTONIC ns */
    int64_t rx_ns;      /**< the kernel's receive stamp of the frame's datagram (SO_TIMESTAMP, us resolution), ns */
    int64_t free_ns;    /**< the end of the daemon's previous input: the earliest it could take this one, ns */
    int64_t handler_ns; /**< LCM called the frame's handler, ns */
    int64_t step_ns;    /**< decoded: vl_session_input called, ns */
    int64_t sent_ns;    /**< its VISLAM_POSE encoded, lcm_publish called (0: none published), ns */
    int64_t prev_handler_ns; /**< the previous input's handler called, ns */
    int64_t prev_sink_ns;    /**< the previous input's publishing (its sink_ns), CLOCK_MONOTONIC ns */
} step_sample_t;

/* The daemon's own counts; the inputs' are the session's (vl_session_counters). */
typedef struct {
    uint64_t bot_poses_out, status_out, publish_errors;
    uint64_t landmarks_out, landmark_batches_out; /* the map on VISLAM_LANDMARKS */
    /* --supersede-imu-poses: IMU poses not sent (a frame's pose of the same or a later time
       followed), and those held for a frame whose pose did not follow in time, sent late */
    uint64_t imu_poses_superseded, imu_poses_sent_late;
    uint64_t trajectory_errors;
    /* timing */
    uint64_t steps, overruns;
} counts_t;

typedef struct {
    options_t opt;
    char channel[CH_COUNT][CHANNEL_MAX];
    lcm_t *lcm;
    int direct;     /* inputs read from the socket by this thread (vl_lcm_rx), not through liblcm's */
    vl_lcm_rx_t rx; /* the direct receiver */

    vl_config_t cfg;
    vl_config_file_info_t info;
    vl_session_t session;

    counts_t n;

    /* decoding storage: one input event at a time */
    vl_log_decoder_t decoder;
    vl_log_event_t ev;

    /* outputs */
    struct {
        int have;            /* an IMU pose held for the frame of its time */
        int64_t deadline_us; /* CLOCK_MONOTONIC: sent then if no frame came; 0: the frame is already queued */
        int64_t utime;
        uint64_t sequence;
        vl_pose_t pose;
    } held;
    vislam_pose_t pose_msg;
    bot_core_pose_t bot_msg;
    vislam_status_t status_msg;
    uint8_t pose_buf[ENCODE_BUF];
    uint8_t bot_buf[ENCODE_BUF];
    uint8_t status_buf[ENCODE_BUF];
    vislam_landmarks_t map_msg; /* the batch being filled: landmarks the current step marginalized */
    int64_t map_utime;          /* the time of the input being handled (the batch's utime) */
    uint8_t map_buf[MAP_ENCODE_BUF];
    int have_trajectory;
    vl_trajectory_file_t trajectory;

    /* timing */
    vl_latency_t lat_all, lat_step[2];
    vl_latency_t lat_deferred; /**< vl_session_finish after a frame: its work after the pose */
    int64_t budget_us;
    int64_t intervals[INTERVAL_WINDOW];
    unsigned num_intervals, next_interval;
    int64_t prev_imu_utime;
    int have_prev_imu;
    int64_t last_overrun_log_us;
    uint64_t overruns_unlogged;
    uint64_t overruns_at_status; /* "since the last status" for BUDGET_OVERRUN */
    int64_t sink_ns;             /* time publishing (poses, statuses) during the current step, ns */
    int64_t free_ns;             /* CLOCK_REALTIME at the end of the last input handled, ns */
    int64_t last_handler_ns;     /* CLOCK_REALTIME when the last input's handler was called, ns */
    int64_t last_sink_ns;        /* the last input's sink_ns */
    int64_t pose_sent_ns;        /* CLOCK_REALTIME when the current step's VISLAM_POSE went to lcm_publish, ns */
    int64_t handler_mono_us;     /* CLOCK_MONOTONIC when the current input's handler was called, us */
    vl_warm_t warm;              /* --warm-us */
    uint64_t warm_sink;          /* what vl_warm_touch read, kept so that the reads stay */
    vl_awake_t awake;            /* --keep-awake */
    int awake_started;           /* the spinner started (else refused, or not asked for) */
    step_sample_t *step_samples; /* --step-samples: STEP_SAMPLES_MAX, allocated at start-up */
    size_t num_step_samples;
    uint64_t step_samples_dropped;
    FILE *step_samples_file;
    char *step_samples_buf;
    FILE *stats_file; /* --stats-json: opened at start-up, written at exit */

    /* systemd: readiness, watchdog, status line (all no-ops when not run as a Type=notify service) */
    vl_notify_t notify;
    int64_t watchdog_period_us; /* 0: no watchdog */
    int64_t next_watchdog_us;
    char notify_buf[256];
} daemon_t;

/* Several MB (the estimator): static, so it is mapped and locked with the rest at start-up. */
static vl_estimator_t g_est;
static daemon_t g;

/* ---- options ---- */

static void usage(FILE *f)
{
    fprintf(f,
            "usage: vislamd [options]\n"
            "Runs the vislam estimator on LCM messages: subscribes to " VL_CHANNEL_IMU ", " VL_CHANNEL_FEATURES
            " and\n" VL_CHANNEL_CALIBRATION ", publishes " VL_CHANNEL_POSE " and " VL_CHANNEL_BOT_POSE
            " (bot_core.pose_t) after every step,\n" VL_CHANNEL_LANDMARKS
            " (the map: landmarks leaving the window, and the window's at exit) and " VL_CHANNEL_STATUS
            "\nonce a second. Stops on SIGINT or SIGTERM after the current step.\n"
            "\n"
            "  --config FILE           INI configuration on top of the defaults (see tools/vislam.ini);\n"
            "                          its [calibration] is used until the " VL_CHANNEL_CALIBRATION " message arrives\n"
            "                          (or always, with override_log = true)\n"
            "  --lcm-url URL           LCM provider, e.g. udpm://239.255.76.67:7667?ttl=0\n"
            "                          (default: $LCM_DEFAULT_URL, else LCM's default)\n"
            "  --trajectory FILE       TUM trajectory, one line per accepted frame (vislam-run's lines),\n"
            "                          flushed line by line; appended to, never truncated: a restart\n"
            "                          adds a '# ...' comment line and its run after the earlier one\n"
            "  --step-samples FILE     at exit, one line per frame stepped: its utime (us), the step's\n"
            "                          time (ns: vl_session_input less what it publishes), then CLOCK_REALTIME\n"
            "                          ns: kernel receive, previous input done, handler called, step\n"
            "                          started, pose published, previous input's handler called, and its\n"
            "                          publishing (ns); kept in memory for the first %d frames\n"
            "                          (vislam-latency's LCM overhead and its stages)\n"
            "  --stats-json FILE       at exit, the summary as JSON: steps, budget and overruns, step\n"
            "                          latency percentiles, the daemon's, session's and core's counters\n"
            "  --budget-us N           per-step time budget in us (default: the sensor period, the median\n"
            "                          of the last %d IMU intervals; %d us until known)\n"
            "  --rt-priority N         SCHED_FIFO priority 1..99 (a refusal is a warning)\n"
            "  --cpu K                 pin to CPU K (a refusal is a warning)\n"
            "  --cpu-dma-latency US    hold /dev/cpu_dma_latency at US us until exit: no CPU enters an\n"
            "                          idle state slower to leave (system-wide, costs power; a refusal\n"
            "                          is a warning)\n"
            "  --keep-awake            keep --cpu from idling between inputs: a thread pinned there spins at\n"
            "                          SCHED_IDLE (any other thread preempts it) until exit; needs --cpu;\n"
            "                          costs that CPU at 100 %% (a refusal is a warning)\n"
            "  --warm-us N             the predictive wake (0..%d, default 0 = off): sleep until N us before\n"
            "                          the next frame is due (the last one's arrival plus the frame period),\n"
            "                          read the estimator's memory, then poll for it without sleeping until\n"
            "                          it comes or N us after it was due; costs up to 2N us of CPU a frame\n"
            "  --supersede-imu-poses   an IMU sample's pose is held when the next message waiting is a frame\n"
            "                          of the same or a later time, or a frame is due at its time (then up to\n"
            "                          %d us), and not sent when that frame's pose follows: the frame does not\n"
            "                          wait for that publishing. Counted in the exit summary; sent late when\n"
            "                          no frame pose follows in time\n",
            STEP_SAMPLES_MAX, INTERVAL_WINDOW, DEFAULT_BUDGET_US, VL_WARM_MAX_US, SUPERSEDE_WAIT_US);
    fputs(VL_WORKER_USAGE("       "), f);
    fprintf(f,
            "  --no-mlock              do not lock memory (default: mlockall and %d KiB stack pre-fault)\n"
            "  --busy-poll-us N        after each message, spin on the socket up to N us (0..%d) for the\n"
            "                          next before sleeping: trades a CPU for the wake-up (default 0)\n"
            "  --lcm-receive-thread    receive through liblcm's thread, queue and pipe instead of reading\n"
            "                          the multicast socket in the estimation loop (the only way for LCM\n"
            "                          providers other than udpm://)\n"
            "  --channel-prefix P      prefix every channel name below with P\n"
            "  --imu-channel NAME      default " VL_CHANNEL_IMU "\n"
            "  --features-channel NAME default " VL_CHANNEL_FEATURES "\n"
            "  --calib-channel NAME    default " VL_CHANNEL_CALIBRATION "\n"
            "  --pose-channel NAME     default " VL_CHANNEL_POSE "\n"
            "  --bot-pose-channel NAME default " VL_CHANNEL_BOT_POSE "\n"
            "  --status-channel NAME   default " VL_CHANNEL_STATUS "\n"
            "  --landmarks-channel NAME default " VL_CHANNEL_LANDMARKS "\n"
            "  --quiet                 only warnings and errors on stderr (no periodic status line, no\n"
            "                          exit summary)\n"
            "  --print-config          print the effective configuration (INI, as vislam-run) and exit\n"
            "  --version               print the version and exit\n"
            "  --help                  this text\n"
            "\n"
            "As a systemd Type=notify service (NOTIFY_SOCKET set) it reports READY=1 once subscribed,\n"
            "WATCHDOG=1 from the estimation loop every half WATCHDOG_USEC while LCM delivers, a STATUS=\n"
            "line once a second and STOPPING=1 on SIGINT/SIGTERM (the unit: share/vislam/vislamd.service).\n"
            "\n"
            "Exit status: 0 stopped by SIGINT/SIGTERM with every output flushed, 1 run-time failure\n"
            "(LCM, trajectory file), 2 usage or configuration error.\n",
            STACK_PREFAULT_BYTES / 1024, BUSY_POLL_MAX_US);
}

static int parse_long(const char *opt, const char *s, long lo, long hi, long *out)
{
    char *end = NULL;
    errno = 0;
    const long v = strtol(s, &end, 10);
    if (end == s || *end != '\0' || errno != 0 || v < lo || v > hi) {
        fprintf(stderr, "vislamd: %s %s: expected an integer in %ld..%ld\n", opt, s, lo, hi);
        return -1;
    }
    *out = v;
    return 0;
}

static int takes_value(const char *a)
{
    static const char *const names[] = {"--config",         "--lcm-url",         "--trajectory",  "--step-samples",
                                        "--channel-prefix", "--budget-us",       "--rt-priority", "--cpu",
                                        "--busy-poll-us",   "--cpu-dma-latency", "--warm-us",     "--stats-json"};
    for (size_t i = 0; i < sizeof(names) / sizeof(names[0]); ++i) {
        if (strcmp(a, names[i]) == 0) {
            return 1;
        }
    }
    for (int c = 0; c < CH_COUNT; ++c) {
        if (strcmp(a, channel_option[c]) == 0) {
            return 1;
        }
    }
    return 0;
}

static int parse_args(int argc, char **argv, options_t *o)
{
    memset(o, 0, sizeof(*o));
    o->cpu = -1;
    o->cpu_dma_latency_us = -1;
    vl_worker_options_default(&o->worker);
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const int worker_option = vl_worker_parse_option("vislamd", a, i + 1 < argc ? argv[i + 1] : NULL, &o->worker);
        if (worker_option != 0) {
            if (worker_option < 0) {
                return -1;
            }
            ++i;
            continue;
        }
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            exit(0);
        } else if (strcmp(a, "--version") == 0) {
            exit(vl_cli_print_version(stdout, "vislamd") == 0 ? 0 : EXIT_RUNTIME);
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = 1;
            continue;
        } else if (strcmp(a, "--no-mlock") == 0) {
            o->no_mlock = 1;
            continue;
        } else if (strcmp(a, "--lcm-receive-thread") == 0) {
            o->lcm_receive_thread = 1;
            continue;
        } else if (strcmp(a, "--print-config") == 0) {
            o->print_config = 1;
            continue;
        } else if (strcmp(a, "--supersede-imu-poses") == 0) {
            o->supersede_imu_poses = 1;
            continue;
        } else if (strcmp(a, "--keep-awake") == 0) {
            o->keep_awake = 1;
            continue;
        }
        if (a[0] != '-' || a[1] != '-') {
            fprintf(stderr, "vislamd: unexpected argument %s (see --help)\n", a);
            return -1;
        }
        if (!takes_value(a)) {
            fprintf(stderr, "vislamd: unknown option %s (see --help)\n", a);
            return -1;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "vislamd: %s needs a value\n", a);
            return -1;
        }
        const char *v = argv[++i];
        long n = 0;
        int known = 1;
        if (strcmp(a, "--config") == 0) {
            o->config_path = v;
        } else if (strcmp(a, "--lcm-url") == 0) {
            o->lcm_url = v;
        } else if (strcmp(a, "--trajectory") == 0) {
            o->trajectory_path = v;
        } else if (strcmp(a, "--step-samples") == 0) {
            o->step_samples_path = v;
        } else if (strcmp(a, "--stats-json") == 0) {
            o->stats_json_path = v;
        } else if (strcmp(a, "--channel-prefix") == 0) {
            o->prefix = v;
        } else if (strcmp(a, "--budget-us") == 0) {
            if (parse_long(a, v, 1, 1000000000L, &n) != 0) {
                return -1;
            }
            o->budget_us = n;
        } else if (strcmp(a, "--busy-poll-us") == 0) {
            if (parse_long(a, v, 0, BUSY_POLL_MAX_US, &n) != 0) {
                return -1;
            }
            o->busy_poll_us = n;
        } else if (strcmp(a, "--rt-priority") == 0) {
            if (parse_long(a, v, 1, 99, &n) != 0) {
                return -1;
            }
            o->rt_priority = (int)n;
        } else if (strcmp(a, "--cpu") == 0) {
            if (parse_long(a, v, 0, 4095, &n) != 0) {
                return -1;
            }
            o->cpu = (int)n;
        } else if (strcmp(a, "--cpu-dma-latency") == 0) {
            if (parse_long(a, v, 0, 2000000000L, &n) != 0) {
                return -1;
            }
            o->cpu_dma_latency_us = (int)n;
        } else if (strcmp(a, "--warm-us") == 0) {
            if (parse_long(a, v, 0, VL_WARM_MAX_US, &n) != 0) {
                return -1;
            }
            o->warm_us = n;
        } else {
            known = 0;
            for (int c = 0; c < CH_COUNT; ++c) {
                if (strcmp(a, channel_option[c]) == 0) {
                    o->channel[c] = v;
                    known = 1;
                }
            }
        }
        if (!known) {
            fprintf(stderr, "vislamd: unknown option %s (see --help)\n", a);
            return -1;
        }
    }
    if (o->keep_awake && o->cpu < 0) {
        fprintf(stderr, "vislamd: --keep-awake needs --cpu (the CPU to keep awake)\n");
        return -1;
    }
    return 0;
}

static int make_channels(daemon_t *d)
{
    for (int c = 0; c < CH_COUNT; ++c) {
        int n;
        if (d->opt.channel[c] != NULL) {
            n = snprintf(d->channel[c], CHANNEL_MAX, "%s", d->opt.channel[c]);
        } else {
            n = snprintf(d->channel[c], CHANNEL_MAX, "%s%s", d->opt.prefix != NULL ? d->opt.prefix : "",
                         channel_default[c]);
        }
        if (n <= 0 || n >= CHANNEL_MAX) {
            fprintf(stderr, "vislamd: channel name for %s empty or longer than %d characters\n", channel_option[c],
                    CHANNEL_MAX - 1);
            return -1;
        }
    }
    return 0;
}

/* ---- timing ---- */

/* b - a for b > a, saturated: input times are the sender's, INT64_MIN and INT64_MAX included. */
static int64_t utime_after(int64_t a, int64_t b)
{
    const uint64_t d = (uint64_t)b - (uint64_t)a;
    return d > (uint64_t)INT64_MAX ? INT64_MAX : (int64_t)d;
}

/* An IMU sample the core used: its interval to the previous one feeds the automatic budget. */
static void note_imu_interval(daemon_t *d, int64_t utime)
{
    if (d->have_prev_imu && utime > d->prev_imu_utime) {
        d->intervals[d->next_interval] = utime_after(d->prev_imu_utime, utime);
        d->next_interval = (d->next_interval + 1) % INTERVAL_WINDOW;
        if (d->num_intervals < INTERVAL_WINDOW) {
            d->num_intervals++;
        }
        if (d->opt.budget_us == 0) {
            /* Median by insertion sort of a copy: 32 values, cheaper than the step it budgets. */
            int64_t s[INTERVAL_WINDOW];
            const unsigned m = d->num_intervals;
            for (unsigned i = 0; i < m; ++i) {
                int64_t v = d->intervals[i];
                unsigned j = i;
                while (j > 0 && s[j - 1] > v) {
                    s[j] = s[j - 1];
                    --j;
                }
                s[j] = v;
            }
            d->budget_us = s[m / 2];
        }
    }
    d->have_prev_imu = 1;
    d->prev_imu_utime = utime;
}

static void finish_step(daemon_t *d, step_kind_t kind, int64_t t0, int64_t utime)
{
    const int64_t t1 = vl_clock_monotonic_us();
    const int64_t dt = t1 - t0;
    vl_latency_record(&d->lat_all, dt);
    vl_latency_record(&d->lat_step[kind], dt);
    d->n.steps++;
    if (dt <= d->budget_us) {
        return;
    }
    d->n.overruns++;
    d->overruns_unlogged++;
    /* At most one line a second: a slow machine must not also drown in its own log. */
    if (d->last_overrun_log_us == 0 || t1 - d->last_overrun_log_us >= OVERRUN_LOG_PERIOD_US) {
        fprintf(stderr,
                "vislamd: budget overrun: %s at utime %" PRId64 " took %" PRId64 " us > %" PRId64 " us (%" PRIu64
                " overrun(s) since the last message, %" PRIu64 " in all)\n",
                kind == STEP_UPDATE ? "update" : "propagation", utime, dt, d->budget_us, d->overruns_unlogged,
                d->n.overruns);
        d->last_overrun_log_us = t1;
        d->overruns_unlogged = 0;
    }
}

/* ---- outputs ---- */

static void publish(daemon_t *d, int ch, const uint8_t *buf, int len)
{
    if (len < 0 || lcm_publish(d->lcm, d->channel[ch], buf, (unsigned int)len) != 0) {
        d->n.publish_errors++;
    }
}

static int32_t clamp32(int64_t v)
{
    return v > INT32_MAX ? INT32_MAX : (v < INT32_MIN ? INT32_MIN : (int32_t)v);
}

/* The session's fields, then the daemon's: wall-clock stamp, budget, latencies. */
static void publish_status(daemon_t *d)
{
    vislam_status_t *s = &d->status_msg;
    vl_session_fill_status(&d->session, s);
    s->utime = vl_clock_realtime_us();
    if (d->n.overruns != d->overruns_at_status) {
        s->health |= VISLAM_STATUS_T_HEALTH_BUDGET_OVERRUN;
    }
    s->budget_us = d->budget_us;
    s->budget_overruns = (int64_t)d->n.overruns;
    s->steps = (int64_t)d->n.steps;
    s->latency_p50_us = clamp32(vl_latency_percentile(&d->lat_all, 50.0));
    s->latency_p99_us = clamp32(vl_latency_percentile(&d->lat_all, 99.0));
    s->latency_p999_us = clamp32(vl_latency_percentile(&d->lat_all, 99.9));
    s->latency_max_us = clamp32(vl_latency_max(&d->lat_all));
    const int len = vislam_status_t_encode(d->status_buf, 0, (int)sizeof(d->status_buf), s);
    publish(d, CH_STATUS, d->status_buf, len);
    d->n.status_out++;
    d->overruns_at_status = d->n.overruns;
    vl_session_mark(&d->session);
}

/* The pose on VISLAM_POSE and POSE, stamped with the input's time; frames also to the TUM file. */
static void publish_pose(daemon_t *d, vl_session_step_t step, int64_t utime, uint64_t sequence, const vl_pose_t *pose)
{
    const int8_t source = step == VL_SESSION_STEP_UPDATE ? VISLAM_POSE_T_SOURCE_FEATURES : VISLAM_POSE_T_SOURCE_IMU;
    vl_msg_from_pose(pose, source, (int64_t)sequence, &d->pose_msg);
    d->pose_msg.utime = utime;
    int len = vislam_pose_t_encode(d->pose_buf, 0, (int)sizeof(d->pose_buf), &d->pose_msg);
    d->pose_sent_ns = vl_clock_realtime_ns();
    publish(d, CH_POSE, d->pose_buf, len);
    vl_msg_from_pose_bot(pose, &d->bot_msg);
    d->bot_msg.utime = utime;
    len = bot_core_pose_t_encode(d->bot_buf, 0, (int)sizeof(d->bot_buf), &d->bot_msg);
    publish(d, CH_BOT_POSE, d->bot_buf, len);
    d->n.bot_poses_out++;
    if (step == VL_SESSION_STEP_UPDATE && d->have_trajectory && vl_trajectory_write(&d->trajectory, utime, pose) != 0) {
        if (d->n.trajectory_errors++ == 0) {
            fprintf(stderr, "vislamd: error: write to the trajectory %s failed\n", d->opt.trajectory_path);
        }
    }
}

/* --supersede-imu-poses: 1 when the next message waiting on the socket is a frame of time
   utime or later (its utime, the first field after LCM's 8-byte type fingerprint). */
static int frame_waiting(daemon_t *d, int64_t utime)
{
    vl_lcm_rx_peek_t next;
    return vl_lcm_rx_peek(&d->rx, &next) == 1 && strcmp(next.channel, d->channel[CH_FEATURES]) == 0 &&
           next.size >= 16 && vl_be64(next.payload + 8) >= utime;
}

/* The held IMU pose, sent after all: its frame gave no pose, did not come in time, or another pose came first. */
static void publish_held(daemon_t *d)
{
    d->held.have = 0;
    d->n.imu_poses_sent_late++;
    publish_pose(d, VL_SESSION_STEP_PROPAGATE, d->held.utime, d->held.sequence, &d->held.pose);
}

/* The batch of landmarks on VISLAM_LANDMARKS, numbered, then emptied (entries past count stay zero). */
static void publish_map(daemon_t *d)
{
    vislam_landmarks_t *m = &d->map_msg;
    if (m->count == 0) {
        return;
    }
    m->utime = d->map_utime;
    m->sequence = (int64_t)d->n.landmark_batches_out;
    m->first_index = (int64_t)d->n.landmarks_out;
    const int len = vislam_landmarks_t_encode(d->map_buf, 0, (int)sizeof(d->map_buf), m);
    publish(d, CH_LANDMARKS, d->map_buf, len);
    d->n.landmark_batches_out++;
    d->n.landmarks_out += (uint64_t)m->count;
    memset(m, 0, sizeof(*m));
}

/*
 * Session sink: publish_pose, timed so that the step's own time can leave it out. With
 * --supersede-imu-poses an IMU pose is held when a frame of the same or a later time waits behind
 * its sample on the socket, or when a frame is due at its time (vl_warm_frame_due: the sample
 * came first, its frame is on the way) for up to SUPERSEDE_WAIT_US; it is dropped (counted) when
 * that frame's pose comes: the frame's pose is the estimate at that time with the frame's
 * information too, and the frame need not wait for two sends. Any other pose first, no pose from
 * the next input, or no frame in time, and the held one is sent (counted as late), so no pose is
 * lost without a newer one in its place and the sequence numbers on the wire still increase.
 */
static void on_pose(void *user, vl_session_step_t step, int64_t utime, uint64_t sequence, const vl_pose_t *pose)
{
    daemon_t *d = (daemon_t *)user;
    const int64_t t0 = vl_clock_monotonic_ns();
    if (d->held.have) {
        if (step == VL_SESSION_STEP_UPDATE && utime >= d->held.utime) {
            d->held.have = 0;
            d->n.imu_poses_superseded++;
        } else {
            publish_held(d);
        }
    }
    const int imu_pose = step == VL_SESSION_STEP_PROPAGATE && d->opt.supersede_imu_poses;
    const int queued = imu_pose && frame_waiting(d, utime);
    if (queued || (imu_pose && vl_warm_frame_due(&d->warm, utime))) {
        d->held.have = 1;
        d->held.deadline_us = queued ? 0 : vl_clock_monotonic_us() + SUPERSEDE_WAIT_US;
        d->held.utime = utime;
        d->held.sequence = sequence;
        d->held.pose = *pose;
    } else {
        publish_pose(d, step, utime, sequence, pose);
    }
    d->sink_ns += vl_clock_monotonic_ns() - t0;
}

/*
 * Session sink for the map: each landmark leaving the window joins the batch that goes out after
 * the step's pose (handle_input), or at once when the batch is full. Timed as an output.
 */
static void on_landmark(void *user, const vl_landmark_t *landmark)
{
    daemon_t *d = (daemon_t *)user;
    const int64_t t0 = vl_clock_monotonic_ns();
    /* The world it is in: the re-initializations so far (a reset later in this step starts another). */
    const int64_t world = (int64_t)vl_session_core_counters(&d->session)->resets;
    if ((d->map_msg.count > 0 && d->map_msg.world != world) || d->map_msg.count == VISLAM_LANDMARKS_T_MAX_LANDMARKS) {
        publish_map(d); /* a batch holds one world, and at most MAX_LANDMARKS */
    }
    d->map_msg.world = world;
    vl_msg_add_landmark(landmark, &d->map_msg);
    d->sink_ns += vl_clock_monotonic_ns() - t0;
}

/*
 * Session event. A re-initialization is an immediate status with TIMELINE_CHANGE
 * or DIVERGENCE_RESET set, so a listener need not wait for the periodic one;
 * intervals of the old timeline no longer say anything about the sensor period.
 */
static void on_event(void *user, vl_session_event_t event, int64_t utime)
{
    daemon_t *d = (daemon_t *)user;
    (void)utime;
    if (event == VL_SESSION_EVENT_REINITIALIZED) {
        d->have_prev_imu = 0;
        const int64_t t0 = vl_clock_monotonic_ns();
        publish_status(d);
        d->sink_ns += vl_clock_monotonic_ns() - t0; /* an output, not the step (see on_pose) */
    } else if (event == VL_SESSION_EVENT_CALIBRATED && !d->opt.quiet) {
        fprintf(stderr, "vislamd: calibration received; estimating\n");
    }
}

static void print_status_line(const daemon_t *d)
{
    const vislam_status_t *s = &d->status_msg;
    fprintf(stderr,
            "vislamd: status: imu %" PRId64 " frames %" PRId64 " poses %" PRId64 " rejected %" PRId64
            " window %d/%d steps %" PRId64 " p50 %d p99 %d max %d us overruns %" PRId64 " (budget %" PRId64
            " us) health 0x%x",
            s->imu_in, s->frames_in, s->poses_out, s->inputs_rejected, (int)s->window_landmarks,
            (int)s->window_capacity, s->steps, (int)s->latency_p50_us, (int)s->latency_p99_us, (int)s->latency_max_us,
            s->budget_overruns, s->budget_us, (unsigned)s->health);
    fputc('\n', stderr);
}

/* ---- systemd notification (vl_notify: nothing happens without NOTIFY_SOCKET) ---- */

static const char *tracking_state(const daemon_t *d)
{
    const int32_t health = d->status_msg.health;
    if (health & VISLAM_STATUS_T_HEALTH_WAITING_CALIBRATION) {
        return "waiting for a calibration";
    }
    return (health & VISLAM_STATUS_T_HEALTH_NOT_TRACKING) ? "not tracking" : "tracking";
}

/* STATUS=, after each periodic status: the state and the counts an operator looks at first
   (`systemctl status vislamd`). Integers only: formatting them does not allocate. */
static void notify_status(daemon_t *d)
{
    if (!vl_notify_active(&d->notify)) {
        return;
    }
    const vislam_status_t *s = &d->status_msg;
    snprintf(d->notify_buf, sizeof(d->notify_buf),
             "STATUS=%s: imu %" PRId64 " frames %" PRId64 " poses %" PRId64 " rejected %" PRId64
             " window %d/%d p99 %d us overruns %" PRId64 " health 0x%x",
             tracking_state(d), s->imu_in, s->frames_in, s->poses_out, s->inputs_rejected, (int)s->window_landmarks,
             (int)s->window_capacity, (int)s->latency_p99_us, s->budget_overruns, (unsigned)s->health);
    vl_notify_send(&d->notify, d->notify_buf);
}

/*
 * WATCHDOG=1 every half watchdog period, sent from the loop that steps the estimator and only
 * while it is healthy (the last read of its inputs succeeded): a step that hangs, or a receive side
 * that keeps failing, stops the pings and systemd restarts the daemon. Budget overruns do not
 * count: a slow step is reported in the status, a stuck one is what the watchdog is for.
 */
static void feed_watchdog(daemon_t *d, int64_t now, int healthy)
{
    if (d->watchdog_period_us <= 0 || now < d->next_watchdog_us) {
        return;
    }
    if (healthy) {
        vl_notify_send(&d->notify, "WATCHDOG=1");
    }
    d->next_watchdog_us = now + d->watchdog_period_us;
}

/* ---- LCM handlers: decode (vl_log_event_decode), then one session step, timed ---- */

static void keep_step_sample(daemon_t *d, const step_sample_t *s)
{
    if (d->num_step_samples == STEP_SAMPLES_MAX) {
        d->step_samples_dropped++;
        return;
    }
    d->step_samples[d->num_step_samples++] = *s;
}

static void handle_input(daemon_t *d, vl_log_event_kind_t kind, const lcm_recv_buf_t *rbuf, const char *channel)
{
    step_sample_t sample;
    const int held_before = d->held.have;
    const uint64_t held_sequence = d->held.sequence;
    d->handler_mono_us = vl_clock_monotonic_us();
    sample.handler_ns = vl_clock_realtime_ns();
    sample.free_ns = d->free_ns;
    sample.prev_handler_ns = d->last_handler_ns;
    sample.prev_sink_ns = d->last_sink_ns;
    sample.rx_ns = rbuf->recv_utime * 1000;
    const int64_t t0 = vl_clock_monotonic_us();
    vl_log_event_t *ev = &d->ev;
    /* The channel names the event in a decode error; the LCM name is at most CHANNEL_MAX - 1 bytes. */
    snprintf(ev->channel, sizeof(ev->channel), "%s", channel);
    ev->event_number = 0;
    ev->log_utime = rbuf->recv_utime;
    vl_log_event_decode(&d->decoder, kind, rbuf->data, (int)rbuf->data_size, ev);
    d->map_utime =
        kind == VL_LOG_EVENT_FRAME ? ev->frame.utime : (kind == VL_LOG_EVENT_IMU ? ev->imu.utime : d->map_utime);
    vl_status_t status = VL_OK;
    d->sink_ns = 0;
    d->pose_sent_ns = 0;
    sample.step_ns = vl_clock_realtime_ns();
    const int64_t s0 = vl_clock_monotonic_ns();
    const vl_session_step_t step = vl_session_input(&d->session, ev, &status);
    const int64_t step_ns = vl_clock_monotonic_ns() - s0 - d->sink_ns;
    if (held_before && d->held.have && d->held.sequence == held_sequence) {
        publish_held(d); /* the input behind the held pose gave no pose (a pose it held itself stays) */
    }
    d->last_handler_ns = sample.handler_ns;
    d->last_sink_ns = d->sink_ns;
    if (step == VL_SESSION_STEP_NONE) {
        d->free_ns = vl_clock_realtime_ns();
        return;
    }
    const int64_t utime = step == VL_SESSION_STEP_UPDATE ? ev->frame.utime : ev->imu.utime;
    if (step == VL_SESSION_STEP_UPDATE && d->step_samples != NULL) {
        sample.utime = utime;
        sample.ns = step_ns;
        sample.sent_ns = d->pose_sent_ns;
        keep_step_sample(d, &sample);
    }
    if (step == VL_SESSION_STEP_PROPAGATE && status >= 0) {
        note_imu_interval(d, utime);
    }
    if (step == VL_SESSION_STEP_UPDATE && status >= 0) {
        vl_warm_note_frame(&d->warm, utime, d->handler_mono_us);
    }
    finish_step(d, step == VL_SESSION_STEP_UPDATE ? STEP_UPDATE : STEP_PROPAGATE, t0, utime);
    if (vl_deferred_due(vl_session_estimator(&d->session))) {
        /* The frame's work that does not move the pose (the landmarks' downdate, the window's
         * upkeep, what the update's time bound left out), done now that the pose is out. */
        const int64_t f0 = vl_clock_monotonic_us();
        (void)vl_session_finish(&d->session);
        vl_latency_record(&d->lat_deferred, vl_clock_monotonic_us() - f0);
    }
    publish_map(d); /* after the pose and outside the step's time: the map is not what waits on it */
    d->free_ns = vl_clock_realtime_ns();
}

static void on_calibration_msg(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    handle_input((daemon_t *)user, VL_LOG_EVENT_CALIBRATION, rbuf, channel);
}

static void on_imu_msg(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    handle_input((daemon_t *)user, VL_LOG_EVENT_IMU, rbuf, channel);
}

static void on_features_msg(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    handle_input((daemon_t *)user, VL_LOG_EVENT_FRAME, rbuf, channel);
}

/* Start-up only: a message of the daemon's own (its first status, the self test), back through the
   multicast loopback. */
static void on_own_status(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    (void)rbuf;
    (void)channel;
    *(int *)user = 1;
}

/*
 * The inputs' subscriptions. A udpm:// URL is read directly (vl_lcm_rx: the estimation loop waits
 * on the multicast socket itself, one wake-up per message); any other provider, or
 * --lcm-receive-thread, through liblcm's receive thread. The descriptor to wait on, or -1.
 */
static int open_receive(daemon_t *d)
{
    char err[256];
    int rc = 1;
    if (d->opt.lcm_receive_thread) {
        vl_lcm_rx_use_lcm(&d->rx, d->lcm);
    } else {
        rc = vl_lcm_rx_open(&d->rx, d->opt.lcm_url, d->lcm, err, sizeof(err));
    }
    if (rc < 0) {
        fprintf(stderr, "vislamd: %s\n", err);
        return -1;
    }
    d->direct = rc == 0;
    if (!d->direct && d->opt.busy_poll_us > 0) {
        fprintf(stderr, "vislamd: warning: --busy-poll-us needs the direct receiver (a udpm:// URL without "
                        "--lcm-receive-thread); not polling\n");
        d->opt.busy_poll_us = 0;
    }
    if (!d->direct && d->opt.warm_us > 0) {
        /* Spinning at the loop's priority would starve liblcm's receive thread on the same CPU. */
        fprintf(stderr, "vislamd: warning: --warm-us needs the direct receiver (a udpm:// URL without "
                        "--lcm-receive-thread); not warming\n");
        d->opt.warm_us = 0;
        vl_warm_init(&d->warm, 0);
    }
    if (vl_lcm_rx_subscribe(&d->rx, d->channel[CH_CALIB], on_calibration_msg, d) != 0 ||
        vl_lcm_rx_subscribe(&d->rx, d->channel[CH_IMU], on_imu_msg, d) != 0 ||
        vl_lcm_rx_subscribe(&d->rx, d->channel[CH_FEATURES], on_features_msg, d) != 0) {
        fprintf(stderr, "vislamd: cannot subscribe\n");
        vl_lcm_rx_close(&d->rx);
        return -1;
    }
    const int fd = vl_lcm_rx_fd(&d->rx);
    if (fd < 0) {
        fprintf(stderr, "vislamd: LCM has no file descriptor to wait on\n");
    }
    return fd;
}

/* What arrived, handled: 0, or -1 when the receive side failed. */
static int receive(daemon_t *d)
{
    return vl_lcm_rx_poll(&d->rx, RX_BATCH) < 0 ? -1 : 0;
}

/*
 * --busy-poll-us and --warm-us: reads the socket without sleeping until a message is handled or
 * until_us (CLOCK_MONOTONIC) passes; 1 when something was handled. SIGINT and SIGTERM stay blocked
 * while it spins, so a pending one ends the spin and the loop's wait takes it. *spun_us (may be
 * NULL): the time spent polling, up to the last poll that found nothing.
 */
static int busy_poll(daemon_t *d, int64_t until_us, int64_t *spun_us)
{
    sigset_t pending;
    const int64_t start = vl_clock_monotonic_us();
    int64_t last_empty = start;
    int got = 0;
    for (;;) {
        if (sigpending(&pending) == 0 && (sigismember(&pending, SIGINT) == 1 || sigismember(&pending, SIGTERM) == 1)) {
            break;
        }
        const int n = vl_lcm_rx_poll(&d->rx, RX_BATCH);
        if (n != 0) {
            got = n > 0;
            break;
        }
        last_empty = vl_clock_monotonic_us();
        if (last_empty >= until_us) {
            break;
        }
    }
    if (spun_us != NULL) {
        *spun_us = last_empty - start;
    }
    return got;
}

/*
 * --warm-us: in the window around the next frame's due time, the estimator's memory read once and
 * the socket polled without sleeping (up to until_us); outside it, *wake_us brought forward to the
 * window's start. 1 when a message was handled while polling.
 */
static int warm_for_frame(daemon_t *d, int64_t now, int64_t *wake_us)
{
    int64_t from = 0, until = 0;
    if (!d->direct || !vl_warm_window(&d->warm, now, &from, &until)) {
        return 0;
    }
    if (now < from) {
        if (from < *wake_us) {
            *wake_us = from;
        }
        return 0;
    }
    if (d->warm.warmed_for != from) {
        d->warm.warmed_for = from;
        d->warm.windows++;
        const int64_t t0 = vl_clock_monotonic_us();
        d->warm_sink += vl_warm_touch(&g_est, sizeof(g_est));
        d->warm.touch_us += (uint64_t)(vl_clock_monotonic_us() - t0);
    }
    int64_t spun = 0;
    const int got = busy_poll(d, until < *wake_us ? until : *wake_us, &spun);
    d->warm.spin_us += (uint64_t)spun;
    d->warm.inputs_in_spin += (uint64_t)got;
    return got;
}

/*
 * The start-up check, as liblcm's own self test: a message of vislamd's own, published and read
 * back through the multicast loopback (up to 200 ms). It also moves LCM's lazy set-up before
 * memory is locked: the first publish and, through liblcm's receive thread, the main thread's
 * first lcm_handle (a GLib mutex) and that thread's match of the channel against every
 * subscription's regex (GLib/PCRE2), cached per channel name; what that thread allocates for
 * other channel names stays (see the README's measurement). Read directly, the message goes on
 * LCM's self-test channel and the first status only after mlockall; through liblcm's thread the
 * message is that first status. No answer is only a warning: the inputs may come from another host.
 */
static void check_loopback(daemon_t *d)
{
    static const char self_test[] = "LCM_SELF_TEST";
    static const char text[] = "vislamd self test";
    const char *channel = d->direct ? self_test : d->channel[CH_STATUS];
    int seen = 0;
    const int subscribed = vl_lcm_rx_subscribe(&d->rx, channel, on_own_status, &seen) == 0;
    if (d->direct) {
        lcm_publish(d->lcm, channel, text, (unsigned)sizeof(text));
    } else {
        publish_status(d); /* "I am up" */
    }
    const int64_t deadline = vl_clock_monotonic_us() + 200000;
    while (subscribed && !seen) {
        const int64_t left = deadline - vl_clock_monotonic_us();
        if (left <= 0 || vl_signal_wait_fd(vl_lcm_rx_fd(&d->rx), left) <= 0) {
            fprintf(stderr, "vislamd: warning: its own message did not come back through %s in 200 ms\n",
                    d->opt.lcm_url != NULL ? d->opt.lcm_url : "the default LCM url");
            break;
        }
        vl_lcm_rx_poll(&d->rx, RX_BATCH);
    }
    if (subscribed) {
        vl_lcm_rx_unsubscribe(&d->rx, channel, on_own_status);
    }
}

/* ---- start-up ---- */

static int load_config(daemon_t *d)
{
    vl_config_default(&d->cfg);
    memset(&d->info, 0, sizeof(d->info));
    d->info.preset = VL_PRESET_NONE;
    if (d->opt.config_path != NULL) {
        char err[512];
        if (vl_config_load_ini_ex(d->opt.config_path, &d->cfg, &d->info, err, sizeof(err)) != VL_OK) {
            fprintf(stderr, "vislamd: %s\n", err);
            return -1;
        }
    }
    return 0;
}

/* The PM QoS request's descriptor (-1: none): held open until exit. */
static int g_cpu_latency_fd = -1;

static void realtime_setup(const options_t *o)
{
    char msg[256];
    if (o->cpu_dma_latency_us >= 0) {
        const vl_rt_status_t s = vl_rt_request_cpu_latency(o->cpu_dma_latency_us, &g_cpu_latency_fd, msg, sizeof(msg));
        if (s != VL_RT_OK || !o->quiet) {
            fprintf(stderr, "vislamd: %s%s\n", s != VL_RT_OK ? "warning: " : "", msg);
        }
    }
    if (o->cpu >= 0) {
        const vl_rt_status_t s = vl_rt_set_affinity(o->cpu, msg, sizeof(msg));
        if (s != VL_RT_OK || !o->quiet) {
            fprintf(stderr, "vislamd: %s%s\n", s != VL_RT_OK ? "warning: " : "", msg);
        }
    }
    if (o->rt_priority > 0) {
        const vl_rt_status_t s = vl_rt_set_fifo(o->rt_priority, msg, sizeof(msg));
        if (s != VL_RT_OK || !o->quiet) {
            fprintf(stderr, "vislamd: %s%s\n", s != VL_RT_OK ? "warning: " : "", msg);
        }
    }
}

/*
 * The last step of start-up: LCM, the estimator, the buffers and the stack are
 * mapped by now, so MCL_CURRENT locks what the loop touches (MCL_FUTURE the rest).
 * Scheduling comes first (realtime_setup) so LCM's thread inherits it.
 */
static void lock_memory(const options_t *o)
{
    char msg[256];
    if (!o->no_mlock) {
        const vl_rt_status_t s = vl_rt_lock_memory(msg, sizeof(msg));
        if (s != VL_RT_OK || !o->quiet) {
            fprintf(stderr, "vislamd: %s%s\n", s != VL_RT_OK ? "warning: " : "", msg);
        }
        vl_rt_prefault_stack(STACK_PREFAULT_BYTES, msg, sizeof(msg));
        if (!o->quiet) {
            fprintf(stderr, "vislamd: %s\n", msg);
        }
    }
}

/* Runs every output path once before the loop, so first-use costs (and lazy allocations) happen here. */
static int warm_up(daemon_t *d)
{
    vl_pose_t p;
    memset(&p, 0, sizeof(p));
    vl_msg_from_pose(&p, VISLAM_POSE_T_SOURCE_IMU, 0, &d->pose_msg);
    vl_msg_from_pose_bot(&p, &d->bot_msg);
    memset(&d->status_msg, 0, sizeof(d->status_msg));
    memset(&d->map_msg, 0, sizeof(d->map_msg));
    if (vislam_pose_t_encoded_size(&d->pose_msg) > ENCODE_BUF ||
        bot_core_pose_t_encoded_size(&d->bot_msg) > ENCODE_BUF ||
        vislam_status_t_encoded_size(&d->status_msg) > ENCODE_BUF ||
        vislam_landmarks_t_encoded_size(&d->map_msg) > MAP_ENCODE_BUF ||
        vislam_landmarks_t_encode(d->map_buf, 0, MAP_ENCODE_BUF, &d->map_msg) < 0) {
        fprintf(stderr, "vislamd: internal error: an encoded message exceeds its buffer\n");
        return -1;
    }
    char line[VL_TRAJECTORY_LINE_MAX];
    p.rotation[0] = p.rotation[4] = p.rotation[8] = 1.0;
    vl_trajectory_format_line(line, sizeof(line), 0, &p);
    return 0;
}

/* --step-samples at start-up: the file opened (an unwritable path fails now, not at exit), its
   stdio buffer and the samples allocated, so that neither the loop nor the final write allocates. */
static int open_step_samples(daemon_t *d)
{
    d->step_samples = (step_sample_t *)calloc(STEP_SAMPLES_MAX, sizeof(step_sample_t));
    d->step_samples_buf = (char *)malloc(STEP_SAMPLES_BUF);
    d->step_samples_file = fopen(d->opt.step_samples_path, "w");
    if (d->step_samples == NULL || d->step_samples_buf == NULL || d->step_samples_file == NULL ||
        setvbuf(d->step_samples_file, d->step_samples_buf, _IOFBF, STEP_SAMPLES_BUF) != 0) {
        fprintf(stderr, "vislamd: cannot write %s: %s\n", d->opt.step_samples_path, strerror(errno));
        return -1;
    }
    return 0;
}

/* At exit: the kept samples, "utime ns" and the stamps (step_sample_t's order) a line; 0, or -1 on
   a write error. */
static int write_step_samples(daemon_t *d)
{
    FILE *f = d->step_samples_file;
    for (size_t i = 0; i < d->num_step_samples; ++i) {
        const step_sample_t *s = &d->step_samples[i];
        fprintf(f,
                "%" PRId64 " %" PRId64 " %" PRId64 " %" PRId64 " %" PRId64 " %" PRId64 " %" PRId64 " %" PRId64
                " %" PRId64 "\n",
                s->utime, s->ns, s->rx_ns, s->free_ns, s->handler_ns, s->step_ns, s->sent_ns, s->prev_handler_ns,
                s->prev_sink_ns);
    }
    if (d->step_samples_dropped > 0) {
        fprintf(stderr, "vislamd: %s: the first %d frames kept, %" PRIu64 " later ones not\n", d->opt.step_samples_path,
                STEP_SAMPLES_MAX, d->step_samples_dropped);
    }
    const int bad = ferror(f);
    const int closed = fclose(f);
    d->step_samples_file = NULL;
    free(d->step_samples_buf);
    free(d->step_samples);
    if (closed != 0 || bad) {
        fprintf(stderr, "vislamd: error: write error on %s\n", d->opt.step_samples_path);
        return -1;
    }
    return 0;
}

/* --stats-json at start-up: the file opened (an unwritable path fails now, not at exit) with a
   static stdio buffer, so that the write at exit does not allocate. */
static int open_stats(daemon_t *d)
{
    static char buf[16384];
    d->stats_file = fopen(d->opt.stats_json_path, "w");
    if (d->stats_file == NULL || setvbuf(d->stats_file, buf, _IOFBF, sizeof(buf)) != 0) {
        fprintf(stderr, "vislamd: cannot write %s: %s\n", d->opt.stats_json_path, strerror(errno));
        return -1;
    }
    return 0;
}

/* At exit: what print_summary says, as JSON for programs (tools/bench.sh); 0, or -1 on a write error. */
static int write_stats(daemon_t *d)
{
    FILE *f = d->stats_file;
    const vl_session_t *ss = &d->session;
    const int sig = vl_signal_last();
    fprintf(f, "{\n  \"program\": \"vislamd\",\n  \"stopped_by\": \"%s\",\n  \"calibration_source\": ",
            sig == SIGINT ? "SIGINT" : (sig == SIGTERM ? "SIGTERM" : "error"));
    vl_json_string(f, vl_session_calibration_source(ss));
    fprintf(f,
            ",\n  \"health\": %d,\n  \"steps\": %" PRIu64 ",\n  \"budget_us\": %" PRId64
            ",\n  \"budget_source\": \"%s\",\n  \"overruns\": %" PRIu64 ",\n",
            (int)vl_session_health(ss), d->n.steps, d->budget_us,
            d->opt.budget_us > 0 ? "--budget-us" : "sensor_period", d->n.overruns);
    fprintf(f, "  \"step_latency\": {\n");
    vl_json_latency(f, "    ", "all", &d->lat_all, 0);
    vl_json_latency(f, "    ", "propagation", &d->lat_step[STEP_PROPAGATE], 0);
    vl_json_latency(f, "    ", "update", &d->lat_step[STEP_UPDATE], 0);
    vl_json_latency(f, "    ", "deferred", &d->lat_deferred, 1);
    const vl_counter_entry_t out[] = {
        {"bot_poses_out", d->n.bot_poses_out, "bot_core.pose_t messages published"},
        {"status_out", d->n.status_out, "VISLAM_STATUS messages published"},
        {"publish_errors", d->n.publish_errors, "lcm_publish calls that failed"},
        {"landmarks_out", d->n.landmarks_out, "landmarks published on the map channel"},
        {"landmark_batches_out", d->n.landmark_batches_out, "map messages published"},
        {"imu_poses_superseded", d->n.imu_poses_superseded,
         "IMU poses not sent: a frame's pose of the same or a later time followed"},
        {"imu_poses_sent_late", d->n.imu_poses_sent_late,
         "IMU poses held for a frame whose pose did not follow in time, sent late"},
        {"trajectory_lines", d->have_trajectory ? vl_trajectory_lines(&d->trajectory) : 0, "TUM lines written"},
        {"trajectory_errors", d->n.trajectory_errors, "TUM lines that failed to write"},
        {"lcm_rx_messages", d->rx.messages, "messages the direct receiver handed to a handler"},
        {"lcm_rx_other_channels", d->rx.other, "well-formed messages on channels vislamd does not read"},
        {"lcm_rx_fragments_dropped", d->rx.fragments, "datagrams of fragmented (large) messages, dropped"},
        {"lcm_rx_malformed", d->rx.malformed, "datagrams that were not LCM messages"},
    };
    fprintf(f, "  },\n  \"daemon\": {\n");
    vl_json_counts(f, "    ", out, sizeof(out) / sizeof(out[0]));
    vl_counter_entry_t session[VL_SESSION_NUM_COUNTERS], core[VL_NUM_COUNTERS];
    fprintf(f, "  },\n  \"session\": {\n");
    vl_json_counts(f, "    ", session, vl_session_counter_list(ss, session));
    fprintf(f, "  },\n  \"core_counters\": {\n");
    vl_json_counts(f, "    ", core, vl_counters_list(vl_session_core_counters(ss), core));
    fprintf(f, "  },\n");
    vl_json_core_status(f, "  ", ss);
    fprintf(f, "\n}\n");
    const int bad = ferror(f);
    const int closed = fclose(f);
    d->stats_file = NULL;
    if (closed != 0 || bad) {
        fprintf(stderr, "vislamd: error: write error on %s\n", d->opt.stats_json_path);
        return -1;
    }
    return 0;
}

static void print_summary(const daemon_t *d)
{
    const vl_session_t *ss = &d->session;
    const vl_session_counters_t *n = vl_session_counters(ss);
    const vl_counters_t *c = vl_session_core_counters(ss);
    const vl_estimator_t *est = vl_session_estimator(ss);
    fprintf(stderr, "vislamd: stopped (%s); calibration from %s\n",
            vl_signal_last() == SIGINT ? "SIGINT" : (vl_signal_last() == SIGTERM ? "SIGTERM" : "error"),
            vl_session_calibration_source(ss));
    fprintf(stderr,
            "  in: imu %" PRIu64 " frames %" PRIu64 " calibrations %" PRIu64 "; out: poses %" PRIu64 " (+%" PRIu64
            " on %s), statuses %" PRIu64 ", trajectory lines %" PRIu64 "\n",
            n->imu_in, n->frames_in, n->calibrations_in, n->poses_out, d->n.bot_poses_out, d->channel[CH_BOT_POSE],
            d->n.status_out, d->have_trajectory ? vl_trajectory_lines(&d->trajectory) : 0);
    vl_counter_entry_t list[VL_SESSION_NUM_COUNTERS];
    const size_t k = vl_session_counter_list(ss, list);
    fprintf(stderr, "  session:");
    for (size_t i = 0; i < k; ++i) {
        if (list[i].value != 0) {
            fprintf(stderr, " %s %" PRIu64, list[i].name, list[i].value);
        }
    }
    fprintf(stderr, "; publish errors %" PRIu64 "; trajectory write errors %" PRIu64 "\n", d->n.publish_errors,
            d->n.trajectory_errors);
    fprintf(stderr, "  map: %" PRIu64 " landmarks in %" PRIu64 " batches on %s\n", d->n.landmarks_out,
            d->n.landmark_batches_out, d->channel[CH_LANDMARKS]);
    if (d->rx.fd >= 0) {
        /* What the direct receiver could not hand on is counted, never dropped silently. */
        fprintf(stderr,
                "  lcm receive: messages %" PRIu64 ", on other channels %" PRIu64 ", fragmented (dropped) %" PRIu64
                ", malformed %" PRIu64 "\n",
                d->rx.messages, d->rx.other, d->rx.fragments, d->rx.malformed);
    }
    fprintf(stderr,
            "  core: frames accepted %" PRIu64 ", observations used %" PRIu64 ", gated %" PRIu64
            ", landmarks mapped %" PRIu64 ", window %u/%u, numerical failures %" PRIu64
            ", innovation ratio over the run %.3g\n",
            c->frames_accepted, c->observations_used, c->observations_gated, c->landmarks_marginalized,
            est != NULL ? (unsigned)vl_window_size(est) : 0u, (unsigned)vl_session_config(ss)->max_landmarks,
            c->numerical_failures, vl_session_innovation_ratio(ss, 0));
    fprintf(stderr,
            "  robustness: time refused %" PRIu64 " (jumps %" PRIu64 "), timeline changes %" PRIu64
            ", divergence resets %" PRIu64 ", implausible imu %" PRIu64 " observations %" PRIu64
            ", frames during IMU silence %" PRIu64 ", poses withheld %" PRIu64 "\n",
            n->time_refused, c->time_jumps, c->timeline_changes, c->divergence_resets, c->imu_implausible,
            c->observations_implausible, c->frames_imu_silent, n->poses_withheld);
    if (d->opt.supersede_imu_poses) {
        fprintf(stderr,
                "  superseded IMU poses: %" PRIu64 " not sent (a frame's pose of the same or a later time followed),"
                " %" PRIu64 " held and sent late (no frame pose followed in time)\n",
                d->n.imu_poses_superseded, d->n.imu_poses_sent_late);
    }
    if (d->opt.warm_us > 0) {
        const vl_warm_t *w = &d->warm;
        fprintf(stderr,
                "  warm (--warm-us %ld): %" PRIu64 " frame periods, frame period %" PRId64
                " us; reading the state %" PRIu64 " us, polling %" PRIu64 " us in all (%.0f us a period); %" PRIu64
                " inputs came while polling\n",
                d->opt.warm_us, w->windows, w->period_us, w->touch_us, w->spin_us,
                w->windows > 0 ? (double)(w->touch_us + w->spin_us) / (double)w->windows : 0.0, w->inputs_in_spin);
    }
    if (d->opt.keep_awake) {
        if (d->awake_started) {
            fprintf(stderr, "  keep awake (--keep-awake): CPU %d, a SCHED_IDLE thread spun %" PRIu64 " loops\n",
                    d->opt.cpu, vl_awake_loops(&d->awake));
        } else {
            fprintf(stderr, "  keep awake (--keep-awake): CPU %d, not running (refused at start-up)\n", d->opt.cpu);
        }
    }
    fprintf(stderr, "  budget %" PRId64 " us (%s): %" PRIu64 " overrun(s) in %" PRIu64 " steps\n", d->budget_us,
            d->opt.budget_us > 0 ? "--budget-us" : "sensor period", d->n.overruns, d->n.steps);
    fprintf(stderr, "  step latency (CLOCK_MONOTONIC, decode to publish):\n");
    vl_latency_print(&d->lat_all, stderr, "    all steps  ");
    vl_latency_print(&d->lat_step[STEP_PROPAGATE], stderr, "    propagation");
    vl_latency_print(&d->lat_step[STEP_UPDATE], stderr, "    update     ");
    vl_latency_print(&d->lat_deferred, stderr, "    deferred   ");
    fprintf(stderr, "  histogram of all steps:\n");
    vl_latency_print_buckets(&d->lat_all, stderr);
}

int main(int argc, char **argv)
{
    daemon_t *d = &g;
    if (parse_args(argc, argv, &d->opt) != 0 || make_channels(d) != 0 || load_config(d) != 0) {
        return EXIT_USAGE;
    }
    if (d->opt.print_config) {
        return vl_config_write_ini(stdout, &d->cfg, d->info.has_calibration) == 0 ? 0 : EXIT_RUNTIME;
    }
    {
        char err[256];
        if (vl_notify_open(&d->notify, err, sizeof(err)) < 0) {
            fprintf(stderr, "vislamd: warning: %s; not notifying the service manager\n", err);
        }
        d->watchdog_period_us = vl_notify_watchdog_period_us(&d->notify);
    }
    d->budget_us = d->opt.budget_us > 0 ? d->opt.budget_us : DEFAULT_BUDGET_US;
    vl_warm_init(&d->warm, d->opt.warm_us);
    vl_latency_reset(&d->lat_all);
    vl_latency_reset(&d->lat_step[0]);
    vl_latency_reset(&d->lat_step[1]);
    vl_latency_reset(&d->lat_deferred);

    /* Signals: handlers first, then blocked, so LCM's receive thread inherits the blocked mask
       and they reach the main thread only inside vl_signal_wait_fd. */
    if (vl_signal_install() != 0 || vl_signal_block() != 0) {
        fprintf(stderr, "vislamd: cannot install signal handlers: %s\n", strerror(errno));
        return EXIT_RUNTIME;
    }
    realtime_setup(&d->opt);
    /* After the daemon's own CPU and priority: the worker avoids that CPU and takes that priority. */
    static vl_worker_t worker;
    {
        char msg[256];
        d->opt.worker.priority = d->opt.rt_priority;
        if (vl_worker_start(&worker, &d->opt.worker, msg, sizeof(msg)) != 0 ||
            (d->opt.worker.threads > 1 && !d->opt.quiet)) {
            fprintf(stderr, "vislamd: %s\n", msg);
        }
    }
    if (d->opt.keep_awake) {
        /* vl_awake pins the spinner and sets its policy itself: it inherits nothing from this thread. */
        char msg[256];
        d->awake_started = vl_awake_start(&d->awake, d->opt.cpu, msg, sizeof(msg)) == 0;
        if (!d->awake_started || !d->opt.quiet) {
            fprintf(stderr, "vislamd: %s%s\n", d->awake_started ? "" : "warning: ", msg);
        }
    }

    vl_session_options_t so;
    memset(&so, 0, sizeof(so));
    so.program = "vislamd";
    so.worker = &worker;
    so.quiet = d->opt.quiet;
    so.config_has_calibration = d->info.has_calibration;
    so.override_log = d->info.override_log;
    so.callbacks.on_pose = on_pose;
    so.callbacks.on_landmark = on_landmark;
    so.callbacks.on_event = on_event;
    so.callbacks.user = d;
    if (vl_session_init(&d->session, &g_est, &d->cfg, &so) != VL_OK) {
        fprintf(stderr, "vislamd: vl_init refused the configuration\n");
        return EXIT_USAGE;
    }
    if (d->opt.trajectory_path != NULL) {
        char err[512];
        /* Append: a restart (after a crash or kill -9) must not destroy the earlier run's poses. */
        char note[160];
        int appended = 0;
        snprintf(note, sizeof(note), "vislamd (pid %ld) restarted: the lines below are a new run", (long)getpid());
        if (vl_trajectory_open_append(&d->trajectory, d->opt.trajectory_path, note, &appended, err, sizeof(err)) != 0) {
            fprintf(stderr, "vislamd: %s\n", err);
            return EXIT_RUNTIME;
        }
        if (appended && !d->opt.quiet) {
            fprintf(stderr, "vislamd: appending to the existing trajectory %s\n", d->opt.trajectory_path);
        }
        d->have_trajectory = 1;
    }
    if (d->opt.step_samples_path != NULL && open_step_samples(d) != 0) {
        return EXIT_RUNTIME;
    }
    if (d->opt.stats_json_path != NULL && open_stats(d) != 0) {
        return EXIT_RUNTIME;
    }
    if (warm_up(d) != 0) {
        return EXIT_RUNTIME;
    }

    d->lcm = lcm_create(d->opt.lcm_url);
    if (d->lcm == NULL) {
        fprintf(stderr, "vislamd: cannot create LCM (url %s)\n",
                d->opt.lcm_url != NULL ? d->opt.lcm_url : "default; set --lcm-url or LCM_DEFAULT_URL");
        return EXIT_RUNTIME;
    }
    const int fd = open_receive(d);
    if (fd < 0) {
        lcm_destroy(d->lcm);
        return EXIT_RUNTIME;
    }
    check_loopback(d);

    /* End of start-up: everything the loop uses is mapped; lock it. From here on the loop does
       not allocate (an LD_PRELOAD counter can take this mlockall as its mark: tests/support). */
    lock_memory(&d->opt);
    if (d->direct) {
        /* "I am up" only now: a replay that starts on it finds the daemon ready, not in mlockall. */
        publish_status(d);
    }
    if (!d->opt.quiet) {
        fprintf(stderr, "vislamd: ready: %s %s %s -> %s %s %s %s (lcm %s)%s\n", d->channel[CH_IMU],
                d->channel[CH_FEATURES], d->channel[CH_CALIB], d->channel[CH_POSE], d->channel[CH_BOT_POSE],
                d->channel[CH_LANDMARKS], d->channel[CH_STATUS], d->opt.lcm_url != NULL ? d->opt.lcm_url : "default",
                vl_session_initialized(&d->session) ? "" : "; waiting for a calibration");
    }
    snprintf(d->notify_buf, sizeof(d->notify_buf), "READY=1\nSTATUS=ready: %s",
             vl_session_initialized(&d->session) ? "calibrated, waiting for inputs" : "waiting for a calibration");
    vl_notify_send(&d->notify, d->notify_buf);

    int exit_code = 0;
    int lcm_errors = 0;
    int64_t next_status = vl_clock_monotonic_us() + STATUS_PERIOD_US;
    while (!vl_signal_stop_requested()) {
        int64_t now = vl_clock_monotonic_us();
        feed_watchdog(d, now, lcm_errors == 0);
        if (now >= next_status) {
            publish_status(d);
            notify_status(d);
            if (!d->opt.quiet && d->n.status_out % STATUS_LOG_EVERY == 0) {
                print_status_line(d);
            }
            next_status += STATUS_PERIOD_US;
            if (next_status <= now) {
                next_status = now + STATUS_PERIOD_US; /* do not burst after a stall */
            }
        }
        if (d->held.have && d->held.deadline_us != 0 && now >= d->held.deadline_us) {
            publish_held(d); /* its frame did not come in time */
        }
        int64_t wake = next_status;
        if (d->watchdog_period_us > 0 && d->next_watchdog_us < wake) {
            wake = d->next_watchdog_us;
        }
        if (d->held.have && d->held.deadline_us != 0 && d->held.deadline_us < wake) {
            wake = d->held.deadline_us;
        }
        if (warm_for_frame(d, now, &wake)) {
            continue;
        }
        now = vl_clock_monotonic_us();
        if (wake <= now) {
            continue;
        }
        if (d->opt.busy_poll_us > 0 &&
            busy_poll(d, now + d->opt.busy_poll_us < wake ? now + d->opt.busy_poll_us : wake, NULL)) {
            continue;
        }
        const int r = vl_signal_wait_fd(fd, wake - now);
        if (r > 0) {
            if (receive(d) != 0) {
                if (++lcm_errors >= LCM_ERRORS_MAX) {
                    fprintf(stderr, "vislamd: receiving from LCM failed %d times in a row; stopping\n", lcm_errors);
                    exit_code = EXIT_RUNTIME;
                    break;
                }
            } else {
                lcm_errors = 0;
            }
        } else if (r < 0 && errno != EINTR) {
            fprintf(stderr, "vislamd: waiting for LCM failed: %s\n", strerror(errno));
            exit_code = EXIT_RUNTIME;
            break;
        }
    }

    snprintf(d->notify_buf, sizeof(d->notify_buf), "STOPPING=1\nSTATUS=stopping (%s)",
             exit_code != 0 ? "LCM failed" : (vl_signal_last() == SIGINT ? "SIGINT" : "SIGTERM"));
    vl_notify_send(&d->notify, d->notify_buf);

    /* Messages already received are still processed, so no input that arrived is lost. */
    for (int i = 0; i < DRAIN_MAX && exit_code == 0; ++i) {
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, 0) != 1 || !(p.revents & POLLIN) || receive(d) != 0) {
            break;
        }
    }
    if (d->held.have) {
        publish_held(d); /* the frame behind it was not read */
    }
    vl_session_flush(&d->session); /* the window's landmarks join the map: none is lost at exit */
    publish_map(d);
    publish_status(d);
    vl_awake_stop(&d->awake); /* its final count in the summary */
    if (!d->opt.quiet) {
        print_status_line(d);
        print_summary(d);
    }
    if (d->step_samples_file != NULL && write_step_samples(d) != 0) {
        exit_code = EXIT_RUNTIME;
    }
    if (d->stats_file != NULL && write_stats(d) != 0) {
        exit_code = EXIT_RUNTIME;
    }
    if (d->have_trajectory && vl_trajectory_close(&d->trajectory) != 0) {
        fprintf(stderr, "vislamd: error: the trajectory %s is incomplete (write error)\n", d->opt.trajectory_path);
        exit_code = EXIT_RUNTIME;
    }
    vl_lcm_rx_close(&d->rx);
    lcm_destroy(d->lcm);
    vl_worker_stop(&worker);
    vl_notify_close(&d->notify);
    vl_rt_release_cpu_latency(&g_cpu_latency_fd);
    return exit_code;
}
