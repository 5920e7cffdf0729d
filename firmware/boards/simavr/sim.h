/* The simulated AVR board's state (plant.c: it, the clock and the plant link), shared by
 * board_simavr.c (the process: pacing, the pty) and mcu.c (simavr: the MCU, its pins and
 * lines). */
#ifndef SIM_H
#define SIM_H

#include <stdint.h>

#include <sim_avr.h>

#include "../../core/fs_core.h"
#include "probe.h"

#define TX_RING 65536 /* device -> pty */
#define RX_QUEUE 4096 /* pty -> the MCU's RXD, at the line's rate */

struct avr_uart_t;

struct sim {
    avr_t *avr;
    struct avr_uart_t *uart;
    void (*run0)(avr_t *); /* simavr's own run callback (the watchdog swaps it to reset) */
    uint64_t t0_ns;        /* cycle 0 on CLOCK_MONOTONIC */
    int master;            /* the pty */
    int adc_wait_us;
    uint32_t vref_mv;
    /* the lines */
    uint8_t tx[TX_RING];
    size_t tx_head, tx_len;
    uint8_t rx[RX_QUEUE];
    size_t rx_head, rx_len;
    int rx_feeding, xoff;
    struct line tx_line, rx_line;
    /* the pins */
    uint8_t outputs, led;
    uint16_t aout[FS_MAX_AOUT];
    uint16_t adc_next[FS_MAX_CH]; /* counts the plant computed for adc_next_ns */
    uint64_t adc_next_ns;
    uint64_t last_start; /* cycle of the last sample's first conversion */
    /* what the device's frames say (a protocol analyser on TXD) */
    uint8_t dev_session, dev_armed, have_seq, have_tick;
    uint16_t dev_seq;
    uint32_t dev_tick, hb_tick;
    /* events on the host's line, by cycle of the last byte's stop bit */
    uint64_t set_end, hb_end, vent_pins;
    int set_pending, vent_pending;
    uint8_t cmd_type; /* the last command on the host's line */
    uint16_t cmd_seq;
    /* control */
    volatile int reset_request, stall;
    int fn_main, fn_timer;
    uint64_t slept;
    struct profile prof;
    struct {
        uint64_t ticks, stale, samples, resets, watchdog_resets, vents, tx_bytes, rx_bytes, tx_dropped, rx_dropped,
            plant_dropped;
        /* the device's frames as a protocol analyser checks them */
        uint64_t seq_gaps, tick_gaps, flagged_tx_dropped, flagged_adc_late;
        uint64_t lag_max_us, lag_over_100ms; /* the MCU behind the host's clock */
        struct hist lag, cmd_to_pin;
        uint64_t hb_to_vent_us[16]; /* the first vents' */
    } stats;
};

extern struct sim S;

/* plant.c */
uint64_t now_ns(void);
uint64_t cycle_ns(uint64_t cycle);
void to_plant(uint8_t kind, uint32_t tick, uint32_t extra, uint64_t t_ns, uint64_t next_ns);
void from_plant(void);

/* mcu.c */
void mcu_load(const char *elf, uint32_t f_cpu, uint32_t vref_mv);
void mcu_after_step(void);
void board_reset(uint8_t cause);
void rx_start(void);

#endif
