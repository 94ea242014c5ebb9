#define _POSIX_C_SOURCE 200809L

#include "vl_signal.h"

#include <errno.h>
#include <signal.h>
#include <string.h>
#include <sys/select.h>
#include <time.h>

static volatile sig_atomic_t g_stop_signal = 0;

static void on_signal(int sig)
{
    g_stop_signal = sig;
}

int vl_signal_install(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = 0; /* no SA_RESTART: blocking calls return EINTR */
    if (sigaction(SIGINT, &sa, NULL) != 0 || sigaction(SIGTERM, &sa, NULL) != 0) {
        return -1;
    }
    return 0;
}

int vl_signal_stop_requested(void)
{
    return g_stop_signal != 0;
}

int vl_signal_last(void)
{
    return (int)g_stop_signal;
}

void vl_signal_reset(void)
{
    g_stop_signal = 0;
}

static void stop_set(sigset_t *set)
{
    sigemptyset(set);
    sigaddset(set, SIGINT);
    sigaddset(set, SIGTERM);
}

int vl_signal_block(void)
{
    sigset_t set;
    stop_set(&set);
    const int rc = pthread_sigmask(SIG_BLOCK, &set, NULL);
    if (rc != 0) {
        errno = rc;
        return -1;
    }
    return 0;
}

int vl_signal_wait_fd(int fd, int64_t timeout_us)
{
    /* The mask in force during the wait: the current one without SIGINT and SIGTERM. */
    sigset_t wait_mask;
    if (pthread_sigmask(SIG_BLOCK, NULL, &wait_mask) != 0) {
        sigemptyset(&wait_mask);
    }
    sigdelset(&wait_mask, SIGINT);
    sigdelset(&wait_mask, SIGTERM);
    if (g_stop_signal != 0) {
        errno = EINTR;
        return -1;
    }
    if (timeout_us < 0) {
        timeout_us = 0;
    }
    struct timespec ts;
    ts.tv_sec = (time_t)(timeout_us / 1000000);
    ts.tv_nsec = (long)(timeout_us % 1000000) * 1000;
    fd_set rd;
    FD_ZERO(&rd);
    FD_SET(fd, &rd);
    const int rc = pselect(fd + 1, &rd, NULL, NULL, &ts, &wait_mask);
    if (rc < 0) {
        return -1;
    }
    return rc > 0 ? 1 : 0;
}
