#define _POSIX_C_SOURCE 200809L
#define _DEFAULT_SOURCE /* SOCK_CLOEXEC, SOCK_NONBLOCK, MSG_NOSIGNAL */

#include "vl_notify.h"

#include <errno.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

/* Parses a whole unsigned decimal number; -1 when s is not one. */
static long long parse_unsigned(const char *s)
{
    char *end = NULL;
    if (s == NULL || *s < '0' || *s > '9') {
        return -1;
    }
    errno = 0;
    const unsigned long long v = strtoull(s, &end, 10);
    if (errno != 0 || *end != '\0' || v > (unsigned long long)INT64_MAX) {
        return -1;
    }
    return (long long)v;
}

int vl_notify_open(vl_notify_t *n, char *err, int err_len)
{
    memset(n, 0, sizeof(*n));
    n->fd = -1;
    const char *path = getenv("NOTIFY_SOCKET");
    if (path == NULL || path[0] == '\0') {
        return 0;
    }
    if ((path[0] != '/' && path[0] != '@') || strlen(path) >= sizeof(n->path)) {
        snprintf(err, (size_t)err_len, "NOTIFY_SOCKET=%s: not an absolute path or @name that fits a unix socket", path);
        return -1;
    }
    const char *usec = getenv("WATCHDOG_USEC");
    if (usec != NULL) {
        /* The watchdog is this process's only if WATCHDOG_PID, when set, names it. */
        const long long pid = parse_unsigned(getenv("WATCHDOG_PID"));
        const long long us = parse_unsigned(usec);
        if (us <= 0) {
            snprintf(err, (size_t)err_len, "WATCHDOG_USEC=%s: not a positive number of microseconds", usec);
            return -1;
        }
        if (getenv("WATCHDOG_PID") == NULL || pid == (long long)getpid()) {
            n->watchdog_us = (int64_t)us;
        }
    }
    n->fd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
    if (n->fd < 0) {
        snprintf(err, (size_t)err_len, "cannot create the notification socket: %s", strerror(errno));
        n->watchdog_us = 0;
        return -1;
    }
    snprintf(n->path, sizeof(n->path), "%s", path);
    return 1;
}

int vl_notify_active(const vl_notify_t *n)
{
    return n->fd >= 0;
}

int vl_notify_send(vl_notify_t *n, const char *message)
{
    if (n->fd < 0) {
        return 0;
    }
    struct sockaddr_un addr;
    memset(&addr, 0, sizeof(addr));
    addr.sun_family = AF_UNIX;
    const size_t len = strlen(n->path);
    memcpy(addr.sun_path, n->path, len);
    if (n->path[0] == '@') {
        addr.sun_path[0] = '\0'; /* abstract namespace: the name is the bytes after the zero, no terminator */
    }
    const socklen_t addr_len = (socklen_t)(offsetof(struct sockaddr_un, sun_path) + len + (n->path[0] == '@' ? 0 : 1));
    if (sendto(n->fd, message, strlen(message), MSG_NOSIGNAL, (const struct sockaddr *)&addr, addr_len) < 0) {
        n->errors++;
        return -1;
    }
    n->sent++;
    return 0;
}

int64_t vl_notify_watchdog_period_us(const vl_notify_t *n)
{
    return n->fd >= 0 ? n->watchdog_us / 2 : 0;
}

void vl_notify_close(vl_notify_t *n)
{
    if (n->fd >= 0) {
        close(n->fd);
    }
    n->fd = -1;
}
