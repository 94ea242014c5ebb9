#define _GNU_SOURCE /* SOCK_NONBLOCK, SOCK_CLOEXEC */

#include "vl_lcm_rx.h"

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <time.h>
#include <unistd.h>

#include "vl_bytes.h"

/* LCM's wire format: a big-endian magic and sequence number, then (short messages) the channel
   name with its NUL and the payload; fragmented messages carry a longer header and magic. */
#define LCM_MAGIC_SHORT 0x4c433032u
#define LCM_MAGIC_LONG 0x4c433033u
#define LCM_SHORT_HEADER 8
#define LCM_DEFAULT_URL_TEXT "udpm://239.255.76.67:7667?ttl=0"
#define LCM_DEFAULT_NETWORK "239.255.76.67:7667"
#define LCM_DEFAULT_PORT 7667

static void set_err(char *err, size_t len, const char *what, const char *url)
{
    if (err != NULL && len > 0) {
        snprintf(err, len, "%s (LCM url %s)%s%s", what, url, errno != 0 ? ": " : "", errno != 0 ? strerror(errno) : "");
    }
}

/* "ADDR[:PORT]" of a udpm URL (up to '?'), into a multicast group and a port; 0 or -1. */
static int parse_network(const char *s, size_t n, struct in_addr *group, unsigned *port)
{
    char buf[64];
    if (n == 0) {
        s = LCM_DEFAULT_NETWORK;
        n = strlen(s);
    }
    if (n >= sizeof(buf)) {
        return -1;
    }
    memcpy(buf, s, n);
    buf[n] = '\0';
    *port = LCM_DEFAULT_PORT;
    char *colon = strchr(buf, ':');
    if (colon != NULL) {
        *colon = '\0';
        char *end = NULL;
        const long p = strtol(colon + 1, &end, 10);
        if (end == colon + 1 || *end != '\0' || p <= 0 || p > 65535) {
            return -1;
        }
        *port = (unsigned)p;
    }
    if (inet_aton(buf, group) == 0 || !IN_MULTICAST(ntohl(group->s_addr))) {
        return -1;
    }
    return 0;
}

/* recv_buf_size=N among the URL's options (after '?', '&'-separated); 0 when absent. */
static long recv_buf_size(const char *opts)
{
    static const char key[] = "recv_buf_size=";
    for (const char *p = opts; p != NULL && *p != '\0';) {
        if (strncmp(p, key, sizeof(key) - 1) == 0) {
            return strtol(p + sizeof(key) - 1, NULL, 0);
        }
        p = strchr(p, '&');
        p = p != NULL ? p + 1 : NULL;
    }
    return 0;
}

int vl_lcm_rx_open(vl_lcm_rx_t *rx, const char *url, lcm_t *lcm, char *err, size_t err_len)
{
    vl_lcm_rx_use_lcm(rx, lcm);
    if (url == NULL) {
        url = getenv("LCM_DEFAULT_URL");
    }
    if (url == NULL || *url == '\0') {
        url = LCM_DEFAULT_URL_TEXT;
    }
    const char *sep = strstr(url, "://");
    if (sep == NULL || (size_t)(sep - url) != 4 || strncmp(url, "udpm", 4) != 0) {
        return 1; /* through liblcm */
    }
    const char *network = sep + 3;
    const char *q = strchr(network, '?');
    const size_t network_len = q != NULL ? (size_t)(q - network) : strlen(network);
    struct in_addr group;
    unsigned port = 0;
    errno = 0;
    if (parse_network(network, network_len, &group, &port) != 0) {
        set_err(err, err_len, "not a multicast ADDRESS:PORT", url);
        return -1;
    }
    const int fd = socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        set_err(err, err_len, "cannot open a UDP socket", url);
        return -1;
    }
    const int one = 1;
    const int rcvbuf = (int)recv_buf_size(q != NULL ? q + 1 : NULL);
    struct sockaddr_in addr;
    memset(&addr, 0, sizeof(addr));
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_ANY);
    addr.sin_port = htons((uint16_t)port);
    struct ip_mreq mreq;
    memset(&mreq, 0, sizeof(mreq));
    mreq.imr_multiaddr = group;
    mreq.imr_interface.s_addr = htonl(INADDR_ANY);
    const char *what = NULL;
    if (setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) != 0) {
        what = "SO_REUSEADDR refused";
    } else if (rcvbuf > 0 && setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof(rcvbuf)) != 0) {
        what = "SO_RCVBUF refused";
    } else if (setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &one, sizeof(one)) != 0) {
        what = "SO_TIMESTAMPNS refused";
    } else if (bind(fd, (const struct sockaddr *)&addr, sizeof(addr)) != 0) {
        what = "cannot bind the LCM port";
    } else if (setsockopt(fd, IPPROTO_IP, IP_ADD_MEMBERSHIP, &mreq, sizeof(mreq)) != 0) {
        what = "cannot join the multicast group";
    }
    if (what != NULL) {
        set_err(err, err_len, what, url);
        close(fd);
        return -1;
    }
    rx->fd = fd;
    rx->via_lcm = 0;
    return 0;
}

void vl_lcm_rx_use_lcm(vl_lcm_rx_t *rx, lcm_t *lcm)
{
    memset(rx, 0, offsetof(vl_lcm_rx_t, packet));
    rx->fd = -1;
    rx->lcm = lcm;
    rx->via_lcm = 1;
}

int vl_lcm_rx_subscribe(vl_lcm_rx_t *rx, const char *channel, lcm_msg_handler_t handler, void *user)
{
    if (rx->num_subs >= VL_LCM_RX_MAX_SUBSCRIPTIONS || strlen(channel) >= VL_LCM_RX_CHANNEL_MAX || handler == NULL) {
        return -1;
    }
    vl_lcm_rx_subscription_t *s = &rx->subs[rx->num_subs];
    snprintf(s->channel, sizeof(s->channel), "%s", channel);
    s->handler = handler;
    s->user = user;
    s->lcm_sub = NULL;
    if (rx->via_lcm && (rx->lcm == NULL || (s->lcm_sub = lcm_subscribe(rx->lcm, channel, handler, user)) == NULL)) {
        return -1;
    }
    rx->num_subs++;
    return 0;
}

int vl_lcm_rx_unsubscribe(vl_lcm_rx_t *rx, const char *channel, lcm_msg_handler_t handler)
{
    int kept = 0, removed = 0;
    for (int i = 0; i < rx->num_subs; ++i) {
        if (rx->subs[i].handler == handler && strcmp(rx->subs[i].channel, channel) == 0) {
            if (rx->subs[i].lcm_sub != NULL) {
                lcm_unsubscribe(rx->lcm, rx->subs[i].lcm_sub);
            }
            removed++;
        } else {
            rx->subs[kept++] = rx->subs[i];
        }
    }
    rx->num_subs = kept;
    return removed;
}

int vl_lcm_rx_fd(const vl_lcm_rx_t *rx)
{
    if (rx->via_lcm) {
        return rx->lcm != NULL ? lcm_get_fileno(rx->lcm) : -1; /* also starts liblcm's receive side */
    }
    return rx->fd;
}

/* Through liblcm: what its thread has queued (its pipe readable), up to max messages. */
static int poll_lcm(vl_lcm_rx_t *rx, int max)
{
    const int fd = vl_lcm_rx_fd(rx);
    int handled = 0;
    for (int i = 0; i < max && fd >= 0; ++i) {
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, 0) <= 0) {
            break;
        }
        if (lcm_handle(rx->lcm) != 0) {
            return -1;
        }
        handled++;
    }
    return fd >= 0 ? handled : -1;
}

/* The kernel's receive stamp of the datagram msg, CLOCK_REALTIME us; now when there is none. */
static int64_t receive_utime(struct msghdr *msg)
{
    for (struct cmsghdr *c = CMSG_FIRSTHDR(msg); c != NULL; c = CMSG_NXTHDR(msg, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS) {
            struct timespec ts;
            memcpy(&ts, CMSG_DATA(c), sizeof(ts));
            return (int64_t)ts.tv_sec * 1000000 + (int64_t)(ts.tv_nsec / 1000);
        }
    }
    struct timespec now;
    clock_gettime(CLOCK_REALTIME, &now);
    return (int64_t)now.tv_sec * 1000000 + (int64_t)(now.tv_nsec / 1000);
}

/* One datagram of n bytes in rx->packet: dispatched, or counted; 1 when a handler took it. */
static int dispatch(vl_lcm_rx_t *rx, size_t n, int64_t utime)
{
    if (n < LCM_SHORT_HEADER + 1) {
        rx->malformed++;
        return 0;
    }
    const uint32_t magic = vl_be32(rx->packet);
    if (magic == LCM_MAGIC_LONG) {
        rx->fragments++;
        return 0;
    }
    const char *channel = (const char *)rx->packet + LCM_SHORT_HEADER;
    const size_t len = strnlen(channel, n - LCM_SHORT_HEADER);
    if (magic != LCM_MAGIC_SHORT || len == n - LCM_SHORT_HEADER || len == 0 || len >= VL_LCM_RX_CHANNEL_MAX) {
        rx->malformed++;
        return 0;
    }
    lcm_recv_buf_t rbuf;
    rbuf.data = rx->packet + LCM_SHORT_HEADER + len + 1;
    rbuf.data_size = (uint32_t)(n - LCM_SHORT_HEADER - len - 1);
    rbuf.recv_utime = utime;
    rbuf.lcm = rx->lcm;
    int taken = 0;
    for (int i = 0; i < rx->num_subs; ++i) {
        if (strcmp(rx->subs[i].channel, channel) == 0) {
            rx->subs[i].handler(&rbuf, channel, rx->subs[i].user);
            taken = 1;
        }
    }
    rx->messages += (uint64_t)taken;
    rx->other += (uint64_t)!taken;
    return taken;
}

int vl_lcm_rx_poll(vl_lcm_rx_t *rx, int max)
{
    if (rx->via_lcm) {
        return poll_lcm(rx, max);
    }
    int handled = 0;
    for (int i = 0; i < max; ++i) {
        struct iovec iov = {rx->packet, VL_LCM_RX_PACKET_MAX};
        union {
            char buf[CMSG_SPACE(sizeof(struct timespec))];
            struct cmsghdr align;
        } control;
        struct msghdr msg;
        memset(&msg, 0, sizeof(msg));
        msg.msg_iov = &iov;
        msg.msg_iovlen = 1;
        msg.msg_control = control.buf;
        msg.msg_controllen = sizeof(control.buf);
        const ssize_t n = recvmsg(rx->fd, &msg, MSG_DONTWAIT);
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            if (errno == EAGAIN || errno == EWOULDBLOCK) {
                break;
            }
            return -1;
        }
        rx->packet[n] = 0; /* a channel name cut by the datagram's end still ends */
        handled += dispatch(rx, (size_t)n, receive_utime(&msg));
    }
    return handled;
}

int vl_lcm_rx_peek(vl_lcm_rx_t *rx, vl_lcm_rx_peek_t *out)
{
    if (rx->via_lcm || rx->fd < 0) {
        return -1;
    }
    /* The header, the longest channel name with its NUL and the payload's first bytes: a longer
       datagram is cut (MSG_TRUNC) in this copy only, the socket keeps it whole. */
    uint8_t head[LCM_SHORT_HEADER + VL_LCM_RX_CHANNEL_MAX + VL_LCM_RX_PEEK_MAX];
    ssize_t n;
    do {
        n = recv(rx->fd, head, sizeof(head), MSG_PEEK | MSG_DONTWAIT);
    } while (n < 0 && errno == EINTR);
    if (n < 0) {
        return (errno == EAGAIN || errno == EWOULDBLOCK) ? 0 : -1;
    }
    if ((size_t)n < LCM_SHORT_HEADER + 1 || vl_be32(head) != LCM_MAGIC_SHORT) {
        return 0;
    }
    const char *channel = (const char *)head + LCM_SHORT_HEADER;
    const size_t len = strnlen(channel, (size_t)n - LCM_SHORT_HEADER);
    if (len == (size_t)n - LCM_SHORT_HEADER || len == 0 || len >= VL_LCM_RX_CHANNEL_MAX) {
        return 0;
    }
    memcpy(out->channel, channel, len + 1);
    const size_t payload = (size_t)n - LCM_SHORT_HEADER - len - 1;
    out->size = payload < VL_LCM_RX_PEEK_MAX ? payload : VL_LCM_RX_PEEK_MAX;
    memcpy(out->payload, head + LCM_SHORT_HEADER + len + 1, out->size);
    return 1;
}

void vl_lcm_rx_close(vl_lcm_rx_t *rx)
{
    if (rx->fd >= 0) {
        close(rx->fd);
    }
    rx->fd = -1;
    for (int i = 0; i < rx->num_subs; ++i) {
        if (rx->subs[i].lcm_sub != NULL) {
            lcm_unsubscribe(rx->lcm, rx->subs[i].lcm_sub);
        }
    }
    rx->num_subs = 0;
}
