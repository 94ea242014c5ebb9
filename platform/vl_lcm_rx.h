/**
 * @file vl_lcm_rx.h
 * @brief LCM's UDP multicast receive side, in the caller's own thread.
 *
 * liblcm 1.3.1 receives on a thread of its own: each datagram wakes that thread, which queues it
 * and writes a byte to a pipe, which wakes the thread that calls lcm_handle. This receiver reads
 * the multicast socket itself (one wake-up per message, no queue, no allocation), so a loop can
 * poll() it, or spin on it, and hand each message to the same lcm_msg_handler_t LCM would call.
 * Publishing stays with lcm_publish (a sendmsg in the caller's thread); an lcm_t that never
 * subscribes starts no receive thread.
 *
 * It speaks the receive half of LCM's UDP multicast wire format for messages that fit one
 * datagram (LCM's "short" messages, up to 65,499 bytes with the channel name): every message of
 * vislam's types. Fragmented messages are counted and dropped. Only udpm:// URLs: for any other
 * provider (or by choice, vl_lcm_rx_use_lcm) the same receiver goes through liblcm's receive
 * thread instead, so that a program subscribes, waits and handles one way whichever path is used.
 */
#ifndef VISLAM_PLATFORM_VL_LCM_RX_H
#define VISLAM_PLATFORM_VL_LCM_RX_H

#include <stddef.h>
#include <stdint.h>

#include <lcm/lcm.h>

#ifdef __cplusplus
extern "C" {
#endif

#define VL_LCM_RX_MAX_SUBSCRIPTIONS 8 /**< channels one receiver dispatches */
#define VL_LCM_RX_CHANNEL_MAX 64      /**< bytes of a channel name, with its terminating NUL */
#define VL_LCM_RX_PACKET_MAX 65536    /**< bytes of the largest datagram */
#define VL_LCM_RX_PEEK_MAX 64         /**< payload bytes vl_lcm_rx_peek shows of the next message */

/** One subscription: an exact channel name and the handler LCM would call for it. */
typedef struct {
    char channel[VL_LCM_RX_CHANNEL_MAX];
    lcm_msg_handler_t handler;
    void *user;
    lcm_subscription_t *lcm_sub; /**< through liblcm: its subscription; else NULL */
} vl_lcm_rx_subscription_t;

/** The next message waiting, as vl_lcm_rx_peek shows it (nothing taken from the socket). */
typedef struct {
    char channel[VL_LCM_RX_CHANNEL_MAX];
    uint8_t payload[VL_LCM_RX_PEEK_MAX]; /**< the payload's first bytes */
    size_t size;                         /**< bytes of payload shown: min(payload size, VL_LCM_RX_PEEK_MAX) */
} vl_lcm_rx_peek_t;

/** A receiver. Caller-owned (about 64 KiB: its packet buffer); no allocation after open. */
typedef struct {
    int fd;      /**< the multicast socket, -1 when closed or through liblcm */
    lcm_t *lcm;  /**< handed to handlers in lcm_recv_buf_t::lcm (may be NULL when direct) */
    int via_lcm; /**< 1: subscriptions, the descriptor and polling go through liblcm's receive thread */
    vl_lcm_rx_subscription_t subs[VL_LCM_RX_MAX_SUBSCRIPTIONS];
    int num_subs;
    uint64_t messages;  /**< messages handed to a handler */
    uint64_t other;     /**< well-formed messages on channels nobody subscribed to here */
    uint64_t fragments; /**< datagrams of fragmented (large) messages, dropped */
    uint64_t malformed; /**< datagrams that are not LCM messages */
    uint8_t packet[VL_LCM_RX_PACKET_MAX + 1];
} vl_lcm_rx_t;

/**
 * Parses an LCM URL (NULL: $LCM_DEFAULT_URL, else LCM's default udpm://239.255.76.67:7667?ttl=0)
 * and, for udpm://, opens the socket as liblcm does: bound to the port with SO_REUSEADDR (several
 * processes on one host share the group), the group joined, SO_RCVBUF from recv_buf_size if
 * given, kernel receive stamps on, non-blocking.
 * @param lcm the lcm_t the handlers are given (may be NULL); the one received through otherwise
 * @return 0 open; 1 not a udpm:// URL (nothing opened: the receiver goes through @p lcm, as after
 *         vl_lcm_rx_use_lcm); -1 an error, in err
 */
int vl_lcm_rx_open(vl_lcm_rx_t *rx, const char *url, lcm_t *lcm, char *err, size_t err_len);

/**
 * Receives through liblcm (its thread, queue and pipe) instead of the socket: vl_lcm_rx_subscribe
 * becomes lcm_subscribe, vl_lcm_rx_fd lcm_get_fileno and vl_lcm_rx_poll lcm_handle on what is
 * queued. For any LCM provider.
 */
void vl_lcm_rx_use_lcm(vl_lcm_rx_t *rx, lcm_t *lcm);

/** Adds a handler for exactly @p channel; 0, or -1 when full, the name is too long or LCM refuses. */
int vl_lcm_rx_subscribe(vl_lcm_rx_t *rx, const char *channel, lcm_msg_handler_t handler, void *user);

/** Removes the subscriptions of @p channel to @p handler; the number removed. */
int vl_lcm_rx_unsubscribe(vl_lcm_rx_t *rx, const char *channel, lcm_msg_handler_t handler);

/** The descriptor to wait on (poll/select readable): the socket, or liblcm's; -1 when none. */
int vl_lcm_rx_fd(const vl_lcm_rx_t *rx);

/**
 * Reads what the socket holds, without blocking, at most @p max datagrams, and calls the handler
 * of each message subscribed to (with recv_utime the kernel's receive time, CLOCK_REALTIME us).
 * Through liblcm: handles up to @p max of the messages its thread has queued, without blocking.
 * @return the messages handed to handlers (0: none waiting), or -1 on a socket error (errno set)
 */
int vl_lcm_rx_poll(vl_lcm_rx_t *rx, int max);

/**
 * Looks at the next datagram waiting on the socket without taking it (the next vl_lcm_rx_poll
 * still hands it on): a program can decide what to do with the current message's outputs knowing
 * what comes next. Never blocks.
 * @return 1 the next datagram is an LCM message that fits one datagram: its channel and first
 *         payload bytes in @p out; 0 nothing waiting, or the next datagram is something else
 *         (a fragment, not LCM); -1 through liblcm (its queue cannot be looked into) or a socket
 *         error
 */
int vl_lcm_rx_peek(vl_lcm_rx_t *rx, vl_lcm_rx_peek_t *out);

/** Closes the socket, or unsubscribes from liblcm (a closed or never opened receiver is fine). */
void vl_lcm_rx_close(vl_lcm_rx_t *rx);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_LCM_RX_H */
