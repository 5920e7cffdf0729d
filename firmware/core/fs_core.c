#include "fs_core.h"

#include <string.h>

#include "fs_wire.h"

#define NO_TICK 0xFFFFFFFFUL

static void send_payload(struct fs_core *c, uint8_t *payload, uint8_t len) {
    uint8_t frame[FS_TX_MAX];
    fs_put_u16(payload + len, fs_crc16(payload, len));
    size_t n = fs_cobs_encode(payload, (size_t)len + 2, frame);
    frame[n++] = 0;
    c->seq++;
    if (fs_board_send(frame, (uint8_t)n))
        c->tx_dropped = 0;
    else
        c->tx_dropped = 1; /* the host sees the gap in seq; the next frame carries the flag */
}

static uint8_t flags(const struct fs_core *c) {
    return (uint8_t)((c->armed ? FS_F_ARMED : 0) | (c->vented ? FS_F_VENTED : 0) |
                     (c->tx_dropped ? FS_F_TX_DROPPED : 0) | (c->adc_late ? FS_F_ADC_LATE : 0));
}

static void header(const struct fs_core *c, uint8_t *p, uint8_t type) {
    p[0] = type;
    p[1] = c->session;
    fs_put_u16(p + 2, c->seq);
}

static void send_info(struct fs_core *c) {
    uint8_t p[28];
    header(c, p, FS_INFO);
    p[4] = FS_PROTO_VERSION;
    memcpy(p + 5, c->info.name, 8);
    p[13] = c->info.adc_bits;
    p[14] = c->info.n_adc;
    p[15] = c->info.n_outputs;
    p[16] = c->info.n_aout;
    fs_put_u16(p + 17, c->info.max_rate_hz);
    fs_put_u16(p + 19, c->rate_hz);
    p[21] = c->info.reset_cause;
    fs_put_u16(p + 22, c->heartbeat_ms);
    fs_put_u16(p + 24, c->rx_errors);
    send_payload(c, p, 26);
}

static void send_ack(struct fs_core *c, uint8_t type, uint16_t cmd_seq, uint8_t status) {
    uint8_t p[18];
    header(c, p, FS_ACK);
    p[4] = type;
    fs_put_u16(p + 5, cmd_seq);
    p[7] = status;
    fs_put_u32(p + 8, c->tick);
    p[12] = c->outputs;
    p[13] = flags(c);
    send_payload(c, p, 14);
}

static void apply_outputs(struct fs_core *c, uint8_t levels) {
    c->outputs = levels;
    fs_board_outputs(levels);
}

static void apply_aout(struct fs_core *c, uint8_t ch, uint16_t value) {
    c->aout[ch] = value;
    fs_board_aout(ch, value);
}

static void go_safe(struct fs_core *c) {
    apply_outputs(c, (uint8_t)((c->outputs & ~c->used_outputs) | (c->safe_outputs & c->used_outputs)));
    for (uint8_t ch = 0; ch < c->info.n_aout; ch++)
        apply_aout(c, ch, c->safe_aout[ch]);
}

void fs_core_init(struct fs_core *c, const struct fs_board_info *info) {
    memset(c, 0, sizeof *c);
    c->info = *info;
    c->tick = NO_TICK;
    c->rate_hz = 1000;
    apply_outputs(c, 0);
    for (uint8_t ch = 0; ch < info->n_aout; ch++)
        apply_aout(c, ch, 0);
    fs_board_configure(c->rate_hz, 0x01);
    static const uint8_t delimiter = 0;
    fs_board_send(&delimiter, 1); /* ends whatever the line carried before the reset */
    send_info(c);
}

static uint8_t count_bits(uint8_t m) {
    uint8_t n = 0;
    for (; m; m &= (uint8_t)(m - 1))
        n++;
    return n;
}

static uint8_t cmd_start(struct fs_core *c, const uint8_t *a, uint8_t n) {
    if (n != 12)
        return FS_E_LENGTH;
    uint8_t session = a[0], safe = a[5], used = a[6], mask = a[7];
    uint16_t rate = fs_get_u16(a + 1), hb_ms = fs_get_u16(a + 3);
    uint8_t all_outputs = (uint8_t)(c->info.n_outputs >= 8 ? 0xFF : (1u << c->info.n_outputs) - 1);
    uint8_t all_adc = (uint8_t)(c->info.n_adc >= 8 ? 0xFF : (1u << c->info.n_adc) - 1);
    if (session == 0 || rate == 0 || rate > c->info.max_rate_hz || hb_ms < 10 || (used & ~all_outputs) ||
        mask == 0 || (mask & ~all_adc))
        return FS_E_ARG;
    c->streaming = 0;
    if (fs_board_configure(rate, mask) != 0)
        return FS_E_ARG;
    c->session = session;
    c->rate_hz = rate;
    c->heartbeat_ms = hb_ms;
    c->hb_ticks = ((uint32_t)hb_ms * rate + 999) / 1000;
    c->safe_outputs = safe;
    c->used_outputs = used;
    c->adc_mask = mask;
    c->n_ch = count_bits(mask);
    for (uint8_t ch = 0; ch < FS_MAX_AOUT; ch++)
        c->safe_aout[ch] = fs_get_u16(a + 8 + 2 * ch);
    go_safe(c); /* a session starts safe: what an earlier one left set is void */
    c->tick = NO_TICK;
    c->last_hb_tick = 0;
    c->armed = 0; /* from the first heartbeat, or the first output off its safe level */
    c->vented = 0;
    c->adc_late = 0;
    c->streaming = 1;
    return FS_OK;
}

static int all_safe(const struct fs_core *c) {
    if ((c->outputs & c->used_outputs) != (c->safe_outputs & c->used_outputs))
        return 0;
    for (uint8_t ch = 0; ch < c->info.n_aout; ch++)
        if (c->aout[ch] != c->safe_aout[ch])
            return 0;
    return 1;
}

/* No output leaves its safe level unguarded: a host that sets one before its first
 * heartbeat arms the watchdog with it. */
static void guard(struct fs_core *c, uint32_t now) {
    if (!c->armed && !all_safe(c)) {
        c->armed = 1;
        c->last_hb_tick = now;
    }
}

/* Handles one decoded command (CRC already checked); returns the ack status. */
static uint8_t command(struct fs_core *c, uint8_t type, const uint8_t *a, uint8_t n) {
    uint32_t now = c->tick == NO_TICK ? 0 : c->tick;
    switch (type) {
    case FS_HELLO:
        send_info(c);
        return FS_OK;
    case FS_START:
        return cmd_start(c, a, n);
    case FS_STOP:
        c->streaming = 0;
        c->armed = 0;
        if (c->session) /* no session: nothing was configured, the outputs are as at power-on */
            go_safe(c);
        return FS_OK;
    default:
        break;
    }
    if (!c->session)
        return FS_E_NO_SESSION;
    switch (type) {
    case FS_HEARTBEAT:
        if (n != 0)
            return FS_E_LENGTH;
        c->armed = 1;
        c->last_hb_tick = now;
        return FS_OK;
    case FS_ARM:
        if (n != 0)
            return FS_E_LENGTH;
        c->vented = 0;
        c->armed = 1;
        c->last_hb_tick = now;
        return FS_OK;
    case FS_SET_OUTPUTS: {
        if (n != 2)
            return FS_E_LENGTH;
        uint8_t mask = a[0], levels = (uint8_t)(a[1] & a[0]);
        if (mask & ~c->used_outputs)
            return FS_E_ARG;
        if (c->vented && levels != (c->safe_outputs & mask))
            return FS_E_VENTED; /* held safe until the host re-arms */
        apply_outputs(c, (uint8_t)((c->outputs & ~mask) | levels));
        guard(c, now);
        return FS_OK;
    }
    case FS_SET_AOUT: {
        if (n != 3)
            return FS_E_LENGTH;
        uint8_t ch = a[0];
        uint16_t value = fs_get_u16(a + 1);
        if (ch >= c->info.n_aout)
            return FS_E_ARG;
        if (c->vented && value != c->safe_aout[ch])
            return FS_E_VENTED;
        apply_aout(c, ch, value);
        guard(c, now);
        return FS_OK;
    }
    default:
        return FS_E_UNKNOWN;
    }
}

static void handle_frame(struct fs_core *c) {
    uint8_t p[FS_RX_MAX];
    int n = fs_cobs_decode(c->rx, c->rx_len, p);
    if (n < 5 || fs_crc16(p, (size_t)n - 2) != fs_get_u16(p + n - 2)) {
        c->rx_errors++; /* the host retries when the ack does not come */
        return;
    }
    uint8_t type = p[0];
    uint16_t cmd_seq = fs_get_u16(p + 1);
    if (c->have_last && cmd_seq == c->last_cmd_seq && type == c->last_cmd_type && type != FS_HELLO) {
        send_ack(c, type, cmd_seq, c->last_status); /* a retry whose ack was lost: not applied twice */
        return;
    }
    uint8_t status = command(c, type, p + 3, (uint8_t)(n - 5));
    c->last_cmd_seq = cmd_seq;
    c->last_cmd_type = type;
    c->last_status = status;
    c->have_last = 1;
    send_ack(c, type, cmd_seq, status);
    if (type == FS_STOP)
        c->session = 0; /* after the ack, which still names the session */
}

void fs_core_rx(struct fs_core *c, uint8_t byte) {
    if (byte == 0) {
        if (c->rx_len && !c->rx_skip)
            handle_frame(c);
        else if (c->rx_skip)
            c->rx_errors++;
        c->rx_len = 0;
        c->rx_skip = 0;
        return;
    }
    if (c->rx_len == FS_RX_MAX)
        c->rx_skip = 1; /* overlong: drop everything up to the next delimiter */
    else
        c->rx[c->rx_len++] = byte;
}

void fs_core_adc_overrun(struct fs_core *c) {
    c->adc_late = 1;
}

void fs_core_tick(struct fs_core *c, uint32_t tick, const uint16_t *counts, uint8_t late_us) {
    c->tick = tick;
    if (c->armed && !c->vented && tick - c->last_hb_tick > c->hb_ticks) {
        go_safe(c);
        c->vented = 1;
        c->vent_tick = tick;
        c->vent_last_hb_tick = c->last_hb_tick;
        fs_board_vented(tick, c->last_hb_tick);
    }
    if (!c->streaming)
        return;
    uint8_t p[15 + 2 * FS_MAX_CH + 2];
    header(c, p, FS_SAMPLE);
    fs_put_u32(p + 4, tick);
    p[8] = c->outputs;
    p[9] = flags(c);
    p[10] = late_us;
    fs_put_u16(p + 11, c->aout[0]);
    fs_put_u16(p + 13, c->aout[1]);
    for (uint8_t i = 0; i < c->n_ch; i++)
        fs_put_u16(p + 15 + 2 * i, counts[i]);
    c->adc_late = 0;
    send_payload(c, p, (uint8_t)(15 + 2 * c->n_ch));
}
