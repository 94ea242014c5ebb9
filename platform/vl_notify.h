/**
 * @file vl_notify.h
 * @brief The systemd service notification protocol (sd_notify), without libsystemd.
 *
 * A service started with Type=notify gets the path of a unix datagram socket in NOTIFY_SOCKET
 * ("@name" for the abstract namespace) and, with WatchdogSec=, its watchdog period in
 * WATCHDOG_USEC (for the process WATCHDOG_PID names, when set). Each message is one datagram of
 * newline-separated KEY=VALUE lines: READY=1, WATCHDOG=1, STOPPING=1, STATUS=text. Without
 * NOTIFY_SOCKET every call does nothing, so a program run by hand behaves as before. Nothing here
 * allocates; sending is one non-blocking sendto.
 */
#ifndef VISLAM_PLATFORM_VL_NOTIFY_H
#define VISLAM_PLATFORM_VL_NOTIFY_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Longest NOTIFY_SOCKET path accepted (that of sockaddr_un). */
#define VL_NOTIFY_PATH_MAX 108

/** The notification socket and watchdog period taken from the environment. */
typedef struct {
    int fd;                        /**< datagram socket, -1 when inactive */
    char path[VL_NOTIFY_PATH_MAX]; /**< NOTIFY_SOCKET, "@" for the abstract namespace */
    int64_t watchdog_us;           /**< WATCHDOG_USEC for this process, us; 0 = no watchdog */
    uint64_t sent;                 /**< messages sent */
    uint64_t errors;               /**< messages that could not be sent */
} vl_notify_t;

/**
 * Reads NOTIFY_SOCKET, WATCHDOG_USEC and WATCHDOG_PID and opens the socket.
 * @param err message on failure
 * @return 1 active, 0 not run by a service manager (no NOTIFY_SOCKET), -1 a NOTIFY_SOCKET or
 *         WATCHDOG_USEC that cannot be used (n then does nothing).
 */
int vl_notify_open(vl_notify_t *n, char *err, int err_len);

/** Whether messages go anywhere. */
int vl_notify_active(const vl_notify_t *n);

/**
 * Sends one message ("READY=1", "WATCHDOG=1", "STATUS=...", lines joined by '\n').
 * @return 0 sent or inactive, -1 not sent (counted in errors)
 */
int vl_notify_send(vl_notify_t *n, const char *message);

/** How often to send WATCHDOG=1: half the watchdog period, us; 0 when there is no watchdog. */
int64_t vl_notify_watchdog_period_us(const vl_notify_t *n);

/** Closes the socket. */
void vl_notify_close(vl_notify_t *n);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_NOTIFY_H */
