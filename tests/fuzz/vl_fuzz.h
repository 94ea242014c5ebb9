/**
 * @file vl_fuzz.h
 * @brief What the fuzz harnesses, their replay driver and the seed generator share.
 *
 * Each harness (fuzz_messages.c, fuzz_log_reader.c) defines LLVMFuzzerTestOneInput only.
 * Linked with libFuzzer (-DVL_FUZZ=ON, clang) it is fuzzed; linked with vl_fuzz_replay.c
 * (any compiler) it replays the files given on the command line, which is how the
 * regression inputs under tests/fuzz/regressions/ run in every build.
 *
 * Input format of fuzz_messages (the seed generator writes it, the harness reads it):
 *
 *   byte 0            configuration selector (VL_FUZZ_CFG_*)
 *   then records      [channel selector: 1 byte][payload length: 2 bytes, little-endian][payload]
 *
 * The channel selector modulo 3 is the channel (VL_FUZZ_CH_*); a length past the end of the
 * input is cut to what is left. Payloads are LCM-encoded messages, exactly as on the wire.
 */
#ifndef VISLAM_TESTS_VL_FUZZ_H
#define VISLAM_TESTS_VL_FUZZ_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** libFuzzer's entry point; the replay driver calls it once per file. Returns 0. */
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/** Channel selectors of fuzz_messages records (the selector byte modulo VL_FUZZ_NUM_CHANNELS). */
enum {
    VL_FUZZ_CH_IMU = 0,         /**< vislam.imu_t, as on VISLAM_IMU */
    VL_FUZZ_CH_FEATURES = 1,    /**< vislam.stereo_frame_t, as on VISLAM_FEATURES */
    VL_FUZZ_CH_CALIBRATION = 2, /**< vislam.calibration_t, as on VISLAM_CALIB */
    VL_FUZZ_NUM_CHANNELS = 3
};

/** Bytes before a record's payload: selector and 16-bit length. */
#define VL_FUZZ_RECORD_HEADER 3

/**
 * Bits of the configuration selector (byte 0 of a fuzz_messages input); 0 is the
 * default configuration, as vislamd runs without a config file.
 */
enum {
    VL_FUZZ_CFG_MODE_MASK = 0x03,   /**< 0 slam, 1 mapping, 2 imu_only, 3 slam */
    VL_FUZZ_CFG_PRESET_SEED = 0x04, /**< start from vl_config_preset_seed */
    VL_FUZZ_CFG_ADAPTIVE = 0x08,    /**< adaptive_noise on */
    VL_FUZZ_CFG_WINDOW_MASK = 0x30, /**< max_landmarks: 0 default, then 16, 4, 1 */
    VL_FUZZ_CFG_NO_OFFSETS = 0x40,  /**< estimate_input_offsets off */
    VL_FUZZ_CFG_NO_OUTLIERS = 0x80  /**< gate_chi2 = 0: every outlier test off */
};

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_TESTS_VL_FUZZ_H */
