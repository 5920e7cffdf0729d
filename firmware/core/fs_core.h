/* fluidsense serial streamer: the portable core (protocol, sample frames, commands with
 * acknowledgements, the heartbeat watchdog). A board file owns the hardware: it calls
 * fs_core_init once, fs_core_rx for every received byte and fs_core_tick once per sample
 * taken, and implements the fs_board_* hooks below. firmware/README.md is the protocol. */
#ifndef FS_CORE_H
#define FS_CORE_H

#include <stdint.h>

#define FS_PROTO_VERSION 1
#define FS_MAX_CH 8
#define FS_MAX_AOUT 2
#define FS_RX_MAX 48  /* longest encoded command, with room to spare */
#define FS_TX_MAX 40  /* longest encoded frame + delimiter (a sample frame of 8 channels: 36) */

/* frame types: device -> host */
enum { FS_SAMPLE = 0x01, FS_ACK = 0x02, FS_INFO = 0x03 };
/* frame types: host -> device (commands) */
enum { FS_HELLO = 0x10, FS_START = 0x11, FS_STOP = 0x12, FS_HEARTBEAT = 0x13, FS_SET_OUTPUTS = 0x14,
       FS_SET_AOUT = 0x15, FS_ARM = 0x16 };
/* acknowledgement status */
enum { FS_OK = 0, FS_E_LENGTH = 1, FS_E_UNKNOWN = 2, FS_E_ARG = 3, FS_E_NO_SESSION = 4, FS_E_VENTED = 5 };
/* flags of sample and ack frames */
enum { FS_F_ARMED = 0x01, FS_F_VENTED = 0x02, FS_F_TX_DROPPED = 0x04, FS_F_ADC_LATE = 0x08 };
/* reset causes reported in INFO */
enum { FS_RESET_POWER = 0, FS_RESET_EXTERNAL = 1, FS_RESET_BROWNOUT = 2, FS_RESET_WATCHDOG = 3,
       FS_RESET_SOFTWARE = 4 };

struct fs_board_info {
    char name[8];          /* zero-padded */
    uint8_t adc_bits;      /* resolution of the counts */
    uint8_t n_adc;         /* analog inputs 0 .. n_adc - 1 */
    uint8_t n_outputs;     /* digital outputs 0 .. n_outputs - 1 (at most 8) */
    uint8_t n_aout;        /* analog outputs (at most FS_MAX_AOUT) */
    uint16_t max_rate_hz;
    uint8_t reset_cause;
};

struct fs_core {
    struct fs_board_info info;
    uint8_t session;       /* 0: none (power-on, after STOP) */
    uint8_t streaming;
    uint16_t seq;          /* of the next device -> host frame, every type */
    uint32_t tick;         /* tick of the last sample frame built; 0xFFFFFFFF: none yet */
    uint16_t rate_hz;
    uint16_t heartbeat_ms;
    uint32_t hb_ticks;     /* heartbeat timeout in ticks */
    uint32_t last_hb_tick;
    uint8_t armed, vented, tx_dropped, adc_late;
    uint8_t outputs, safe_outputs, used_outputs;
    uint16_t aout[FS_MAX_AOUT], safe_aout[FS_MAX_AOUT];
    uint8_t adc_mask, n_ch;
    uint16_t rx_errors;    /* command frames dropped: bad COBS, CRC, overlong */
    uint8_t rx[FS_RX_MAX];
    uint8_t rx_len, rx_skip;
    uint16_t last_cmd_seq;
    uint8_t last_cmd_type, last_status, have_last;
    uint32_t vent_tick;    /* when the watchdog last vented, and the heartbeat before it */
    uint32_t vent_last_hb_tick;
};

/* Power-on: outputs low, analog outputs 0, no session, INFO sent. */
void fs_core_init(struct fs_core *c, const struct fs_board_info *info);
/* One received byte. Complete command frames are handled at once (ack sent). */
void fs_core_rx(struct fs_core *c, uint8_t byte);
/* The samples of tick `tick` (counts of the channels in adc_mask, lowest channel first);
 * `late_us`: how long after the tick the first conversion started (saturated at 255). */
void fs_core_tick(struct fs_core *c, uint32_t tick, const uint16_t *counts, uint8_t late_us);
/* The ADC could not take the samples of a tick (its previous conversions still ran). */
void fs_core_adc_overrun(struct fs_core *c);

/* ---- implemented by the board file ---- */
void fs_board_outputs(uint8_t levels);
void fs_board_aout(uint8_t channel, uint16_t value);
/* Restart the sample timer at rate_hz sampling the channels of adc_mask; the next sample
 * is tick 0. Returns 0, or -1 when the board cannot (rate, channels, conversion time). */
int fs_board_configure(uint16_t rate_hz, uint8_t adc_mask);
/* Queue a whole encoded frame (delimiter included) for sending, or none of it: returns 1
 * when queued, 0 when there was no room (the frame is dropped and the next one says so). */
int fs_board_send(const uint8_t *frame, uint8_t len);
/* The watchdog vented (for boards that tell someone, e.g. the simulated plant). */
void fs_board_vented(uint32_t tick, uint32_t last_hb_tick);

#endif
