/*
 * A firmware's main loop on a desktop: the gyrocal protocol library driven as a wearable drives it, with the
 * radio replaced by standard input and output. It is how the library is tested end to end (tests/link/
 * test_firmware_library.py) and a template for a real firmware (docs/firmware.md).
 *
 *   gyrocal_host [--mtu N] [--link-loss FIRST:END] CONTROL_HEX... < samples > frames
 *
 * Each CONTROL_HEX is one write to the control characteristic (hex digits), handled in order before streaming;
 * START among them opens the session. Standard input: the IMU's samples, 16 bytes each (u32 device time in us,
 * then gx gy gz ax ay az as i16 counts, little-endian). Standard output: frames `u8 kind | u16 length | value`,
 * kind 'S' a status notification, 'C' the config characteristic after the writes, 'P' a data notification,
 * 'H' the calibration characteristic at the end. --link-loss: no central listens while the samples with index
 * FIRST..END-1 are taken (their packets are not sent), then it resumes the session.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../gyrocal_protocol.h"

typedef struct {
    gc_config config;
    gc_stream stream;
    gc_calibration held;
    int holds;
    int streaming;
    uint8_t identify_s; /* the last IDENTIFY: how long the LED blinks */
} device;

static void frame(char kind, const uint8_t *data, size_t len) {
    uint8_t head[3] = {(uint8_t)kind, (uint8_t)(len & 0xFFu), (uint8_t)(len >> 8)};
    fwrite(head, 1, sizeof head, stdout);
    fwrite(data, 1, len, stdout);
}

static float gyro_sensitivity(uint16_t full_scale) {
    switch (full_scale) {
    case 250: return 131.0f;
    case 500: return 65.5f;
    case 1000: return 32.8f;
    case 2000: return 16.4f;
    default: return 0.0f;
    }
}

static float accel_sensitivity(uint8_t range) {
    switch (range) {
    case 2: return 16384.0f;
    case 4: return 8192.0f;
    case 8: return 4096.0f;
    case 16: return 2048.0f;
    default: return 0.0f;
    }
}

static int rate_offered(float hz) {
    static const float rates[] = {52.0f, 104.0f, 208.0f, 416.0f, 562.5f};
    for (size_t i = 0; i < sizeof rates / sizeof rates[0]; i++) {
        if (hz == rates[i]) {
            return 1;
        }
    }
    return 0;
}

/* What a firmware does with one control write; returns the status to answer with. */
static uint8_t handle(device *d, const uint8_t *data, size_t len, uint16_t mtu) {
    gc_command cmd;
    uint8_t status = gc_decode_command(data, len, &cmd);
    if (status != GC_STATUS_OK) {
        return status;
    }
    gc_config *c = &d->config;
    switch (cmd.opcode) {
    case GC_OP_START:
        gc_stream_begin(&d->stream, c->config_id, c->samples_per_packet);
        d->streaming = 1;
        c->state = GC_STATE_STREAMING | GC_STATE_SESSION_ACTIVE;
        return GC_STATUS_OK;
    case GC_OP_STOP:
        d->streaming = 0;
        c->state = 0;
        return GC_STATUS_OK;
    case GC_OP_WRITE_CALIBRATION:
        d->held = cmd.arg.calibration; /* a real firmware also hands it to whatever applies it */
        d->holds = 1;
        return GC_STATUS_OK;
    case GC_OP_CLEAR_CALIBRATION:
        d->holds = 0;
        return GC_STATUS_OK;
    case GC_OP_IDENTIFY:
        /* a real firmware starts its LED or buzzer here, for cmd.arg.identify_s seconds, and goes on streaming */
        d->identify_s = cmd.arg.identify_s;
        return GC_STATUS_OK;
    default:
        break;
    }
    if (d->streaming) {
        return GC_STATUS_BUSY;
    }
    if (cmd.opcode == GC_OP_SET_RATE) {
        if (!rate_offered(cmd.arg.rate_hz)) {
            return GC_STATUS_INVALID_VALUE;
        }
        c->rate_hz = cmd.arg.rate_hz;
        c->samples_per_packet = gc_samples_per_packet(c->rate_hz, mtu);
    } else if (cmd.opcode == GC_OP_SET_GYRO_RANGE) {
        if (gyro_sensitivity(cmd.arg.gyro_full_scale_dps) == 0.0f) {
            return GC_STATUS_INVALID_VALUE;
        }
        c->gyro_full_scale_dps = cmd.arg.gyro_full_scale_dps;
        c->gyro_lsb_per_dps = gyro_sensitivity(c->gyro_full_scale_dps);
    } else {
        if (accel_sensitivity(cmd.arg.accel_range_g) == 0.0f) {
            return GC_STATUS_INVALID_VALUE;
        }
        c->accel_range_g = cmd.arg.accel_range_g;
        c->accel_lsb_per_g = accel_sensitivity(c->accel_range_g);
    }
    c->config_id = (uint8_t)(c->config_id % 255u + 1u);
    return GC_STATUS_OK;
}

static int hex_value(char ch) {
    if (ch >= '0' && ch <= '9') return ch - '0';
    if (ch >= 'a' && ch <= 'f') return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F') return ch - 'A' + 10;
    return -1;
}

static size_t from_hex(const char *text, uint8_t *out, size_t cap) {
    size_t n = strlen(text) / 2;
    if (strlen(text) % 2 != 0 || n > cap) {
        return (size_t)-1;
    }
    for (size_t i = 0; i < n; i++) {
        int hi = hex_value(text[2 * i]), lo = hex_value(text[2 * i + 1]);
        if (hi < 0 || lo < 0) {
            return (size_t)-1;
        }
        out[i] = (uint8_t)(hi * 16 + lo);
    }
    return n;
}

int main(int argc, char **argv) {
    uint16_t mtu = 247;
    unsigned long loss_first = 0, loss_end = 0;
    device d;
    memset(&d, 0, sizeof d);
    d.config = (gc_config){1, 104.0f, 500, 4, 0, 65.5f, 8192.0f, 0};
    int first_control = 1;
    for (; first_control < argc && strncmp(argv[first_control], "--", 2) == 0; first_control += 2) {
        if (first_control + 1 >= argc) {
            fprintf(stderr, "gyrocal_host: %s needs a value\n", argv[first_control]);
            return 2;
        }
        if (strcmp(argv[first_control], "--mtu") == 0) {
            mtu = (uint16_t)strtoul(argv[first_control + 1], NULL, 10);
        } else if (strcmp(argv[first_control], "--link-loss") == 0) {
            if (sscanf(argv[first_control + 1], "%lu:%lu", &loss_first, &loss_end) != 2 || loss_end < loss_first) {
                fprintf(stderr, "gyrocal_host: --link-loss takes FIRST:END sample indices\n");
                return 2;
            }
        } else {
            fprintf(stderr, "gyrocal_host: unknown option %s\n", argv[first_control]);
            return 2;
        }
    }
    d.config.samples_per_packet = gc_samples_per_packet(d.config.rate_hz, mtu);
    if (d.config.samples_per_packet == 0) {
        fprintf(stderr, "gyrocal_host: an ATT MTU of %u cannot carry one sample\n", (unsigned)mtu);
        return 2;
    }
    uint8_t buf[GC_MAX_PACKET_SIZE];
    for (int i = first_control; i < argc; i++) {
        uint8_t write[1 + GC_CALIBRATION_SIZE + 8];
        size_t len = from_hex(argv[i], write, sizeof write);
        if (len == (size_t)-1) {
            fprintf(stderr, "gyrocal_host: %s is not a control write in hex\n", argv[i]);
            return 2;
        }
        uint8_t status = handle(&d, write, len, mtu);
        gc_encode_status(buf, len ? write[0] : 0u, status, d.config.config_id);
        frame('S', buf, GC_STATUS_SIZE);
    }
    gc_encode_config(buf, &d.config);
    frame('C', buf, GC_CONFIG_SIZE);

    uint8_t record[16];
    unsigned long index = 0;
    while (d.streaming && fread(record, 1, sizeof record, stdin) == sizeof record) {
        uint32_t t_us = (uint32_t)record[0] | ((uint32_t)record[1] << 8) | ((uint32_t)record[2] << 16) |
                        ((uint32_t)record[3] << 24);
        int16_t sample[6];
        for (int axis = 0; axis < 6; axis++) {
            sample[axis] = (int16_t)(uint16_t)(record[4 + 2 * axis] | (record[5 + 2 * axis] << 8));
        }
        if (index == loss_end && loss_end > loss_first) {
            gc_stream_resume(&d.stream);
        }
        size_t size = gc_stream_push(&d.stream, sample, t_us, buf, sizeof buf);
        int listening = index < loss_first || index >= loss_end;
        if (size > 0 && listening) {
            frame('P', buf, size);
        }
        index++;
    }
    gc_encode_status(buf, GC_OP_STREAM_END, GC_STATUS_OK, d.config.config_id);
    frame('S', buf, GC_STATUS_SIZE);
    gc_encode_slot(buf, d.holds ? &d.held : NULL);
    frame('H', buf, GC_SLOT_SIZE);
    return 0;
}
