/*
 * gyrocal wearable protocol, firmware side (C99).
 *
 * Encodes what a wearable sends (sample packets, its configuration, status replies, the calibration it
 * holds) and decodes what it receives (control commands, including a calibration written back with its
 * CRC-32). The specification is docs/protocol.md; docs/firmware.md shows how a firmware uses this.
 *
 * No allocation, no platform calls, no global state: every function works on buffers and structs the
 * caller owns. All multi-byte fields are little-endian on the wire whatever the MCU's byte order; floats
 * are IEEE 754 binary32.
 */
#ifndef GYROCAL_PROTOCOL_H
#define GYROCAL_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define GC_PROTOCOL_VERSION 1u
#define GC_HEADER_SIZE 10u
#define GC_SAMPLE_SIZE 12u         /* six int16: gx gy gz ax ay az, counts */
#define GC_CONFIG_SIZE 20u
#define GC_STATUS_SIZE 3u
#define GC_CALIBRATION_SIZE 56u    /* WRITE_CALIBRATION payload: id, K, b, CRC-32 */
#define GC_SLOT_SIZE 58u           /* the calibration characteristic: version, held, then the 56 bytes */
#define GC_POWER_UP_SIZE 12u       /* the power-up characteristic: boot count, uptime, temperature */
#ifndef GC_MAX_SAMPLES
/* Samples one packet (and gc_stream's buffer) can hold: 19 fills an ATT MTU of 247, (247 - 3 - 10) / 12. A firmware
 * that negotiates a larger MTU may define it up to 255 before including this header. */
#define GC_MAX_SAMPLES 19u
#endif
#define GC_MAX_PACKET_SIZE (GC_HEADER_SIZE + GC_MAX_SAMPLES * GC_SAMPLE_SIZE)
#define GC_MAX_NOTIFICATIONS_PER_S 40u
#define GC_IDENTIFY_MAX_S 60u      /* the longest IDENTIFY a central may ask for */

/* Bits of a packet's flags byte. */
enum gc_flag {
    GC_FLAG_SESSION_START = 0x01, /* first packet of a session: sequence numbers start at 0 */
    GC_FLAG_RESUMED = 0x02,       /* first packet after the central resumed the session */
    GC_FLAG_GYRO_CLIPPED = 0x04   /* a gyro value of this packet is at the int16 limit */
};

/* Bits of the configuration's state byte. */
enum gc_state {
    GC_STATE_STREAMING = 0x01,
    GC_STATE_SESSION_ACTIVE = 0x02, /* a session survives a link loss until STOP */
    GC_STATE_REPLAY = 0x04
};

/* Control opcodes (first byte of a control write). */
enum gc_opcode {
    GC_OP_START = 0x01,
    GC_OP_STOP = 0x02,
    GC_OP_SET_RATE = 0x03,          /* f32 Hz */
    GC_OP_SET_GYRO_RANGE = 0x04,    /* u16 deg/s */
    GC_OP_SET_ACCEL_RANGE = 0x05,   /* u8 g */
    GC_OP_WRITE_CALIBRATION = 0x06, /* 56 bytes: gc_calibration with its CRC-32 */
    GC_OP_CLEAR_CALIBRATION = 0x07,
    GC_OP_IDENTIFY = 0x08,          /* u8 s, 1..60: blink or buzz for that long (allowed while streaming) */
    GC_OP_STREAM_END = 0x10         /* device -> central only */
};

/* Status byte of a control reply. */
enum gc_status {
    GC_STATUS_OK = 0,
    GC_STATUS_UNKNOWN_OPCODE = 1,
    GC_STATUS_INVALID_VALUE = 2,
    GC_STATUS_BUSY = 3,
    GC_STATUS_BAD_LENGTH = 4,
    GC_STATUS_NOT_SUPPORTED = 5,
    GC_STATUS_CHECKSUM = 6
};

/* The configuration the config characteristic reports. */
typedef struct {
    uint8_t config_id;           /* change it whenever any field below changes */
    float rate_hz;               /* nominal output data rate */
    uint16_t gyro_full_scale_dps;
    uint8_t accel_range_g;
    uint8_t samples_per_packet;  /* N, see gc_samples_per_packet */
    float gyro_lsb_per_dps;      /* counts per deg/s */
    float accel_lsb_per_g;       /* counts per g */
    uint8_t state;               /* enum gc_state bits */
} gc_config;

/* A calibration of g = K m + b (m the raw reading in deg/s, b in deg/s of true rate). */
typedef struct {
    uint32_t id;   /* the id gyrocal's store gave it */
    float K[9];    /* row-major */
    float b[3];
} gc_calibration;

/* A decoded control write. Only the member of `arg` that belongs to `opcode` is set. */
typedef struct {
    uint8_t opcode;
    union {
        float rate_hz;
        uint16_t gyro_full_scale_dps;
        uint8_t accel_range_g;
        uint8_t identify_s;      /* IDENTIFY: how long to blink or buzz, s */
        gc_calibration calibration;
    } arg;
} gc_command;

/* The packetiser of one streaming session: collects samples, emits packets. */
typedef struct {
    uint8_t config_id;
    uint8_t samples_per_packet;
    uint8_t count;          /* samples collected for the next packet */
    uint8_t flags;          /* flags the next packet carries */
    uint16_t seq;           /* sequence number of the next packet */
    uint32_t t_first_us;    /* device time of the next packet's first sample */
    int16_t samples[GC_MAX_SAMPLES][6];
} gc_stream;

/* CRC-32 of IEEE 802.3 (reflected 0xEDB88320, init and final XOR 0xFFFFFFFF); "123456789" -> 0xCBF43926. */
uint32_t gc_crc32(const uint8_t *data, size_t len);

/* N for a rate: the fewest samples per packet keeping notifications at <= 40/s, capped by the ATT MTU and by
 * GC_MAX_SAMPLES. Returns 0 when the MTU cannot carry one sample (it must be at least 25). */
uint8_t gc_samples_per_packet(float rate_hz, uint16_t att_mtu);

/* One packet from n (1..GC_MAX_SAMPLES) samples. Returns its length, or 0 if `cap` is too small or n is out of range. */
size_t gc_encode_packet(uint8_t *out, size_t cap, uint8_t flags, uint8_t config_id, uint16_t seq, uint32_t t_first_us,
                        const int16_t samples[][6], uint8_t n);

/* The config characteristic's value (GC_CONFIG_SIZE bytes). */
void gc_encode_config(uint8_t out[GC_CONFIG_SIZE], const gc_config *config);

/* A status reply (GC_STATUS_SIZE bytes) for a control write, or an unsolicited STREAM_END. */
void gc_encode_status(uint8_t out[GC_STATUS_SIZE], uint8_t opcode, uint8_t status, uint8_t config_id);

/* Decode a control write. Returns GC_STATUS_OK, or the status to answer with: UNKNOWN_OPCODE, BAD_LENGTH,
 * CHECKSUM (a calibration whose CRC-32 does not match) or INVALID_VALUE (a calibration with a non-finite value,
 * a value beyond 1e6 or a singular K; an IDENTIFY of 0 s or over GC_IDENTIFY_MAX_S). On an error `cmd->opcode` is
 * still set when the opcode was known. IDENTIFY is the one command a device obeys while streaming: it blinks its
 * LED or buzzes for `arg.identify_s` seconds, so the clinician can tell which wearable on the table is which. */
uint8_t gc_decode_command(const uint8_t *data, size_t len, gc_command *cmd);

/* The WRITE_CALIBRATION payload for a calibration (GC_CALIBRATION_SIZE bytes, CRC-32 appended). */
void gc_encode_calibration(uint8_t out[GC_CALIBRATION_SIZE], const gc_calibration *cal);

/* The calibration characteristic's value: what the device holds, or none when `held` is NULL. */
void gc_encode_slot(uint8_t out[GC_SLOT_SIZE], const gc_calibration *held);

/* The power-up characteristic's value. `boot_count` counts power-ups in non-volatile memory (pass
 * has_boot_count false when the device keeps no count); `uptime_s` is the seconds since this power-up;
 * `temperature_centi_c` the IMU temperature in 0.01 degC (pass has_temperature false without a sensor). */
void gc_encode_power_up(uint8_t out[GC_POWER_UP_SIZE], bool has_boot_count, uint32_t boot_count, uint32_t uptime_s,
                        bool has_temperature, int16_t temperature_centi_c);

/* g = K m + b for one raw reading m (deg/s). */
void gc_apply_calibration(const gc_calibration *cal, const float m[3], float g[3]);

/* Start a session's packetiser: sequence 0, the first packet flagged SESSION_START. */
void gc_stream_begin(gc_stream *s, uint8_t config_id, uint8_t samples_per_packet);

/* The central reconnected and resumed the session: the next packet is flagged RESUMED. Packets made while no
 * central listened are simply not sent; their sequence numbers tell the central how many were lost. */
void gc_stream_resume(gc_stream *s);

/* Add one sample taken at device time t_us. When it completes a packet, the packet is written to `out` and its
 * length returned (send it as one notification); otherwise 0. `cap` must be at least the packet size. */
size_t gc_stream_push(gc_stream *s, const int16_t sample[6], uint32_t t_us, uint8_t *out, size_t cap);

#ifdef __cplusplus
}
#endif

#endif /* GYROCAL_PROTOCOL_H */
