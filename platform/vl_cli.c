#include "vl_cli.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>

#include "vl_version.h"

const char *vl_cli_version(void)
{
    return VL_VERSION_GIT[0] != '\0' ? VL_VERSION_PROJECT " (git " VL_VERSION_GIT ")" : VL_VERSION_PROJECT;
}

int vl_cli_print_version(FILE *f, const char *program)
{
    fprintf(f, "%s %s\n", program, vl_cli_version());
    return fflush(f) != 0 || ferror(f) ? -1 : 0;
}

void vl_cli_format_double(char *buf, size_t len, double v)
{
    if (buf == NULL || len == 0) {
        return;
    }
    if (!isfinite(v)) {
        snprintf(buf, len, "%g", v);
        return;
    }
    /* 17 digits always read back. For a normal number fewer than 15 never need trying: a shorter
       text that reads back lies within half an ulp (1.1e-16 relative) of v, so rounding v to 15
       digits gives that same text (%g drops the trailing zeros). Subnormals carry fewer digits. */
    for (int digits = fabs(v) >= DBL_MIN ? 15 : 1; digits < 17; ++digits) {
        snprintf(buf, len, "%.*g", digits, v);
        if (strtod(buf, NULL) == v) {
            return;
        }
    }
    snprintf(buf, len, "%.17g", v);
}
