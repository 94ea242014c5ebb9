/* INI configuration loader on top of libinih. */
#include "vl_config_file.h"

#include <errno.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <ini.h>

#include "vl_cli.h"

typedef enum {
    KEY_DOUBLE,   /* double member of vl_config_t */
    KEY_UINT32,   /* uint32_t member of vl_config_t */
    KEY_BOOL,     /* int member of vl_config_t, true|false */
    KEY_MODE,     /* vl_mode_t */
    KEY_PRESET,   /* applied in the first pass */
    KEY_OVERRIDE, /* [calibration] override_log, not part of vl_config_t */
    KEY_CAM_T_IMU /* 16 numbers, may continue on indented lines */
} key_type_t;

typedef struct {
    const char *section;
    const char *name;
    key_type_t type;
    size_t offset;       /* into vl_config_t, for the value types */
    double min;          /* inclusive unless min_open */
    double max;          /* inclusive */
    int min_open;        /* nonzero: value must be strictly greater than min */
    int calibration;     /* one of the six keys that make a complete calibration */
    const char *units;   /* "" when none */
    const char *meaning; /* one paragraph, for the annotated writer */
    const char *example; /* calibration and preset: the value tools/vislam.ini shows */
} key_def_t;

#define CFG_OFF(member) offsetof(vl_config_t, member)

/* A row of the schema (vislam/vl_config_schema.h) as a key of this reader and writer. */
#define SCHEMA_KEY(section_, key_, field_, type_, def_, min_, max_, min_open_, units_, meaning_) \
    {.section = section_,                                                                        \
     .name = key_,                                                                               \
     .type = KEY_##type_,                                                                        \
     .offset = CFG_OFF(field_),                                                                  \
     .min = (double)(min_),                                                                      \
     .max = (double)(max_),                                                                      \
     .min_open = min_open_,                                                                      \
     .units = units_,                                                                            \
     .meaning = meaning_},

/* The schema's keys, plus the ones that are not plain values of vl_config_t: the preset
   (applied before every other key) and the calibration (a rig, checked as a whole, that
   normally comes from the log). Their texts live here because only the file has them. */
static const key_def_t k_keys[] = {
    {.section = "estimator",
     .name = "preset",
     .type = KEY_PRESET,
     .units = "",
     .example = "default",
     .meaning = "Tuning preset applied FIRST, wherever this line appears; the other keys of the file then "
                "change it. default = the tuned defaults listed here; seed = the seed project's noise "
                "(W = diag(1e-5 I3, 1e-4 I3) per 0.1 s step, V = 3500 I4), no offset states, no outlier "
                "rejection. A preset keeps the calibration. Leave the key out to start from whatever the "
                "program gives (vislam-run: the defaults, or --preset)."},
    VL_CONFIG_KEYS(SCHEMA_KEY){.section = "calibration",
                               .name = "override_log",
                               .type = KEY_OVERRIDE,
                               .units = "",
                               .example = "false",
                               .meaning = "true: use this section even when the log carries a calibration."},
    {.section = "calibration",
     .name = "fx",
     .type = KEY_DOUBLE,
     .offset = CFG_OFF(calibration.fx),
     .max = DBL_MAX,
     .min_open = 1,
     .calibration = 1,
     .units = "px",
     .example = "700",
     .meaning = "Horizontal focal length."},
    {.section = "calibration",
     .name = "fy",
     .type = KEY_DOUBLE,
     .offset = CFG_OFF(calibration.fy),
     .max = DBL_MAX,
     .min_open = 1,
     .calibration = 1,
     .units = "px",
     .example = "700",
     .meaning = "Vertical focal length."},
    {.section = "calibration",
     .name = "cx",
     .type = KEY_DOUBLE,
     .offset = CFG_OFF(calibration.cx),
     .min = -DBL_MAX,
     .max = DBL_MAX,
     .calibration = 1,
     .units = "px",
     .example = "600",
     .meaning = "Principal point, horizontal."},
    {.section = "calibration",
     .name = "cy",
     .type = KEY_DOUBLE,
     .offset = CFG_OFF(calibration.cy),
     .min = -DBL_MAX,
     .max = DBL_MAX,
     .calibration = 1,
     .units = "px",
     .example = "180",
     .meaning = "Principal point, vertical."},
    {.section = "calibration",
     .name = "baseline",
     .type = KEY_DOUBLE,
     .offset = CFG_OFF(calibration.baseline),
     .max = DBL_MAX,
     .min_open = 1,
     .calibration = 1,
     .units = "m",
     .example = "0.5",
     .meaning = "Stereo baseline."},
    {.section = "calibration",
     .name = "cam_T_imu",
     .type = KEY_CAM_T_IMU,
     .offset = CFG_OFF(calibration.cam_T_imu),
     .calibration = 1,
     .units = "",
     .example = "0 -1  0 0\n"
                "0  0 -1 0\n"
                "1  0  0 0\n"
                "0  0  0 1",
     .meaning = "4x4 row-major transform from the IMU frame to the left camera optical frame (x right, y "
                "down, z forward): 16 numbers separated by spaces or commas; the rows may continue on "
                "indented lines. Must be rigid (orthonormal rotation, det +1, last row 0 0 0 1)."},
};

#define NUM_KEYS (sizeof(k_keys) / sizeof(k_keys[0]))
#define NUM_CALIBRATION_KEYS 6

/* Feeds inih one line at a time and knows which line it handed out last,
   because this libinih is built without line numbers in the handler. */
typedef struct {
    FILE *f;
    int line;          /* 1-based number of the line inih is processing */
    int at_line_start; /* the previous chunk ended a line */
    int indented;      /* current line starts with whitespace (an inih continuation) */
    int too_long_line; /* first line longer than inih's buffer, 0 if none */
} line_reader_t;

typedef struct {
    const char *path;
    line_reader_t *reader;
    int pass;        /* 1: find the preset; 2: apply every key */
    vl_config_t cfg; /* working copy, committed only on success */
    vl_config_file_info_t info;
    int seen_line[NUM_KEYS]; /* line where each key was set, 0 if not */
    int last_key;            /* index of the previous key, for continuations; -1 none */
    int cam_count;           /* numbers of cam_T_imu read so far */
    int preset_line;
    char preset_value[32];
    char *err;
    size_t err_len;
    int failed;
} load_ctx_t;

static void set_error(load_ctx_t *ctx, const char *fmt, ...)
{
    if (ctx->failed) {
        return; /* the first error is the useful one */
    }
    ctx->failed = 1;
    if (ctx->err != NULL && ctx->err_len > 0) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(ctx->err, ctx->err_len, fmt, ap);
        va_end(ap);
    }
}

static void key_error(load_ctx_t *ctx, const char *section, const char *name, const char *fmt, ...)
{
    if (ctx->failed) {
        return;
    }
    char reason[256];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(reason, sizeof(reason), fmt, ap);
    va_end(ap);
    if (section[0] == '\0') {
        set_error(ctx, "%s:%d: %s: %s", ctx->path, ctx->reader->line, name, reason);
    } else {
        set_error(ctx, "%s:%d: [%s] %s: %s", ctx->path, ctx->reader->line, section, name, reason);
    }
}

static char *read_line(char *str, int num, void *stream)
{
    line_reader_t *lr = (line_reader_t *)stream;
    char *s = fgets(str, num, lr->f);
    if (s == NULL) {
        return NULL;
    }
    if (lr->at_line_start) {
        lr->line++;
        lr->indented = (s[0] == ' ' || s[0] == '\t');
    }
    size_t n = strlen(s);
    lr->at_line_start = n > 0 && s[n - 1] == '\n';
    if (!lr->at_line_start) {
        int c = fgetc(lr->f);
        if (c != EOF) {
            /* inih would parse the rest of the line as a new line: refuse the file instead. */
            if (lr->too_long_line == 0) {
                lr->too_long_line = lr->line;
            }
            while (c != EOF && c != '\n') {
                c = fgetc(lr->f);
            }
        }
        lr->at_line_start = 1;
    }
    return s;
}

/* strtod over the whole token, finite only. */
static int parse_double(const char *text, double *out)
{
    if (text == NULL || *text == '\0') {
        return -1;
    }
    char *end = NULL;
    errno = 0;
    double v = strtod(text, &end);
    if (end == text || *end != '\0' || errno == ERANGE || !isfinite(v)) {
        return -1;
    }
    *out = v;
    return 0;
}

static int parse_bool(const char *text, int *out)
{
    if (strcmp(text, "true") == 0) {
        *out = 1;
        return 0;
    }
    if (strcmp(text, "false") == 0) {
        *out = 0;
        return 0;
    }
    return -1;
}

static int find_key(const char *section, const char *name, int *section_known)
{
    *section_known = 0;
    for (size_t i = 0; i < NUM_KEYS; ++i) {
        if (strcmp(k_keys[i].section, section) == 0) {
            *section_known = 1;
            if (strcmp(k_keys[i].name, name) == 0) {
                return (int)i;
            }
        }
    }
    return -1;
}

static int check_range(load_ctx_t *ctx, const key_def_t *k, double v)
{
    int low = k->min_open ? !(v > k->min) : !(v >= k->min);
    if (low || v > k->max) {
        char value[VL_CLI_DOUBLE_MAX], lo[VL_CLI_DOUBLE_MAX], hi[VL_CLI_DOUBLE_MAX];
        vl_cli_format_double(value, sizeof(value), v);
        vl_cli_format_double(lo, sizeof(lo), k->min);
        vl_cli_format_double(hi, sizeof(hi), k->max);
        if (k->max == DBL_MAX) {
            key_error(ctx, k->section, k->name, "%s is out of range: must be %s %s", value,
                      k->min_open ? ">" : ">=", lo);
        } else if (k->min == -DBL_MAX) {
            key_error(ctx, k->section, k->name, "%s is out of range: must be <= %s", value, hi);
        } else {
            key_error(ctx, k->section, k->name, "%s is out of range %s%s, %s]", value, k->min_open ? "(" : "[", lo, hi);
        }
        return -1;
    }
    return 0;
}

/* Appends the numbers of one line of cam_T_imu (separated by spaces or commas). */
static int parse_cam_numbers(load_ctx_t *ctx, const key_def_t *k, const char *value)
{
    double *m = (double *)((char *)&ctx->cfg + k->offset);
    char token[64];
    const char *p = value;
    for (;;) {
        while (*p == ' ' || *p == '\t' || *p == ',') {
            ++p;
        }
        if (*p == '\0') {
            return 0;
        }
        size_t n = strcspn(p, " \t,");
        if (n >= sizeof(token)) {
            key_error(ctx, k->section, k->name, "number too long");
            return -1;
        }
        memcpy(token, p, n);
        token[n] = '\0';
        p += n;
        double v;
        if (parse_double(token, &v) != 0) {
            key_error(ctx, k->section, k->name, "'%s' is not a finite number", token);
            return -1;
        }
        if (ctx->cam_count >= 16) {
            key_error(ctx, k->section, k->name, "more than 16 numbers");
            return -1;
        }
        m[ctx->cam_count++] = v;
    }
}

/* A rigid transform: last row 0 0 0 1, orthonormal right-handed rotation. */
static int check_rigid(const double *m)
{
    if (m[12] != 0.0 || m[13] != 0.0 || m[14] != 0.0 || m[15] != 1.0) {
        return -1;
    }
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            double dot = 0.0;
            for (int c = 0; c < 3; ++c) {
                dot += m[4 * i + c] * m[4 * j + c];
            }
            if (fabs(dot - (i == j ? 1.0 : 0.0)) > 1e-6) {
                return -1;
            }
        }
    }
    double det =
        m[0] * (m[5] * m[10] - m[6] * m[9]) - m[1] * (m[4] * m[10] - m[6] * m[8]) + m[2] * (m[4] * m[9] - m[5] * m[8]);
    return det > 0.0 ? 0 : -1;
}

static int handle_pass1(load_ctx_t *ctx, const char *section, const char *name, const char *value)
{
    if (strcmp(section, "estimator") == 0 && strcmp(name, "preset") == 0 && ctx->preset_line == 0) {
        ctx->preset_line = ctx->reader->line;
        snprintf(ctx->preset_value, sizeof(ctx->preset_value), "%s", value);
    }
    return 1;
}

static int handle_key(load_ctx_t *ctx, int idx, const char *value)
{
    const key_def_t *k = &k_keys[idx];
    char *member = (char *)&ctx->cfg + k->offset;
    double v;
    switch (k->type) {
    case KEY_DOUBLE:
        if (parse_double(value, &v) != 0) {
            key_error(ctx, k->section, k->name, "'%s' is not a finite number", value);
            return -1;
        }
        if (check_range(ctx, k, v) != 0) {
            return -1;
        }
        *(double *)member = v;
        return 0;
    case KEY_UINT32: {
        char *end = NULL;
        errno = 0;
        long long n = strtoll(value, &end, 10);
        if (*value == '\0' || end == value || *end != '\0' || errno == ERANGE) {
            key_error(ctx, k->section, k->name, "'%s' is not an integer", value);
            return -1;
        }
        if (check_range(ctx, k, (double)n) != 0) {
            return -1;
        }
        *(uint32_t *)member = (uint32_t)n;
        return 0;
    }
    case KEY_BOOL: {
        int b;
        if (parse_bool(value, &b) != 0) {
            key_error(ctx, k->section, k->name, "'%s' is not true or false", value);
            return -1;
        }
        *(int *)member = b;
        return 0;
    }
    case KEY_MODE: {
        vl_mode_t mode;
        if (vl_mode_from_name(value, &mode) != 0) {
            key_error(ctx, k->section, k->name, "'%s' is not imu_only, mapping or slam", value);
            return -1;
        }
        *(vl_mode_t *)member = mode;
        return 0;
    }
    case KEY_PRESET: {
        vl_preset_t preset;
        if (vl_preset_from_name(value, &preset) != 0) {
            key_error(ctx, k->section, k->name, "'%s' is not default or seed", value);
            return -1;
        }
        return 0; /* applied before this pass */
    }
    case KEY_OVERRIDE: {
        int b;
        if (parse_bool(value, &b) != 0) {
            key_error(ctx, k->section, k->name, "'%s' is not true or false", value);
            return -1;
        }
        ctx->info.override_log = b;
        return 0;
    }
    case KEY_CAM_T_IMU:
        return parse_cam_numbers(ctx, k, value);
    }
    return -1;
}

static int handle_pass2(load_ctx_t *ctx, const char *section, const char *name, const char *value)
{
    int section_known;
    int idx = find_key(section, name, &section_known);
    if (idx < 0) {
        if (section[0] == '\0') {
            key_error(ctx, "", name, "key outside any section");
        } else if (!section_known) {
            key_error(ctx, section, name, "unknown section [%s]", section);
        } else {
            key_error(ctx, section, name, "unknown key");
        }
        ctx->last_key = -1;
        return 0;
    }
    const key_def_t *k = &k_keys[idx];
    const int continuation = ctx->reader->indented && idx == ctx->last_key;
    if (continuation && k->type != KEY_CAM_T_IMU) {
        key_error(ctx, section, name, "continuation lines are only allowed for cam_T_imu");
        return 0;
    }
    if (ctx->seen_line[idx] != 0 && !continuation) {
        key_error(ctx, section, name, "set twice (first on line %d)", ctx->seen_line[idx]);
        return 0;
    }
    if (!continuation) {
        ctx->seen_line[idx] = ctx->reader->line;
        ctx->info.keys_set++;
    }
    ctx->last_key = idx;
    return handle_key(ctx, idx, value) == 0 ? 1 : 0;
}

static int on_ini_entry(void *user, const char *section, const char *name, const char *value)
{
    load_ctx_t *ctx = (load_ctx_t *)user;
    if (ctx->failed) {
        return 1; /* already failed: let inih finish quietly */
    }
    if (value == NULL) {
        value = "";
    }
    return ctx->pass == 1 ? handle_pass1(ctx, section, name, value) : handle_pass2(ctx, section, name, value);
}

static int parse_pass(load_ctx_t *ctx, FILE *f, int pass)
{
    line_reader_t reader;
    memset(&reader, 0, sizeof(reader));
    reader.f = f;
    reader.at_line_start = 1;
    ctx->reader = &reader;
    ctx->pass = pass;
    ctx->last_key = -1;
    rewind(f);
    int rc = ini_parse_stream(read_line, &reader, on_ini_entry, ctx);
    if (reader.too_long_line != 0) {
        ctx->failed = 0; /* the overlong line explains any later confusion best */
        set_error(ctx,
                  "%s:%d: line too long (inih reads at most 197 characters; split cam_T_imu "
                  "over indented continuation lines)",
                  ctx->path, reader.too_long_line);
        return -1;
    }
    if (ferror(f)) {
        set_error(ctx, "%s: read error: %s", ctx->path, strerror(errno));
        return -1;
    }
    if (ctx->failed) {
        return -1;
    }
    if (rc > 0) {
        set_error(ctx, "%s:%d: syntax error (expected [section], key = value, or a ; or # comment)", ctx->path, rc);
        return -1;
    }
    if (rc < 0) {
        set_error(ctx, "%s: inih failed (%d)", ctx->path, rc);
        return -1;
    }
    return 0;
}

static int finish_calibration(load_ctx_t *ctx)
{
    int set = 0;
    const char *missing = NULL;
    int cam_idx = -1;
    int override_idx = -1;
    for (size_t i = 0; i < NUM_KEYS; ++i) {
        if (k_keys[i].type == KEY_CAM_T_IMU) {
            cam_idx = (int)i;
        }
        if (k_keys[i].type == KEY_OVERRIDE) {
            override_idx = (int)i;
        }
        if (!k_keys[i].calibration) {
            continue;
        }
        if (ctx->seen_line[i] != 0) {
            ++set;
        } else if (missing == NULL) {
            missing = k_keys[i].name;
        }
    }
    if (cam_idx >= 0 && ctx->seen_line[cam_idx] != 0) {
        if (ctx->cam_count != 16) {
            set_error(ctx, "%s:%d: [calibration] cam_T_imu: %d numbers, expected 16 (row-major 4x4)", ctx->path,
                      ctx->seen_line[cam_idx], ctx->cam_count);
            return -1;
        }
        if (check_rigid(ctx->cfg.calibration.cam_T_imu) != 0) {
            set_error(ctx,
                      "%s:%d: [calibration] cam_T_imu: not a rigid transform (rotation must be "
                      "orthonormal with det +1, last row 0 0 0 1)",
                      ctx->path, ctx->seen_line[cam_idx]);
            return -1;
        }
    }
    if (set != 0 && set != NUM_CALIBRATION_KEYS) {
        set_error(ctx,
                  "%s: [calibration] is incomplete: %s is missing (give fx fy cx cy baseline cam_T_imu, "
                  "or none of them)",
                  ctx->path, missing);
        return -1;
    }
    if (ctx->info.override_log && set == 0) {
        set_error(ctx, "%s:%d: [calibration] override_log: true, but the file gives no calibration", ctx->path,
                  ctx->seen_line[override_idx]);
        return -1;
    }
    ctx->info.has_calibration = set == NUM_CALIBRATION_KEYS;
    return 0;
}

static int calibration_valid(const vl_config_t *cfg)
{
    vl_config_t probe;
    vl_config_default(&probe);
    probe.calibration = cfg->calibration;
    return vl_config_check(&probe) == VL_OK;
}

static void set_placeholder_calibration(vl_calibration_t *c)
{
    memset(c, 0, sizeof(*c));
    c->fx = 1.0;
    c->fy = 1.0;
    c->baseline = 1.0;
    c->cam_T_imu[0] = c->cam_T_imu[5] = c->cam_T_imu[10] = c->cam_T_imu[15] = 1.0;
}

vl_status_t vl_config_load_ini_ex(const char *path, vl_config_t *cfg, vl_config_file_info_t *info, char *err,
                                  size_t err_len)
{
    if (err != NULL && err_len > 0) {
        err[0] = '\0';
    }
    if (path == NULL || cfg == NULL) {
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "vl_config_load_ini: NULL argument");
        }
        return VL_ERR_NULL;
    }
    /* About 8 KB: static would not be reentrant, and this is not a hot path. */
    load_ctx_t *ctx = (load_ctx_t *)calloc(1, sizeof(*ctx));
    if (ctx == NULL) {
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "%s: out of memory", path);
        }
        return VL_ERR_CONFIG;
    }
    ctx->path = path;
    ctx->cfg = *cfg;
    ctx->info.preset = VL_PRESET_NONE;
    ctx->err = err;
    ctx->err_len = err_len;

    vl_status_t status = VL_ERR_CONFIG;
    FILE *f = fopen(path, "r");
    if (f == NULL) {
        set_error(ctx, "%s: cannot open: %s", path, strerror(errno));
        goto done;
    }
    if (parse_pass(ctx, f, 1) != 0) {
        goto done;
    }
    if (ctx->preset_line != 0) {
        vl_preset_t preset;
        if (vl_preset_from_name(ctx->preset_value, &preset) != 0) {
            set_error(ctx, "%s:%d: [estimator] preset: '%s' is not default or seed", path, ctx->preset_line,
                      ctx->preset_value);
            goto done;
        }
        vl_config_apply_preset(&ctx->cfg, preset);
        ctx->info.preset = preset;
    }
    if (parse_pass(ctx, f, 2) != 0 || finish_calibration(ctx) != 0) {
        goto done;
    }
    /* Without a calibration in the file the rig comes from the log later, so check the
       rest with a stand-in rig rather than fail on the default's empty one. */
    vl_config_t checked = ctx->cfg;
    if (!ctx->info.has_calibration && !calibration_valid(&checked)) {
        set_placeholder_calibration(&checked.calibration);
    }
    if (vl_config_check(&checked) != VL_OK) {
        set_error(ctx,
                  "%s: the resulting configuration is rejected by vl_config_check "
                  "(every key is in range, so a combination of values is invalid)",
                  path);
        goto done;
    }
    *cfg = ctx->cfg;
    if (info != NULL) {
        *info = ctx->info;
    }
    status = VL_OK;
done:
    if (f != NULL) {
        fclose(f);
    }
    free(ctx);
    return status;
}

vl_status_t vl_config_load_ini(const char *path, vl_config_t *cfg, char *err, size_t err_len)
{
    return vl_config_load_ini_ex(path, cfg, NULL, err, err_len);
}

const char *vl_mode_name(vl_mode_t mode)
{
    switch (mode) {
    case VL_MODE_IMU_ONLY:
        return "imu_only";
    case VL_MODE_MAPPING:
        return "mapping";
    case VL_MODE_SLAM:
        return "slam";
    }
    return "?";
}

const char *vl_preset_name(vl_preset_t preset)
{
    switch (preset) {
    case VL_PRESET_DEFAULT:
        return "default";
    case VL_PRESET_SEED:
        return "seed";
    case VL_PRESET_NONE:
        break;
    }
    return "none";
}

int vl_mode_from_name(const char *name, vl_mode_t *mode)
{
    if (name == NULL || mode == NULL) {
        return -1;
    }
    if (strcmp(name, "imu_only") == 0) {
        *mode = VL_MODE_IMU_ONLY;
    } else if (strcmp(name, "mapping") == 0) {
        *mode = VL_MODE_MAPPING;
    } else if (strcmp(name, "slam") == 0) {
        *mode = VL_MODE_SLAM;
    } else {
        return -1;
    }
    return 0;
}

int vl_preset_from_name(const char *name, vl_preset_t *preset)
{
    if (name == NULL || preset == NULL) {
        return -1;
    }
    if (strcmp(name, "default") == 0) {
        *preset = VL_PRESET_DEFAULT;
    } else if (strcmp(name, "seed") == 0) {
        *preset = VL_PRESET_SEED;
    } else {
        return -1;
    }
    return 0;
}

void vl_config_apply_preset(vl_config_t *cfg, vl_preset_t preset)
{
    if (cfg == NULL || preset == VL_PRESET_NONE) {
        return;
    }
    vl_config_t fresh;
    if (preset == VL_PRESET_SEED) {
        vl_config_preset_seed(&fresh);
    } else {
        vl_config_default(&fresh);
    }
    /* The rig and the host's callbacks are not tuning: keep them. */
    fresh.calibration = cfg->calibration;
    fresh.landmark_sink = cfg->landmark_sink;
    fresh.landmark_sink_user = cfg->landmark_sink_user;
    fresh.log = cfg->log;
    fresh.log_user = cfg->log_user;
    fresh.parallel_for = cfg->parallel_for;
    fresh.parallel_ctx = cfg->parallel_ctx;
    *cfg = fresh;
}

/* The value of a single-valued key in cfg as the reader takes it; the preset's and
   override_log's, which cfg does not hold, as the example shows them. */
static void format_value(char *buf, size_t len, const key_def_t *k, const vl_config_t *cfg)
{
    const char *member = (const char *)cfg + k->offset;
    switch (k->type) {
    case KEY_DOUBLE:
        vl_cli_format_double(buf, len, *(const double *)member);
        return;
    case KEY_UINT32:
        snprintf(buf, len, "%u", (unsigned)*(const uint32_t *)member);
        return;
    case KEY_BOOL:
        snprintf(buf, len, "%s", *(const int *)member ? "true" : "false");
        return;
    case KEY_MODE:
        snprintf(buf, len, "%s", vl_mode_name(*(const vl_mode_t *)member));
        return;
    case KEY_PRESET:
    case KEY_OVERRIDE:
    case KEY_CAM_T_IMU:
        break;
    }
    snprintf(buf, len, "%s", k->example != NULL ? k->example : "");
}

/* A key's units and range, and its default for the schema keys: "m/s, > 0, default 0.5". */
static void format_attributes(char *buf, size_t len, const key_def_t *k)
{
    char lo[VL_CLI_DOUBLE_MAX], hi[VL_CLI_DOUBLE_MAX], range[96];
    vl_cli_format_double(lo, sizeof(lo), k->min);
    vl_cli_format_double(hi, sizeof(hi), k->max);
    switch (k->type) {
    case KEY_DOUBLE:
        if (k->min == -DBL_MAX && k->max == DBL_MAX) {
            snprintf(range, sizeof(range), "any number");
        } else if (k->max == DBL_MAX) {
            snprintf(range, sizeof(range), "%s %s", k->min_open ? ">" : ">=", lo);
        } else {
            snprintf(range, sizeof(range), "%s %s and <= %s", k->min_open ? ">" : ">=", lo, hi);
        }
        break;
    case KEY_UINT32:
        if (k->max == (double)UINT32_MAX) {
            snprintf(range, sizeof(range), "integer >= %s", lo);
        } else {
            snprintf(range, sizeof(range), "integer %s..%s", lo, hi);
        }
        break;
    case KEY_BOOL:
    case KEY_OVERRIDE:
        snprintf(range, sizeof(range), "true or false");
        break;
    case KEY_MODE:
        snprintf(range, sizeof(range), "imu_only, mapping or slam");
        break;
    case KEY_PRESET:
        snprintf(range, sizeof(range), "default or seed");
        break;
    case KEY_CAM_T_IMU:
        snprintf(range, sizeof(range), "16 numbers");
        break;
    }
    char def[48] = "";
    const int from_schema =
        k->type == KEY_DOUBLE || k->type == KEY_UINT32 || k->type == KEY_BOOL || k->type == KEY_MODE;
    if (from_schema && !k->calibration) {
        vl_config_t d;
        vl_config_default(&d);
        char value[32];
        format_value(value, sizeof(value), k, &d);
        snprintf(def, sizeof(def), ", default %s", value);
    }
    snprintf(buf, len, "%s%s%s%s", k->units, k->units[0] != '\0' ? ", " : "", range, def);
}

/* Writes text as ';' comment lines of at most 80 characters, broken between words. */
static void write_comment(FILE *f, const char *text)
{
    const int width = 80 - 2;
    const char *p = text;
    while (*p != '\0') {
        int used = 0;
        fputs(";", f);
        while (*p != '\0') {
            size_t word = strcspn(p, " ");
            if (used > 0 && used + 1 + (int)word > width) {
                break;
            }
            fprintf(f, " %.*s", (int)word, p);
            used += 1 + (int)word;
            p += word;
            while (*p == ' ') {
                ++p;
            }
        }
        fputs("\n", f);
    }
}

typedef enum {
    WRITE_PLAIN,     /* keys and values only */
    WRITE_ANNOTATED, /* each key after its meaning, units, range and default */
    WRITE_EXAMPLE    /* annotated, with the preset and an illustrative, commented-out [calibration] */
} write_style_t;

/* Section comments of the annotated file, for the sections that need one. */
static const char *section_comment(const char *section, write_style_t style)
{
    if (strcmp(section, "limits") == 0) {
        return "Robustness (README \"Robustness\"): inputs beyond these are refused and counted, and the "
               "estimator re-initializes when its inputs or its own state say it must. The defaults refuse "
               "nothing on clean data.";
    }
    if (strcmp(section, "calibration") == 0) {
        return style == WRITE_EXAMPLE
                   ? "Stereo rig. Normally it comes from the log's VISLAM_CALIB message and this "
                     "section is left out. When given, all six values are required (fx fy cx cy baseline cam_T_imu); "
                     "the log's calibration still wins unless override_log = true. The numbers below are only an "
                     "illustration, not a real rig."
                   : "Stereo rig. When given, all six values are required (fx fy cx cy baseline cam_T_imu); the "
                     "log's calibration still wins unless override_log = true.";
    }
    return NULL;
}

static int write_ini(FILE *f, const vl_config_t *cfg, int with_calibration, write_style_t style)
{
    if (f == NULL || cfg == NULL) {
        return -1;
    }
    const char *section = NULL;
    for (size_t i = 0; i < NUM_KEYS; ++i) {
        const key_def_t *k = &k_keys[i];
        const int is_calibration = strcmp(k->section, "calibration") == 0;
        const int commented = style == WRITE_EXAMPLE && is_calibration;
        if ((is_calibration && !with_calibration && style != WRITE_EXAMPLE) ||
            ((k->type == KEY_PRESET || k->type == KEY_OVERRIDE) && style != WRITE_EXAMPLE)) {
            continue;
        }
        const int new_section = section == NULL || strcmp(section, k->section) != 0;
        if (new_section) {
            fprintf(f, "%s[%s]\n", section == NULL ? "" : "\n", k->section);
            section = k->section;
            const char *comment = style != WRITE_PLAIN ? section_comment(section, style) : NULL;
            if (comment != NULL) {
                write_comment(f, comment);
                fputs(commented ? ";\n" : "\n", f);
            }
        }
        if (style != WRITE_PLAIN) {
            char attributes[160];
            format_attributes(attributes, sizeof(attributes), k);
            if (!new_section) {
                fputs(commented ? ";\n" : "\n", f);
            }
            write_comment(f, k->meaning);
            fprintf(f, "; %s\n", attributes);
        }
        const char *lead = commented ? "; " : "";
        if (k->type == KEY_CAM_T_IMU && !commented) {
            /* One row per line keeps each line under inih's 200-character limit. */
            const double *m = (const double *)((const char *)cfg + k->offset);
            for (int r = 0; r < 4; ++r) {
                fprintf(f, "%s", r == 0 ? "cam_T_imu =" : "           ");
                for (int c = 0; c < 4; ++c) {
                    char number[VL_CLI_DOUBLE_MAX];
                    vl_cli_format_double(number, sizeof(number), m[4 * r + c]);
                    fprintf(f, " %s", number);
                }
                fputs("\n", f);
            }
        } else if (k->type == KEY_CAM_T_IMU) {
            const char *row = k->example;
            for (int r = 0; *row != '\0'; ++r) {
                size_t n = strcspn(row, "\n");
                fprintf(f, "%s%s %.*s\n", lead, r == 0 ? "cam_T_imu =" : "           ", (int)n, row);
                row += n + (row[n] == '\n');
            }
        } else if (commented || k->type == KEY_PRESET || k->type == KEY_OVERRIDE) {
            fprintf(f, "%s%s = %s\n", lead, k->name, k->example);
        } else {
            char value[48];
            format_value(value, sizeof(value), k, cfg);
            fprintf(f, "%s = %s\n", k->name, value);
        }
    }
    /* Flushed here, so a closed pipe or a full disk is this call's error, not a silent exit. */
    return fflush(f) != 0 || ferror(f) ? -1 : 0;
}

int vl_config_write_ini(FILE *f, const vl_config_t *cfg, int with_calibration)
{
    return write_ini(f, cfg, with_calibration, WRITE_PLAIN);
}

int vl_config_write_ini_annotated(FILE *f, const vl_config_t *cfg, int with_calibration)
{
    return write_ini(f, cfg, with_calibration, WRITE_ANNOTATED);
}

int vl_config_write_example(FILE *f)
{
    if (f == NULL) {
        return -1;
    }
    write_comment(f, "vislam configuration: every key, set to its default (vl_config_default).");
    fputs(";\n", f);
    write_comment(f, "Generated from the schema in core/include/vislam/vl_config_schema.h by "
                     "vl_config_write_example(): do not edit by hand. After changing the schema, "
                     "regenerate it with");
    fputs(";   build/bin/test_config_file --write-example tools/vislam.ini\n", f);
    write_comment(f, "(test_config_file fails while this file differs from what the schema gives).");
    fputs(";\n", f);
    write_comment(f, "Used by vislam-run --config FILE and vislamd --config FILE. The file is applied on top "
                     "of the defaults; any key may be left out. Parsing is strict: an unknown section or key, "
                     "a repeated key, a number that does not parse completely, or an out-of-range value stops "
                     "the program with \"FILE:LINE: [section] key: reason\". Comments start with ; or # at "
                     "the start of a line, or \" ;\" after a value. Lines are limited to 197 characters "
                     "(libinih). Each key follows its meaning, then its units, range and default.");
    fputs("\n", f);
    vl_config_t cfg;
    vl_config_default(&cfg);
    return write_ini(f, &cfg, 1, WRITE_EXAMPLE);
}
