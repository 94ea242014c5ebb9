/* Tests of the command-line conventions (platform/vl_cli): the version line and shortest doubles. */
#define _POSIX_C_SOURCE 200809L /* fmemopen */

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "unity.h"
#include "vl_cli.h"

void setUp(void)
{
}

void tearDown(void)
{
}

static void assert_formats(double v, const char *expected)
{
    char buf[VL_CLI_DOUBLE_MAX];
    vl_cli_format_double(buf, sizeof(buf), v);
    TEST_ASSERT_EQUAL_STRING(expected, buf);
}

static void test_format_shortest_known_values(void)
{
    assert_formats(0.05, "0.05");
    assert_formats(0.1, "0.1");
    assert_formats(0.1 + 0.2, "0.30000000000000004");
    assert_formats(1.5, "1.5");
    assert_formats(128.0, "128");
    assert_formats(1e-4, "0.0001");
    assert_formats(1e300, "1e+300");
    assert_formats(-2.5e-7, "-2.5e-07");
    assert_formats(0.0, "0");
    assert_formats(-0.0, "-0");
    assert_formats(DBL_MAX, "1.7976931348623157e+308");
    assert_formats(5e-324, "5e-324"); /* subnormal: fewer digits than 15 */
    assert_formats(2.2250738585072014e-308, "2.2250738585072014e-308");
    assert_formats(INFINITY, "inf");
    assert_formats(-INFINITY, "-inf");
}

/* Every text reads back to the same double, and one digit fewer would not (where fewer exist). */
static void test_format_round_trips_with_fewest_digits(void)
{
    uint64_t s = 0x9e3779b97f4a7c15ULL;
    for (int i = 0; i < 20000; ++i) {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        double v;
        if (i % 2 == 0) {
            uint64_t bits = s & 0x7fefffffffffffffULL; /* finite: exponent below all-ones */
            memcpy(&v, &bits, sizeof(v));
        } else {
            v = (double)(s >> 11) / 9007199254740992.0 * pow(10.0, (double)(i % 13) - 6.0);
        }
        char buf[VL_CLI_DOUBLE_MAX];
        vl_cli_format_double(buf, sizeof(buf), v);
        TEST_ASSERT_TRUE_MESSAGE(strtod(buf, NULL) == v, buf);
        /* the significant digits printed: those of the mantissa before 'e', from its first non-zero */
        int digits = 0;
        for (const char *c = buf; *c != '\0' && *c != 'e'; ++c) {
            digits += (*c >= '1' && *c <= '9') || (*c == '0' && digits > 0);
        }
        char shorter[320]; /* what %g may print, for the compiler */
        snprintf(shorter, sizeof(shorter), "%.*g", digits - 1, v);
        if (digits > 1) {
            TEST_ASSERT_TRUE_MESSAGE(strtod(shorter, NULL) != v, buf);
        }
    }
}

static void test_format_truncates_safely(void)
{
    char buf[4];
    vl_cli_format_double(buf, sizeof(buf), 0.30000000000000004);
    TEST_ASSERT_EQUAL_UINT(3, strlen(buf));
}

static void test_version_line(void)
{
    char out[256];
    FILE *f = fmemopen(out, sizeof(out), "w");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_EQUAL_INT(0, vl_cli_print_version(f, "prog"));
    fclose(f);
    char expected[256];
    snprintf(expected, sizeof(expected), "prog %s\n", vl_cli_version());
    TEST_ASSERT_EQUAL_STRING(expected, out);
    /* "MAJOR.MINOR.PATCH", then optionally " (git DESCRIPTION)" */
    const char *v = vl_cli_version();
    int major = -1, minor = -1, patch = -1, n = 0;
    TEST_ASSERT_EQUAL_INT(3, sscanf(v, "%d.%d.%d%n", &major, &minor, &patch, &n));
    TEST_ASSERT_TRUE(v[n] == '\0' || (strncmp(v + n, " (git ", 6) == 0 && v[strlen(v) - 1] == ')'));
}

static void test_version_write_error_is_reported(void)
{
    FILE *f = fopen("/dev/full", "w");
    if (f == NULL) {
        TEST_IGNORE_MESSAGE("no /dev/full");
    }
    TEST_ASSERT_EQUAL_INT(-1, vl_cli_print_version(f, "prog"));
    fclose(f);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_format_shortest_known_values);
    RUN_TEST(test_format_round_trips_with_fewest_digits);
    RUN_TEST(test_format_truncates_safely);
    RUN_TEST(test_version_line);
    RUN_TEST(test_version_write_error_is_reported);
    return UNITY_END();
}
