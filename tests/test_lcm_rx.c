/*
 * Tests of the direct LCM receiver (platform/vl_lcm_rx) against liblcm's own publisher. CTest runs
 * it in a private network namespace with a multicast loopback when it can; the tests that need
 * multicast are ignored (with a message) where it is not routed.
 */
#define _POSIX_C_SOURCE 200809L

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdint.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <lcm/lcm.h>

#include "unity.h"
#include "vl_lcm_rx.h"

#define URL "udpm://239.255.76.67:7667?ttl=0"
#define PAYLOAD_MAX 256

typedef struct {
    int calls;
    char channel[VL_LCM_RX_CHANNEL_MAX];
    uint8_t data[PAYLOAD_MAX];
    uint32_t size;
    int64_t recv_utime;
    lcm_t *lcm;
} received_t;

static vl_lcm_rx_t g_rx;
static lcm_t *g_lcm;

void setUp(void)
{
    g_lcm = NULL;
    g_rx.fd = -1;
}

void tearDown(void)
{
    vl_lcm_rx_close(&g_rx);
    if (g_lcm != NULL) {
        lcm_destroy(g_lcm);
    }
}

static void on_message(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    received_t *r = (received_t *)user;
    r->calls++;
    snprintf(r->channel, sizeof(r->channel), "%s", channel);
    r->size = rbuf->data_size;
    memcpy(r->data, rbuf->data, rbuf->data_size < PAYLOAD_MAX ? rbuf->data_size : PAYLOAD_MAX);
    r->recv_utime = rbuf->recv_utime;
    r->lcm = rbuf->lcm;
}

static void on_message_too(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    on_message(rbuf, channel, user);
}

static int64_t realtime_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

/* Polls the receiver until *count reaches want or a second passes. */
static void wait_for(const uint64_t *count, uint64_t want)
{
    for (int i = 0; i < 100 && *count < want; ++i) {
        struct pollfd p = {vl_lcm_rx_fd(&g_rx), POLLIN, 0};
        if (poll(&p, 1, 10) == 1) {
            TEST_ASSERT_TRUE(vl_lcm_rx_poll(&g_rx, 64) >= 0);
        }
    }
}

/* liblcm and the receiver on URL, or the test ignored where multicast is not routed. */
static void open_both(void)
{
    char err[256];
    g_lcm = lcm_create(URL);
    if (g_lcm == NULL || vl_lcm_rx_open(&g_rx, URL, g_lcm, err, sizeof(err)) != 0) {
        TEST_IGNORE_MESSAGE("no multicast route here (run it as CTest does, in unshare --net)");
    }
}

void test_other_providers_are_left_to_liblcm(void)
{
    char err[64] = "";
    TEST_ASSERT_EQUAL_INT(1, vl_lcm_rx_open(&g_rx, "memq://", NULL, err, sizeof(err)));
    TEST_ASSERT_EQUAL_INT(-1, vl_lcm_rx_fd(&g_rx));
    TEST_ASSERT_EQUAL_INT(1, vl_lcm_rx_open(&g_rx, "tcpq://localhost:7700", NULL, err, sizeof(err)));
    TEST_ASSERT_EQUAL_STRING("", err);
}

void test_a_udpm_url_without_a_multicast_group_is_an_error(void)
{
    char err[256] = "";
    TEST_ASSERT_EQUAL_INT(-1, vl_lcm_rx_open(&g_rx, "udpm://10.1.2.3:7667", NULL, err, sizeof(err)));
    TEST_ASSERT_NOT_NULL(strstr(err, "udpm://10.1.2.3:7667"));
    TEST_ASSERT_EQUAL_INT(-1, vl_lcm_rx_open(&g_rx, "udpm://239.255.76.67:70000", NULL, err, sizeof(err)));
    TEST_ASSERT_EQUAL_INT(-1, vl_lcm_rx_fd(&g_rx));
}

void test_a_message_from_liblcm_reaches_its_handler_whole(void)
{
    open_both();
    received_t a;
    memset(&a, 0, sizeof(a));
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_subscribe(&g_rx, "VL_TEST_A", on_message, &a));
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_poll(&g_rx, 64)); /* nothing yet: no blocking, no call */
    uint8_t payload[200];
    for (int i = 0; i < 200; ++i) {
        payload[i] = (uint8_t)(i * 7 + 3);
    }
    const int64_t before = realtime_us();
    TEST_ASSERT_EQUAL_INT(0, lcm_publish(g_lcm, "VL_TEST_B", payload, 10)); /* not subscribed */
    TEST_ASSERT_EQUAL_INT(0, lcm_publish(g_lcm, "VL_TEST_A", payload, sizeof(payload)));
    wait_for(&g_rx.messages, 1);
    const int64_t after = realtime_us();
    TEST_ASSERT_EQUAL_INT(1, a.calls);
    TEST_ASSERT_EQUAL_STRING("VL_TEST_A", a.channel);
    TEST_ASSERT_EQUAL_UINT32(sizeof(payload), a.size);
    TEST_ASSERT_EQUAL_MEMORY(payload, a.data, sizeof(payload));
    TEST_ASSERT_TRUE(a.lcm == g_lcm);
    /* The kernel's receive stamp, on the real-time clock, between the publish and the handler. */
    TEST_ASSERT_TRUE(a.recv_utime >= before && a.recv_utime <= after);
    TEST_ASSERT_EQUAL_UINT64(1, g_rx.other);
    TEST_ASSERT_EQUAL_UINT64(0, g_rx.malformed + g_rx.fragments);
}

void test_fragments_and_foreign_datagrams_are_counted_not_handed_over(void)
{
    open_both();
    received_t a;
    memset(&a, 0, sizeof(a));
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_subscribe(&g_rx, "VL_TEST_A", on_message, &a));
    static uint8_t large[100000]; /* liblcm fragments it: two datagrams */
    TEST_ASSERT_EQUAL_INT(0, lcm_publish(g_lcm, "VL_TEST_A", large, sizeof(large)));
    const int s = socket(AF_INET, SOCK_DGRAM, 0);
    TEST_ASSERT_TRUE(s >= 0);
    struct sockaddr_in to;
    memset(&to, 0, sizeof(to));
    to.sin_family = AF_INET;
    to.sin_port = htons(7667);
    TEST_ASSERT_EQUAL_INT(1, inet_pton(AF_INET, "239.255.76.67", &to.sin_addr));
    static const uint8_t short_garbage[] = {'x', 'y', 'z'};
    static const uint8_t unterminated[] = {0x4c, 0x43, 0x30, 0x32, 0, 0, 0, 1, 'V', 'L'};
    static const uint8_t wrong_magic[] = {0x12, 0x34, 0x56, 0x78, 0, 0, 0, 1, 'V', 0, 1, 2};
    sendto(s, short_garbage, sizeof(short_garbage), 0, (const struct sockaddr *)&to, sizeof(to));
    sendto(s, unterminated, sizeof(unterminated), 0, (const struct sockaddr *)&to, sizeof(to));
    sendto(s, wrong_magic, sizeof(wrong_magic), 0, (const struct sockaddr *)&to, sizeof(to));
    close(s);
    TEST_ASSERT_EQUAL_INT(0, lcm_publish(g_lcm, "VL_TEST_A", "ok", 2)); /* still received after them */
    wait_for(&g_rx.messages, 1);
    TEST_ASSERT_EQUAL_INT(1, a.calls);
    TEST_ASSERT_EQUAL_UINT32(2, a.size);
    TEST_ASSERT_EQUAL_UINT64(2, g_rx.fragments);
    TEST_ASSERT_EQUAL_UINT64(3, g_rx.malformed);
}

void test_every_subscription_of_a_channel_is_called_until_unsubscribed(void)
{
    open_both();
    received_t a, b;
    memset(&a, 0, sizeof(a));
    memset(&b, 0, sizeof(b));
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_subscribe(&g_rx, "VL_TEST_A", on_message, &a));
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_subscribe(&g_rx, "VL_TEST_A", on_message_too, &b));
    TEST_ASSERT_EQUAL_INT(0, lcm_publish(g_lcm, "VL_TEST_A", "1", 1));
    wait_for(&g_rx.messages, 1);
    TEST_ASSERT_EQUAL_INT(1, a.calls);
    TEST_ASSERT_EQUAL_INT(1, b.calls);
    TEST_ASSERT_EQUAL_INT(1, vl_lcm_rx_unsubscribe(&g_rx, "VL_TEST_A", on_message_too));
    TEST_ASSERT_EQUAL_INT(0, lcm_publish(g_lcm, "VL_TEST_A", "2", 1));
    wait_for(&g_rx.messages, 2);
    TEST_ASSERT_EQUAL_INT(2, a.calls);
    TEST_ASSERT_EQUAL_INT(1, b.calls);
    /* A name that does not fit, and a full table, are refused. */
    char name[VL_LCM_RX_CHANNEL_MAX + 1];
    memset(name, 'N', sizeof(name) - 1);
    name[sizeof(name) - 1] = '\0';
    TEST_ASSERT_EQUAL_INT(-1, vl_lcm_rx_subscribe(&g_rx, name, on_message, &a));
    int added = 0;
    while (vl_lcm_rx_subscribe(&g_rx, "VL_TEST_C", on_message, &a) == 0) {
        added++;
    }
    TEST_ASSERT_EQUAL_INT(VL_LCM_RX_MAX_SUBSCRIPTIONS - 1, added);
}

/* Waits up to a second for a datagram on the receiver's socket; 1 when one is there. */
static int readable(void)
{
    struct pollfd p = {vl_lcm_rx_fd(&g_rx), POLLIN, 0};
    return poll(&p, 1, 1000) == 1;
}

void test_peek_shows_the_next_message_and_leaves_it_for_poll(void)
{
    open_both();
    received_t a;
    memset(&a, 0, sizeof(a));
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_subscribe(&g_rx, "VL_TEST_A", on_message, &a));
    vl_lcm_rx_peek_t next;
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_peek(&g_rx, &next)); /* nothing waiting: no blocking */
    uint8_t payload[200];
    for (int i = 0; i < 200; ++i) {
        payload[i] = (uint8_t)(i * 5 + 1);
    }
    TEST_ASSERT_EQUAL_INT(0, lcm_publish(g_lcm, "VL_TEST_A", payload, sizeof(payload)));
    TEST_ASSERT_EQUAL_INT(0, lcm_publish(g_lcm, "VL_TEST_B", "xy", 2));
    TEST_ASSERT_TRUE(readable());
    for (int k = 0; k < 2; ++k) { /* looking twice takes nothing */
        memset(&next, 0, sizeof(next));
        TEST_ASSERT_EQUAL_INT(1, vl_lcm_rx_peek(&g_rx, &next));
        TEST_ASSERT_EQUAL_STRING("VL_TEST_A", next.channel);
        TEST_ASSERT_EQUAL_UINT32(VL_LCM_RX_PEEK_MAX, (uint32_t)next.size); /* the first bytes only */
        TEST_ASSERT_EQUAL_MEMORY(payload, next.payload, VL_LCM_RX_PEEK_MAX);
    }
    TEST_ASSERT_EQUAL_INT(1, vl_lcm_rx_poll(&g_rx, 1)); /* the message peeked, whole */
    TEST_ASSERT_EQUAL_INT(1, a.calls);
    TEST_ASSERT_EQUAL_UINT32(sizeof(payload), a.size);
    TEST_ASSERT_EQUAL_MEMORY(payload, a.data, sizeof(payload));
    TEST_ASSERT_EQUAL_INT(1, vl_lcm_rx_peek(&g_rx, &next)); /* then the one behind it */
    TEST_ASSERT_EQUAL_STRING("VL_TEST_B", next.channel);
    TEST_ASSERT_EQUAL_UINT32(2, (uint32_t)next.size);
    TEST_ASSERT_EQUAL_MEMORY("xy", next.payload, 2);
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_poll(&g_rx, 64)); /* not subscribed: counted, not handed on */
    TEST_ASSERT_EQUAL_INT(0, vl_lcm_rx_peek(&g_rx, &next));
    /* Through liblcm nothing can be looked at. */
    vl_lcm_rx_close(&g_rx);
    vl_lcm_rx_use_lcm(&g_rx, g_lcm);
    TEST_ASSERT_EQUAL_INT(-1, vl_lcm_rx_peek(&g_rx, &next));
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_other_providers_are_left_to_liblcm);
    RUN_TEST(test_a_udpm_url_without_a_multicast_group_is_an_error);
    RUN_TEST(test_a_message_from_liblcm_reaches_its_handler_whole);
    RUN_TEST(test_fragments_and_foreign_datagrams_are_counted_not_handed_over);
    RUN_TEST(test_every_subscription_of_a_channel_is_called_until_unsubscribed);
    RUN_TEST(test_peek_shows_the_next_message_and_leaves_it_for_poll);
    return UNITY_END();
}
