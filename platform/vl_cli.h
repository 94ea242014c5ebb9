/**
 * @file vl_cli.h
 * @brief Conventions every program's command line shares: the version line and how numbers print.
 *
 * `--version` prints one line, "PROGRAM VERSION (git DESCRIPTION)", from the CMake project
 * version and `git describe --always --dirty` at build time (the part in brackets is left out
 * when the sources were not a git checkout). Doubles meant to be read back, by a person or a
 * program, print with the fewest significant digits that read back to the same value.
 */
#ifndef VISLAM_PLATFORM_VL_CLI_H
#define VISLAM_PLATFORM_VL_CLI_H

#include <stddef.h>
#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Longest text vl_cli_format_double writes, with its terminating zero. */
#define VL_CLI_DOUBLE_MAX 32

/** The version without the program name: "0.1.0 (git 1a2b3c4-dirty)" or "0.1.0". */
const char *vl_cli_version(void);

/**
 * Prints "PROGRAM VERSION\n" on f and flushes it.
 * @return 0, or -1 on a write error (a closed pipe when SIGPIPE is ignored): the caller exits
 *         non-zero without a message, as a program whose reader went away should.
 */
int vl_cli_print_version(FILE *f, const char *program);

/**
 * v with the fewest significant digits (at most 17) that strtod reads back to the same double,
 * e.g. 0.05 as "0.05", not "0.050000000000000003"; infinities and NaN as printf spells them.
 * @param buf output, at least VL_CLI_DOUBLE_MAX bytes for the whole text (NULL or len 0: nothing written)
 */
void vl_cli_format_double(char *buf, size_t len, double v);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_CLI_H */
