/* Unit tests of the portable core against a fake board: CRC, COBS, commands and acks,
 * sample frames, the heartbeat watchdog. Prints one line per check and a closing
 * "N passed, M failed" line; exit status 1 when a check failed. Run by
 * tests/system/test_serial_protocol.py (make -C firmware test-core). */
#include <stdio.h>
#include <string.h>

#include "../core/fs_core.h"
#include "../core/fs_wire.h"

static int passed, failed;
#define CHECK(cond, what)                                                            \
    do {                                                                             \
        if (cond) {                                                                  \
            passed++;                                                                \
        } else {                                                                     \
            failed++;                                                                \
            printf("FAIL %s (line %d)\n", what, __LINE__);                           \
        }                                                                            \
    } while (0)

/* ---- the fake board: remembers what the core did ---- */
static uint8_t out_levels;
static uint16_t out_aout[2];
static uint8_t sent[64][FS_TX_MAX];
static uint8_t sent_len[64];
static int n_sent, refuse_send, configured_rate, vents;

void fs_board_outputs(uint8_t levels) { out_levels = levels; }
void fs_board_aout(uint8_t ch, uint16_t v) { out_aout[ch] = v; }
int fs_board_configure(uint16_t rate, uint8_t mask) { (void)mask; configured_rate = rate; return rate == 999 ? -1 : 0; }
int fs_board_send(const uint8_t *f, uint8_t len) {
    if (refuse_send)
        return 0;
    memcpy(sent[n_sent % 64], f, len);
    sent_len[n_sent % 64] = len;
    n_sent++;
    return 1;
}
void fs_board_vented(uint32_t tick, uint32_t hb) { (void)tick; (void)hb; vents++; }

/* the last frame sent, decoded and CRC-checked; returns its payload length or -1 */
static int last_frame(uint8_t *p) {
    const uint8_t *f = sent[(n_sent - 1) % 64];
    int len = sent_len[(n_sent - 1) % 64];
    if (len < 2 || f[len - 1] != 0)
        return -1;
    int n = fs_cobs_decode(f, (size_t)len - 1, p);
    if (n < 3 || fs_crc16(p, (size_t)n - 2) != fs_get_u16(p + n - 2))
        return -1;
    return n - 2;
}

static uint16_t cmd_seq = 100;
static void command(struct fs_core *c, uint8_t type, const uint8_t *args, uint8_t n, uint16_t seq) {
    uint8_t p[40], e[48];
    p[0] = type;
    fs_put_u16(p + 1, seq);
    memcpy(p + 3, args, n);
    fs_put_u16(p + 3 + n, fs_crc16(p, 3u + n));
    size_t len = fs_cobs_encode(p, 5u + n, e);
    for (size_t i = 0; i < len; i++)
        fs_core_rx(c, e[i]);
    fs_core_rx(c, 0);
}

/* the status of the ack in the last frame, or -1 */
static int ack_status(uint8_t type, uint16_t seq) {
    uint8_t p[40];
    int n = last_frame(p);
    if (n != 14 || p[0] != FS_ACK || p[4] != type || fs_get_u16(p + 5) != seq)
        return -1;
    return p[7];
}

static void test_crc_cobs(void) {
    CHECK(fs_crc16((const uint8_t *)"123456789", 9) == 0x29B1, "CRC-16/CCITT-FALSE check value");
    CHECK(fs_crc16(NULL, 0) == 0xFFFF, "CRC of nothing is the initial value");
    uint8_t in[254], enc[256], dec[256];
    int ok = 1;
    for (int len = 0; len <= 254; len++) {
        for (int pattern = 0; pattern < 4; pattern++) {
            for (int i = 0; i < len; i++)
                in[i] = pattern == 0 ? 0 : pattern == 1 ? (uint8_t)(i + 1) : pattern == 2 ? (uint8_t)(i * 7 % 3)
                                                                               : (uint8_t)(i % 255 + 1);
            size_t n = fs_cobs_encode(in, (size_t)len, enc);
            if (n != (size_t)len + 1 || memchr(enc, 0, n) || fs_cobs_decode(enc, n, dec) != len ||
                memcmp(in, dec, (size_t)len))
                ok = 0;
        }
    }
    CHECK(ok, "COBS round trip, every length 0-254, four patterns, one byte of overhead, no zero");
    const uint8_t bad1[] = {0x05, 0x11, 0x22};       /* code points past the end */
    const uint8_t bad2[] = {0x03, 0x11, 0x00, 0x22}; /* a zero inside */
    CHECK(fs_cobs_decode(bad1, sizeof bad1, dec) == -1, "COBS: a code past the end is refused");
    CHECK(fs_cobs_decode(bad2, sizeof bad2, dec) == -1, "COBS: a zero inside a frame is refused");
}

static void start(struct fs_core *c, uint8_t session, uint16_t rate, uint16_t hb_ms, uint8_t safe, uint8_t used,
                  uint16_t seq) {
    uint8_t a[12] = {session, (uint8_t)rate, (uint8_t)(rate >> 8), (uint8_t)hb_ms, (uint8_t)(hb_ms >> 8), safe,
                     used, 0x03, 0, 0, 0x34, 0x12};
    command(c, FS_START, a, sizeof a, seq);
}

static void test_session(void) {
    struct fs_core c;
    struct fs_board_info info = {.name = "test", .adc_bits = 10, .n_adc = 8, .n_outputs = 8, .n_aout = 2,
                                 .max_rate_hz = 2000};
    out_levels = 0xAA;
    n_sent = 0;
    fs_core_init(&c, &info);
    uint8_t p[40];
    CHECK(out_levels == 0 && last_frame(p) == 26 && p[0] == FS_INFO && p[1] == 0 && p[4] == FS_PROTO_VERSION &&
              p[13] == 10 && fs_get_u16(p + 17) == 2000,
          "power-on: outputs low, INFO with protocol, ADC bits, max rate");

    uint8_t set[2] = {0x02, 0x02};
    command(&c, FS_SET_OUTPUTS, set, 2, ++cmd_seq);
    CHECK(ack_status(FS_SET_OUTPUTS, cmd_seq) == FS_E_NO_SESSION && out_levels == 0, "no output before START");

    start(&c, 7, 999, 500, 0x01, 0x03, ++cmd_seq);
    CHECK(ack_status(FS_START, cmd_seq) == FS_E_ARG && c.session == 0, "START at a rate the board refuses");
    start(&c, 7, 1000, 500, 0x01, 0x03, ++cmd_seq);
    CHECK(ack_status(FS_START, cmd_seq) == FS_OK && c.session == 7 && c.hb_ticks == 500 && configured_rate == 1000,
          "START: session, rate, heartbeat in ticks");

    CHECK(!c.armed && out_levels == 0x01 && out_aout[1] == 0x1234,
          "START puts the outputs safe and does not arm the watchdog (no heartbeat yet)");
    uint8_t safe_bit[2] = {0x01, 0x01};
    command(&c, FS_SET_OUTPUTS, safe_bit, 2, ++cmd_seq);
    CHECK(ack_status(FS_SET_OUTPUTS, cmd_seq) == FS_OK && !c.armed, "outputs at their safe levels stay unarmed");
    command(&c, FS_SET_OUTPUTS, set, 2, ++cmd_seq);
    CHECK(ack_status(FS_SET_OUTPUTS, cmd_seq) == FS_OK && out_levels == 0x03 && c.armed,
          "SET_OUTPUTS sets the masked bits; an output off its safe level arms the watchdog");
    uint8_t clear0[2] = {0x01, 0x00};
    command(&c, FS_SET_OUTPUTS, clear0, 2, ++cmd_seq);
    uint8_t wrong[2] = {0x10, 0x10};
    command(&c, FS_SET_OUTPUTS, wrong, 2, ++cmd_seq);
    CHECK(ack_status(FS_SET_OUTPUTS, cmd_seq) == FS_E_ARG && out_levels == 0x02, "an output not in use is refused");

    /* a retry of the same command (its ack was lost) is acknowledged, not applied again */
    uint8_t clear[2] = {0x02, 0x00};
    uint16_t retried = ++cmd_seq;
    command(&c, FS_SET_OUTPUTS, clear, 2, retried);
    out_levels = 0x55; /* if it were applied again, the board would see it */
    command(&c, FS_SET_OUTPUTS, clear, 2, retried);
    CHECK(ack_status(FS_SET_OUTPUTS, retried) == FS_OK && out_levels == 0x55, "a retried command is re-acked only");
    command(&c, FS_SET_OUTPUTS, set, 2, ++cmd_seq);

    uint16_t counts[2] = {512, 1023};
    fs_core_tick(&c, 0, counts, 3);
    int n = last_frame(p);
    CHECK(n == 19 && p[0] == FS_SAMPLE && p[1] == 7 && p[4] == 0 && p[8] == 0x02 && (p[9] & FS_F_ARMED) &&
              p[10] == 3 && fs_get_u16(p + 15) == 512 && fs_get_u16(p + 17) == 1023,
          "sample frame: session, tick, outputs as set, flags, lateness, counts");
    uint16_t seq0 = fs_get_u16(p + 2);
    refuse_send = 1;
    fs_core_tick(&c, 1, counts, 0);
    refuse_send = 0;
    fs_core_tick(&c, 2, counts, 0);
    n = last_frame(p);
    CHECK(n == 19 && fs_get_u16(p + 2) == (uint16_t)(seq0 + 2) && (p[9] & FS_F_TX_DROPPED),
          "a dropped frame leaves a gap in seq and the next one says so");

    /* corrupted command: dropped, counted, no ack */
    int before = n_sent;
    uint8_t bad[] = {0x04, FS_HEARTBEAT, 0x01, 0x02, 0x05, 0x00};
    for (size_t i = 0; i < sizeof bad; i++)
        fs_core_rx(&c, bad[i]);
    CHECK(n_sent == before && c.rx_errors == 1, "a corrupt command is dropped and counted");

    /* heartbeat watchdog: 500 ticks without a heartbeat are fine, the 501st vents */
    command(&c, FS_HEARTBEAT, NULL, 0, ++cmd_seq);
    uint32_t hb = c.tick;
    for (uint32_t t = 3; t <= hb + 500; t++)
        fs_core_tick(&c, t, counts, 0);
    CHECK(vents == 0 && out_levels == 0x02, "no vent within the heartbeat timeout");
    fs_core_tick(&c, hb + 501, counts, 0);
    CHECK(vents == 1 && out_levels == 0x01 && out_aout[1] == 0x1234 && c.vent_last_hb_tick == hb,
          "vented one tick after the timeout: used outputs and analog outputs at their safe values");
    n = last_frame(p);
    CHECK(n == 19 && (p[9] & FS_F_VENTED) && p[8] == 0x01, "the next frame reports the vent and the outputs");
    command(&c, FS_SET_OUTPUTS, set, 2, ++cmd_seq);
    CHECK(ack_status(FS_SET_OUTPUTS, cmd_seq) == FS_E_VENTED && out_levels == 0x01, "held safe until ARM");
    command(&c, FS_ARM, NULL, 0, ++cmd_seq);
    command(&c, FS_SET_OUTPUTS, set, 2, ++cmd_seq);
    CHECK(ack_status(FS_SET_OUTPUTS, cmd_seq) == FS_OK && out_levels == 0x03, "ARM clears the vent");

    command(&c, FS_STOP, NULL, 0, ++cmd_seq);
    CHECK(ack_status(FS_STOP, cmd_seq) == FS_OK && c.session == 0 && out_levels == 0x01 && !c.streaming,
          "STOP: outputs safe, streaming off, session over");
    before = n_sent;
    fs_core_tick(&c, 10000, counts, 0);
    CHECK(n_sent == before && vents == 1, "after STOP: no frames, no watchdog");
}

int main(void) {
    test_crc_cobs();
    test_session();
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
