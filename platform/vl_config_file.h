/**
 * @file vl_config_file.h
 * @brief Loads an estimator configuration from an INI file (libinih).
 *
 * The file is applied on top of whatever the configuration already holds
 * (start from vl_config_default). The keys are the rows of VL_CONFIG_KEYS
 * (vislam/vl_config_schema.h) plus [estimator] preset and [calibration];
 * tools/vislam.ini, written by vl_config_write_example, documents each one.
 * Parsing is strict: an unknown section or key, a repeated key, a value that
 * does not parse completely or is out of range gives VL_ERR_CONFIG and a
 * message "FILE:LINE: [section] key: reason", and leaves the caller's
 * configuration untouched.
 */
#ifndef VISLAM_PLATFORM_VL_CONFIG_FILE_H
#define VISLAM_PLATFORM_VL_CONFIG_FILE_H

#include <stddef.h>
#include <stdio.h>

#include "vislam/vislam.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Tuning presets selectable with [estimator] preset. */
typedef enum {
    VL_PRESET_NONE = -1,   /**< the file named no preset */
    VL_PRESET_DEFAULT = 0, /**< vl_config_default */
    VL_PRESET_SEED = 1     /**< vl_config_preset_seed */
} vl_preset_t;

/** What a loaded file said beyond the configuration values themselves. */
typedef struct {
    vl_preset_t preset;  /**< preset applied before the other keys, or VL_PRESET_NONE */
    int has_calibration; /**< nonzero: the file set the whole [calibration] (fx fy cx cy baseline cam_T_imu) */
    int override_log;    /**< nonzero: the file's calibration wins over a log's calibration message */
    unsigned keys_set;   /**< number of keys the file set */
} vl_config_file_info_t;

/**
 * Parses @p path on top of @p cfg, then runs vl_config_check.
 *
 * [estimator] preset is applied first wherever it appears; it replaces every
 * tuning value but keeps the calibration and the callbacks already in @p cfg.
 *
 * @param err     receives a one-line message on failure (may be NULL)
 * @return VL_OK, VL_ERR_NULL, or VL_ERR_CONFIG (unreadable file, syntax error,
 *         unknown key, bad or out-of-range value, rejected by vl_config_check);
 *         on failure @p cfg is unchanged.
 */
vl_status_t vl_config_load_ini(const char *path, vl_config_t *cfg, char *err, size_t err_len);

/** As vl_config_load_ini, also reporting preset and calibration details in @p info (may be NULL). */
vl_status_t vl_config_load_ini_ex(const char *path, vl_config_t *cfg, vl_config_file_info_t *info, char *err,
                                  size_t err_len);

/**
 * Writes @p cfg as an INI file that vl_config_load_ini reads back to the same
 * values: keys in the schema's order, numbers with the fewest significant
 * digits (15, 16 or 17) that read back to the same double. Callbacks are not written.
 * @param with_calibration nonzero to include the [calibration] section
 * @return 0, or -1 on a write error
 */
int vl_config_write_ini(FILE *f, const vl_config_t *cfg, int with_calibration);

/**
 * As vl_config_write_ini, with each key preceded by comments: its meaning,
 * then its units, range and default.
 */
int vl_config_write_ini_annotated(FILE *f, const vl_config_t *cfg, int with_calibration);

/**
 * Writes tools/vislam.ini: every key annotated and set to its default, the
 * preset line, and an illustrative [calibration] commented out. A test compares
 * the committed file with this output byte for byte.
 * @return 0, or -1 on a write error
 */
int vl_config_write_example(FILE *f);

/** "imu_only", "mapping", "slam", or "?" */
const char *vl_mode_name(vl_mode_t mode);

/** "default", "seed", or "none" */
const char *vl_preset_name(vl_preset_t preset);

/** Parses a mode name; 0 on success, -1 if unknown. */
int vl_mode_from_name(const char *name, vl_mode_t *mode);

/** Parses a preset name ("default" or "seed"); 0 on success, -1 if unknown. */
int vl_preset_from_name(const char *name, vl_preset_t *preset);

/**
 * Replaces every tuning value of @p cfg with a preset, keeping its
 * calibration and callbacks. VL_PRESET_NONE leaves @p cfg alone.
 */
void vl_config_apply_preset(vl_config_t *cfg, vl_preset_t preset);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_CONFIG_FILE_H */
