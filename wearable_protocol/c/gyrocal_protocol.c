/* gyrocal wearable protocol, firmware side (C99): see gyrocal_protocol.h and docs/protocol.md. */
#include "gyrocal_protocol.h"

#include <string.h>

#define MAX_ABS_PARAMETER 1.0e6
#define MIN_ABS_DETERMINANT 1.0e-9

/* -- little-endian fields, whatever the MCU's byte order ------------------------------------------------ */

static void put_u16(uint8_t *p, uint16_t v) {
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

static void put_f32(uint8_t *p, float v) {
    uint32_t bits;
    memcpy(&bits, &v, sizeof bits);
    put_u32(p, bits);
}

static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (uint16_t)(p[1] << 8)); }

static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static float get_f32(const uint8_t *p) {
    uint32_t bits = get_u32(p);
    float v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

/* -- CRC-32 (IEEE 802.3), bitwise: no 1 KiB table in the firmware's flash -------------------------------- */

uint32_t gc_crc32(const uint8_t *data, size_t len) {
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < len; i++) {
        crc ^= data[i];
        for (int bit = 0; bit < 8; bit++) {
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
        }
    }
    return crc ^ 0xFFFFFFFFu;
}

/* -- packets, configuration, status ----------------------------------------------------------------------- */

uint8_t gc_samples_per_packet(float rate_hz, uint16_t att_mtu) {
    if (att_mtu < 3u + GC_HEADER_SIZE + GC_SAMPLE_SIZE) {
        return 0;
    }
    unsigned cap = (att_mtu - 3u - GC_HEADER_SIZE) / GC_SAMPLE_SIZE;
    double q = (double)rate_hz / (double)GC_MAX_NOTIFICATIONS_PER_S - 1e-9;
    long n = (long)q; /* ceil(q) without libm */
    if ((double)n < q) {
        n++;
    }
    if (n < 1) {
        n = 1;
    }
    if ((unsigned long)n > cap) {
        n = (long)cap;
    }
    if (n > (long)GC_MAX_SAMPLES) {
        n = (long)GC_MAX_SAMPLES;
    }
    return (uint8_t)n;
}

size_t gc_encode_packet(uint8_t *out, size_t cap, uint8_t flags, uint8_t config_id, uint16_t seq, uint32_t t_first_us,
                        const int16_t samples[][6], uint8_t n) {
    size_t size = GC_HEADER_SIZE + (size_t)n * GC_SAMPLE_SIZE;
    if (n == 0 || n > GC_MAX_SAMPLES || cap < size) {
        return 0;
    }
    out[0] = (uint8_t)GC_PROTOCOL_VERSION;
    out[1] = flags;
    out[2] = n;
    out[3] = config_id;
    put_u16(out + 4, seq);
    put_u32(out + 6, t_first_us);
    uint8_t *p = out + GC_HEADER_SIZE;
    for (uint8_t i = 0; i < n; i++) {
        for (int axis = 0; axis < 6; axis++) {
            put_u16(p, (uint16_t)samples[i][axis]);
            p += 2;
        }
    }
    return size;
}

void gc_encode_config(uint8_t out[GC_CONFIG_SIZE], const gc_config *c) {
    out[0] = (uint8_t)GC_PROTOCOL_VERSION;
    out[1] = c->config_id;
    put_f32(out + 2, c->rate_hz);
    put_u16(out + 6, c->gyro_full_scale_dps);
    out[8] = c->accel_range_g;
    out[9] = c->samples_per_packet;
    put_f32(out + 10, c->gyro_lsb_per_dps);
    put_f32(out + 14, c->accel_lsb_per_g);
    out[18] = c->state;
    out[19] = 0;
}

void gc_encode_status(uint8_t out[GC_STATUS_SIZE], uint8_t opcode, uint8_t status, uint8_t config_id) {
    out[0] = opcode;
    out[1] = status;
    out[2] = config_id;
}

/* -- calibration write-back ------------------------------------------------------------------------------- */

void gc_encode_calibration(uint8_t out[GC_CALIBRATION_SIZE], const gc_calibration *cal) {
    put_u32(out, cal->id);
    for (int i = 0; i < 9; i++) {
        put_f32(out + 4 + 4 * i, cal->K[i]);
    }
    for (int i = 0; i < 3; i++) {
        put_f32(out + 40 + 4 * i, cal->b[i]);
    }
    put_u32(out + 52, gc_crc32(out, 52));
}

void gc_encode_slot(uint8_t out[GC_SLOT_SIZE], const gc_calibration *held) {
    out[0] = (uint8_t)GC_PROTOCOL_VERSION;
    out[1] = held != NULL ? 1u : 0u;
    if (held != NULL) {
        gc_encode_calibration(out + 2, held);
    } else {
        memset(out + 2, 0, GC_CALIBRATION_SIZE);
    }
}

void gc_encode_power_up(uint8_t out[GC_POWER_UP_SIZE], bool has_boot_count, uint32_t boot_count, uint32_t uptime_s,
                        bool has_temperature, int16_t temperature_centi_c) {
    out[0] = (uint8_t)GC_PROTOCOL_VERSION;
    out[1] = (uint8_t)((has_boot_count ? 0x01u : 0u) | (has_temperature ? 0x02u : 0u));
    put_u32(out + 2, has_boot_count ? boot_count : 0u);
    put_u32(out + 6, uptime_s);
    put_u16(out + 10, has_temperature ? (uint16_t)temperature_centi_c : 0u);
}

static bool sensible(float v) {
    double d = (double)v;
    return d == d && d <= MAX_ABS_PARAMETER && d >= -MAX_ABS_PARAMETER; /* NaN fails d == d; infinities the bounds */
}

static double determinant(const float *k) {
    double a[9];
    for (int i = 0; i < 9; i++) {
        a[i] = (double)k[i];
    }
    return a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) + a[2] * (a[3] * a[7] - a[4] * a[6]);
}

static uint8_t decode_calibration(const uint8_t *p, gc_calibration *cal) {
    if (gc_crc32(p, 52) != get_u32(p + 52)) {
        return GC_STATUS_CHECKSUM;
    }
    cal->id = get_u32(p);
    for (int i = 0; i < 9; i++) {
        cal->K[i] = get_f32(p + 4 + 4 * i);
    }
    for (int i = 0; i < 3; i++) {
        cal->b[i] = get_f32(p + 40 + 4 * i);
    }
    for (int i = 0; i < 9; i++) {
        if (!sensible(cal->K[i])) {
            return GC_STATUS_INVALID_VALUE;
        }
    }
    for (int i = 0; i < 3; i++) {
        if (!sensible(cal->b[i])) {
            return GC_STATUS_INVALID_VALUE;
        }
    }
    double det = determinant(cal->K);
    if (det < MIN_ABS_DETERMINANT && det > -MIN_ABS_DETERMINANT) {
        return GC_STATUS_INVALID_VALUE;
    }
    return GC_STATUS_OK;
}

uint8_t gc_decode_command(const uint8_t *data, size_t len, gc_command *cmd) {
    if (len == 0) {
        cmd->opcode = 0;
        return GC_STATUS_BAD_LENGTH;
    }
    cmd->opcode = data[0];
    size_t want;
    switch (data[0]) {
    case GC_OP_START:
    case GC_OP_STOP:
    case GC_OP_CLEAR_CALIBRATION:
        want = 0;
        break;
    case GC_OP_SET_RATE:
        want = 4;
        break;
    case GC_OP_SET_GYRO_RANGE:
        want = 2;
        break;
    case GC_OP_SET_ACCEL_RANGE:
    case GC_OP_IDENTIFY:
        want = 1;
        break;
    case GC_OP_WRITE_CALIBRATION:
        want = GC_CALIBRATION_SIZE;
        break;
    default:
        return GC_STATUS_UNKNOWN_OPCODE;
    }
    if (len != 1 + want) {
        return GC_STATUS_BAD_LENGTH;
    }
    const uint8_t *p = data + 1;
    switch (data[0]) {
    case GC_OP_SET_RATE:
        cmd->arg.rate_hz = get_f32(p);
        break;
    case GC_OP_SET_GYRO_RANGE:
        cmd->arg.gyro_full_scale_dps = get_u16(p);
        break;
    case GC_OP_SET_ACCEL_RANGE:
        cmd->arg.accel_range_g = p[0];
        break;
    case GC_OP_IDENTIFY:
        cmd->arg.identify_s = p[0];
        if (p[0] == 0 || p[0] > GC_IDENTIFY_MAX_S) {
            return GC_STATUS_INVALID_VALUE;
        }
        break;
    case GC_OP_WRITE_CALIBRATION:
        return decode_calibration(p, &cmd->arg.calibration);
    default:
        break;
    }
    return GC_STATUS_OK;
}

void gc_apply_calibration(const gc_calibration *cal, const float m[3], float g[3]) {
    for (int i = 0; i < 3; i++) {
        g[i] = cal->K[3 * i] * m[0] + cal->K[3 * i + 1] * m[1] + cal->K[3 * i + 2] * m[2] + cal->b[i];
    }
}

/* -- the streaming session's packetiser -------------------------------------------------------------------- */

void gc_stream_begin(gc_stream *s, uint8_t config_id, uint8_t samples_per_packet) {
    s->config_id = config_id;
    s->samples_per_packet = samples_per_packet == 0 ? 1 : samples_per_packet > GC_MAX_SAMPLES ? GC_MAX_SAMPLES
                                                                                                : samples_per_packet;
    s->count = 0;
    s->flags = GC_FLAG_SESSION_START;
    s->seq = 0;
    s->t_first_us = 0;
}

void gc_stream_resume(gc_stream *s) { s->flags |= GC_FLAG_RESUMED; }

size_t gc_stream_push(gc_stream *s, const int16_t sample[6], uint32_t t_us, uint8_t *out, size_t cap) {
    if (s->count == 0) {
        s->t_first_us = t_us;
    }
    for (int axis = 0; axis < 6; axis++) {
        s->samples[s->count][axis] = sample[axis];
    }
    for (int axis = 0; axis < 3; axis++) {
        if (sample[axis] == INT16_MAX || sample[axis] == INT16_MIN) {
            s->flags |= GC_FLAG_GYRO_CLIPPED;
        }
    }
    s->count++;
    if (s->count < s->samples_per_packet) {
        return 0;
    }
    size_t size = gc_encode_packet(out, cap, s->flags, s->config_id, s->seq, s->t_first_us,
                                   (const int16_t(*)[6])s->samples, s->count);
    s->count = 0;
    s->flags = 0;
    s->seq++; /* wraps at 65536 as the protocol says */
    return size;
}
