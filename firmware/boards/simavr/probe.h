/* The simulated AVR board's bench instruments: what a logic analyser on the USART's two
 * lines and a cycle counter on the CPU would show. Frames on either line are decoded as
 * the protocol says (firmware/README.md), each function of the image has its cycles
 * counted, and latencies (a command's last byte to the pins) go into histograms. */
#ifndef PROBE_H
#define PROBE_H

#include <stdint.h>
#include <stdio.h>

#include "../pc/hist.h"

#define LINE_MAX 64

/* one direction of the serial line, split at the 0x00 delimiters */
struct line {
    uint8_t buf[LINE_MAX];
    uint8_t len, overlong;
    uint32_t frames, bad;
};
/* One byte; a complete valid frame (COBS, CRC) leaves its payload in `payload` and returns
 * its length without the CRC; otherwise -1. */
int line_byte(struct line *l, uint8_t byte, uint8_t *payload);
void line_clear(struct line *l);

/* cycles by function of the image (ELF symbols of the text section) */
#define PROFILE_MAX 96
struct profile {
    int n;
    const char *name[PROFILE_MAX];
    uint32_t start[PROFILE_MAX];
    uint64_t cycles[PROFILE_MAX];
    uint8_t *fn_of;        /* by flash word: the function it belongs to */
    uint32_t words;
    uint64_t asleep, stalled;
};
struct avr_symbol_t;
void profile_init(struct profile *p, struct avr_symbol_t **symbols, uint32_t count, uint32_t flash_bytes);
int profile_find(const struct profile *p, const char *name); /* -1: absent */
static inline int profile_fn(const struct profile *p, uint32_t pc) {
    return pc / 2 < p->words ? p->fn_of[pc / 2] : 0;
}
void profile_json(const struct profile *p, FILE *out);

#endif
