/*
 * vl_notify_listen SOCKET SECONDS: the service manager's side of the sd_notify protocol, for
 * tests/test_notify.sh. Binds a unix datagram socket at SOCKET (the path a test puts in
 * NOTIFY_SOCKET), prints every message it receives as it arrives, and ends 500 ms after a
 * STOPPING=1 or after SECONDS, with a summary as "key value" lines:
 *
 *   msg MS TEXT                 every message (ms since start, its lines joined by " | ")
 *   messages N
 *   ready N / watchdog N / stopping N / status N        messages holding each key
 *   watchdog.before_ready N     WATCHDOG=1 before the first READY=1
 *   watchdog.after_stopping N   WATCHDOG=1 after the first STOPPING=1
 *   watchdog.max_gap_ms MS      longest wait for a WATCHDOG=1, from READY=1 to the STOPPING=1
 *   status.last TEXT            the last STATUS= value
 *   unknown N                   lines that are not KEY=VALUE
 */
#define _POSIX_C_SOURCE 200809L

#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#define LINGER_MS 500

static int64_t now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000 + ts.tv_nsec / 1000000;
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: vl_notify_listen SOCKET SECONDS\n");
        return 2;
    }
    struct sockaddr_un addr;
    memset(&addr, 0, sizeof(addr));
    addr.sun_family = AF_UNIX;
    if (strlen(argv[1]) >= sizeof(addr.sun_path)) {
        fprintf(stderr, "vl_notify_listen: socket path too long\n");
        return 2;
    }
    strcpy(addr.sun_path, argv[1]);
    const int fd = socket(AF_UNIX, SOCK_DGRAM, 0);
    unlink(argv[1]);
    if (fd < 0 || bind(fd, (const struct sockaddr *)&addr, sizeof(addr)) != 0) {
        perror("vl_notify_listen: bind");
        return 1;
    }
    const int64_t start = now_ms();
    int64_t end = start + (int64_t)atoi(argv[2]) * 1000;
    long messages = 0, ready = 0, watchdog = 0, stopping = 0, status = 0, unknown = 0;
    long before_ready = 0, after_stopping = 0;
    int64_t last_alive = -1, max_gap = 0; /* from READY=1, each WATCHDOG=1, up to STOPPING=1 */
    char last_status[512] = "";
    char buf[4096];
    for (;;) {
        const int64_t t = now_ms();
        if (t >= end) {
            break;
        }
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, (int)(end - t)) != 1) {
            continue;
        }
        const ssize_t n = recv(fd, buf, sizeof(buf) - 1, 0);
        if (n < 0) {
            continue;
        }
        buf[n] = '\0';
        const int64_t at = now_ms() - start;
        messages++;
        printf("msg %lld ", (long long)at);
        for (char *line = strtok(buf, "\n"); line != NULL; line = strtok(NULL, "\n")) {
            printf("%s%s", line, " | ");
            if (strcmp(line, "READY=1") == 0) {
                if (ready++ == 0) {
                    last_alive = at;
                }
            } else if (strcmp(line, "WATCHDOG=1") == 0) {
                watchdog++;
                before_ready += ready == 0;
                after_stopping += stopping > 0;
                if (ready > 0 && stopping == 0) {
                    max_gap = at - last_alive > max_gap ? at - last_alive : max_gap;
                    last_alive = at;
                }
            } else if (strcmp(line, "STOPPING=1") == 0) {
                if (stopping++ == 0) {
                    if (last_alive >= 0) {
                        max_gap = at - last_alive > max_gap ? at - last_alive : max_gap;
                    }
                    end = now_ms() + LINGER_MS;
                }
            } else if (strncmp(line, "STATUS=", 7) == 0) {
                status++;
                snprintf(last_status, sizeof(last_status), "%s", line + 7);
            } else if (strchr(line, '=') == NULL) {
                unknown++;
            }
        }
        printf("\n");
        fflush(stdout);
    }
    printf("messages %ld\nready %ld\nwatchdog %ld\nstopping %ld\nstatus %ld\nunknown %ld\n", messages, ready, watchdog,
           stopping, status, unknown);
    printf("watchdog.before_ready %ld\nwatchdog.after_stopping %ld\nwatchdog.max_gap_ms %lld\n", before_ready,
           after_stopping, (long long)max_gap);
    printf("status.last %s\n", last_status);
    close(fd);
    unlink(argv[1]);
    return 0;
}
