/* The MCU in simavr and what is wired to it: the serial line (bytes in at the line's
 * rate, bytes out to the pty), the valve and LED pins, Timer1's PWM (the regulator), the
 * ADC inputs (the plant's sensor voltages) and the reset pin. Register addresses are the
 * ATmega328P datasheet's (data space). */
#define _GNU_SOURCE
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <avr_adc.h>
#include <avr_extint.h>
#include <avr_ioport.h>
#include <avr_timer.h>
#include <avr_uart.h>
#include <sim_elf.h>
#include <sim_io.h>

#include "../../core/fs_wire.h"
#include "../pc/plant_link.h"
#include "sim.h"

enum { R_PORTB = 0x25, R_DDRB = 0x24, R_PORTD = 0x2B, R_DDRD = 0x2A, R_MCUSR = 0x54, R_TCCR1A = 0x80,
       R_TCCR1B = 0x81, R_ICR1L = 0x86, R_OCR1AL = 0x88, R_OCR1BL = 0x8A, R_UCSR0A = 0xC0, R_UCSR0B = 0xC1,
       R_UCSR0C = 0xC2, R_UBRR0L = 0xC4, R_UBRR0H = 0xC5 };
enum { EXTRF = 1, WDRF = 3 }; /* MCUSR bits */

static avr_irq_t *uart_in, *adc_in;
static int just_reset;

static uint16_t reg16(uint16_t low) { return (uint16_t)(S.avr->data[low] | S.avr->data[low + 1] << 8); }

static uint64_t cycles_us(uint64_t cycles) { return cycles * 1000000u / S.avr->frequency; }

/* simavr 1.6 times every character as start + 8 data + parity + stop bits, parity or not,
 * and only when UBRR0L is written (U2X0 set later is ignored): the line's rate is set here
 * from the registers as the datasheet has it (8N1 at U2X: 10 bits of 8 * (UBRR + 1) cycles). */
static void line_rate(struct avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param) {
    (void)addr, (void)v, (void)param;
    const uint8_t *d = avr->data;
    uint32_t ubrr = (uint32_t)(d[R_UBRR0L] | (d[R_UBRR0H] & 0x0F) << 8);
    uint32_t bit = (ubrr + 1) * (d[R_UCSR0A] & 0x02 ? 8 : 16);
    uint32_t data = 5 + ((d[R_UCSR0C] >> 1) & 3) + (d[R_UCSR0B] & 0x04 ? 4 : 0);
    uint32_t parity = (d[R_UCSR0C] >> 4) & 3 ? 1 : 0, stop = d[R_UCSR0C] & 0x08 ? 2 : 1;
    S.uart->cycles_per_byte = bit * (1 + (data > 8 ? 9 : data) + parity + stop);
}

static void ucsr0c_write(struct avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param) {
    avr->data[addr] = v; /* simavr keeps no handler of its own on UCSR0C */
    line_rate(avr, addr, v, param);
}

/* ---------------------------------------------------------------- the pins */
static void update_aout(void) {
    const uint8_t *d = S.avr->data;
    int mode = (d[R_TCCR1B] >> 1 & 0x0C) | (d[R_TCCR1A] & 3), running = d[R_TCCR1B] & 7;
    uint32_t top = reg16(R_ICR1L);
    for (int ch = 0; ch < FS_MAX_AOUT; ch++) {
        /* fast PWM, TOP = ICR1 (mode 14), non-inverting: high for OCR1x + 1 of TOP + 1 counts */
        int com = d[R_TCCR1A] >> (ch ? 5 : 7) & 1, driven = d[R_DDRB] >> (ch ? 2 : 1) & 1;
        uint32_t v = 0;
        if (mode == 14 && running && com && driven && top) {
            uint32_t ocr = reg16(ch ? R_OCR1BL : R_OCR1AL);
            v = ocr >= top ? 65535u : (uint32_t)((uint64_t)(ocr + 1) * 65536u / (top + 1));
        }
        S.aout[ch] = (uint16_t)(v > 65535u ? 65535u : v);
    }
}

static void pins(void) {
    const uint8_t *d = S.avr->data;
    uint8_t pd = d[R_PORTD] & d[R_DDRD], pb = d[R_PORTB] & d[R_DDRB]; /* undriven: pulled low */
    uint8_t out = (uint8_t)(pd >> 2 | (pb & 1) << 6 | (pb >> 3 & 1) << 7), led = pb >> 5 & 1;
    uint16_t a0 = S.aout[0], a1 = S.aout[1];
    uint64_t c = S.avr->cycle;
    update_aout();
    if (out != S.outputs) {
        if (S.set_pending) {
            hist_add(&S.stats.cmd_to_pin, cycles_us(c - S.set_end));
            S.set_pending = 0;
        }
        S.vent_pins = c;
    }
    if (led && !S.led) { /* the watchdog vented: the pins moved just before, if anything moved */
        S.vent_pending = 1;
        if (S.vent_pins < S.hb_end)
            S.vent_pins = c;
    }
    S.led = led;
    if (out != S.outputs || a0 != S.aout[0] || a1 != S.aout[1]) {
        S.outputs = out;
        to_plant(REC_OUTPUTS, S.dev_tick, 0, cycle_ns(c), 0);
    }
}

static void pins_irq(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)value, (void)param;
    pins();
}

/* A sample's conversions start in the timer interrupt (the next channels' in the ADC
 * interrupt): the plant's voltages for this instant go on the pins now. */
static void adc_trigger(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)value, (void)param;
    if (profile_fn(&S.prof, S.avr->pc) != S.fn_timer)
        return;
    uint64_t c = S.avr->cycle, t = cycle_ns(c);
    uint64_t period = S.last_start ? c - S.last_start : 0, slack = (cycle_ns(period) - S.t0_ns) / 4 + 1000;
    S.last_start = c;
    uint64_t until = now_ns() + (uint64_t)S.adc_wait_us * 1000, now;
    while (S.adc_next_ns + slack < t && (now = now_ns()) < until) { /* the plant is behind: a moment */
        struct pollfd in = {.fd = STDIN_FILENO, .events = POLLIN};
        struct timespec ts = {0, (long)(until - now)};
        if (ppoll(&in, 1, &ts, NULL) > 0)
            from_plant();
    }
    if (S.adc_next_ns + slack < t || S.adc_next_ns > t + slack)
        S.stats.stale++;
    for (int ch = 0; ch < FS_MAX_CH; ch++) /* simavr converts mV * 1023 / Vref: the mV that give these counts */
        avr_raise_irq(adc_in + ch, (uint32_t)(((uint64_t)S.adc_next[ch] * S.vref_mv + 1022) / 1023));
    to_plant(REC_TICK, (uint32_t)S.stats.ticks++, 0, t, period ? cycle_ns(c + period) : t + 1000000);
    pins();
}

/* ---------------------------------------------------------------- the serial line */
static void device_frame(const uint8_t *p, int n) {
    uint8_t type = p[0], was_armed = S.dev_armed, was_session = S.dev_session;
    uint16_t seq = fs_get_u16(p + 2);
    S.stats.seq_gaps += S.have_seq && seq != (uint16_t)(S.dev_seq + 1); /* every frame counts in seq */
    S.dev_seq = seq;
    S.have_seq = 1;
    if (p[1] != S.dev_session)
        S.have_tick = 0;
    S.dev_session = p[1];
    if (type == 0x01 && n >= 15) { /* SAMPLE */
        uint32_t tick = fs_get_u32(p + 4);
        S.stats.tick_gaps += S.have_tick && tick != S.dev_tick + 1;
        S.stats.flagged_tx_dropped += !!(p[9] & FS_F_TX_DROPPED);
        S.stats.flagged_adc_late += !!(p[9] & FS_F_ADC_LATE);
        S.dev_tick = tick;
        S.have_tick = 1;
        S.dev_armed = p[9] & FS_F_ARMED;
        S.stats.samples++;
        if (S.vent_pending && (p[9] & FS_F_VENTED)) {
            uint64_t since = S.hb_end && S.vent_pins > S.hb_end ? S.vent_pins - S.hb_end : 0;
            to_plant(REC_VENT, S.dev_tick, S.hb_tick, cycle_ns(S.vent_pins), cycle_ns(since) - S.t0_ns);
            if (S.stats.vents < 16)
                S.stats.hb_to_vent_us[S.stats.vents] = cycles_us(since);
            S.stats.vents++;
            fprintf(stderr, "fsboard-simavr: no heartbeat since tick %u: vented at tick %u, on the pins %.3f ms "
                    "after the heartbeat's last byte\n", S.hb_tick, S.dev_tick, (double)since * 1e3 / S.avr->frequency);
            S.vent_pending = 0;
        }
    } else if (type == 0x02 && n >= 14) { /* ACK: the command's effect is in its flags */
        uint8_t cmd = p[4], status = p[7];
        uint32_t tick = fs_get_u32(p + 8);
        S.dev_armed = p[13] & FS_F_ARMED;
        if (status == FS_OK && (cmd == FS_HEARTBEAT || cmd == FS_ARM || (S.dev_armed && !was_armed)))
            S.hb_tick = tick == 0xFFFFFFFFu ? 0 : tick;
        if (cmd == FS_STOP && status == FS_OK)
            S.dev_session = 0;
        if (cmd == FS_START && status == FS_OK)
            S.have_tick = 0; /* its ticks start again at 0 */
        if (cmd == FS_SET_OUTPUTS)
            S.set_pending = 0; /* answered: a SET that moved no pin is not matched to a later change */
    }
    /* A command's effect on the session or the watchdog shows only in the device's frames
     * (STOP: its ACK). The plant hears of it now, before this frame's bytes reach the pty:
     * waiting for the next tick's record let a host that had STOP's ACK ask the plant first
     * and read `streaming` (the OUTPUTS record of STOP's safe outputs precedes the ACK). */
    if (S.dev_session != was_session || S.dev_armed != was_armed)
        to_plant(REC_STATE, S.dev_tick, 0, cycle_ns(S.avr->cycle), 0);
}

static void uart_out(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param;
    uint8_t p[LINE_MAX];
    S.stats.tx_bytes++;
    if (S.tx_len < TX_RING)
        S.tx[(S.tx_head + S.tx_len++) % TX_RING] = (uint8_t)value;
    else
        S.stats.tx_dropped++;
    int n = line_byte(&S.tx_line, (uint8_t)value, p);
    if (n >= 4)
        device_frame(p, n);
}

static void xoff_irq(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param;
    S.xoff = (int)value;
}

/* The host's bytes enter RXD one character time apart, as on the wire; simavr raises RXC
 * one character after a byte enters: the moment its stop bit ends. */
static avr_cycle_count_t rx_feed(struct avr_t *avr, avr_cycle_count_t when, void *param) {
    (void)avr, (void)param;
    uint8_t p[LINE_MAX];
    if (!S.rx_len) {
        S.rx_feeding = 0;
        return 0;
    }
    uint64_t cpb = S.uart->cycles_per_byte;
    if (S.xoff)
        return when + cpb; /* the UART's buffer is full: the line waits */
    uint8_t b = S.rx[S.rx_head];
    S.rx_head = (S.rx_head + 1) % RX_QUEUE;
    S.rx_len--;
    S.stats.rx_bytes++;
    avr_raise_irq(uart_in, b);
    int n = line_byte(&S.rx_line, b, p);
    if (n >= 3) {
        /* a retry (the type and seq of the command before) is acknowledged, not applied again */
        uint16_t seq = fs_get_u16(p + 1);
        int retry = p[0] == S.cmd_type && seq == S.cmd_seq;
        S.cmd_type = p[0];
        S.cmd_seq = seq;
        if (!retry && (p[0] == FS_HEARTBEAT || p[0] == FS_ARM)) {
            S.hb_end = when + cpb;
        } else if (!retry && p[0] == FS_SET_OUTPUTS) {
            S.set_end = when + cpb;
            S.set_pending = 1;
        }
    }
    return when + cpb;
}

void rx_start(void) {
    if (!S.rx_feeding && S.rx_len) {
        S.rx_feeding = 1;
        avr_cycle_timer_register(S.avr, 1, rx_feed, NULL);
    }
}

/* ---------------------------------------------------------------- reset */
static void on_reset(avr_io_t *io) { /* inside avr_reset, before simavr's own parts reset */
    (void)io;
    just_reset = 1;
}

static avr_io_t reset_probe = {.kind = "fsboard", .reset = on_reset};

/* After a reset: simavr's parts have reset (the watchdog set WDRF if it was its doing). */
static void after_reset(void) {
    just_reset = 0;
    uint8_t m = S.avr->data[R_MCUSR];
    uint8_t cause = m & 1 << WDRF ? FS_RESET_WATCHDOG : m & 1 << EXTRF ? FS_RESET_EXTERNAL : FS_RESET_POWER;
    S.stats.resets++;
    S.stats.watchdog_resets += cause == FS_RESET_WATCHDOG;
    avr_extint_set_strict_lvl_trig(S.avr, 0, 0); /* reset turns it on again (below, why off) */
    avr_extint_set_strict_lvl_trig(S.avr, 1, 0);
    line_clear(&S.tx_line);
    line_clear(&S.rx_line);
    S.dev_session = S.dev_armed = S.have_seq = S.have_tick = 0;
    S.stall = S.vent_pending = S.set_pending = 0;
    S.rx_feeding = S.xoff = 0; /* simavr dropped its cycle timers: the line starts again */
    S.last_start = 0;
    pins();
    to_plant(REC_RESET, 0, cause, cycle_ns(S.avr->cycle), 0);
    fprintf(stderr, "fsboard-simavr: the MCU reset (cause %d) at %.6f s\n", cause,
            (double)S.avr->cycle / S.avr->frequency);
    rx_start();
}

void mcu_after_step(void) {
    if (just_reset)
        after_reset();
}

void board_reset(uint8_t cause) {
    avr_reset(S.avr);
    if (cause == FS_RESET_EXTERNAL)
        S.avr->data[R_MCUSR] |= 1 << EXTRF;
    after_reset();
}

/* ---------------------------------------------------------------- set-up */
void mcu_load(const char *path, uint32_t f_cpu, uint32_t vref_mv) {
    static elf_firmware_t f;
    if (elf_read_firmware(path, &f) != 0) {
        fprintf(stderr, "fsboard-simavr: cannot read %s (make firmware builds it)\n", path);
        exit(3);
    }
    avr_t *avr = avr_make_mcu_by_name("atmega328p");
    if (!avr || avr_init(avr) != 0) {
        fprintf(stderr, "fsboard-simavr: simavr has no atmega328p\n");
        exit(3);
    }
    avr_load_firmware(avr, &f);
    avr->frequency = f_cpu; /* the image's F_CPU: the crystal it was built for */
    avr->vcc = avr->avcc = avr->aref = vref_mv;
    S.avr = avr;
    S.vref_mv = vref_mv;
    S.run0 = avr->run;
    profile_init(&S.prof, f.symbol, f.symbolcount, avr->flashend + 1);
    S.fn_main = profile_find(&S.prof, "main");
    S.fn_timer = profile_find(&S.prof, "__vector_7"); /* TIMER2_COMPA_vect: the sample timer */
    if (S.fn_main < 0 || S.fn_timer < 0) {
        fprintf(stderr, "fsboard-simavr: %s has no symbols main and __vector_7 (a stripped image?)\n", path);
        exit(3);
    }
    for (avr_io_t *io = avr->io_port; io; io = io->next)
        if (!strcmp(io->kind, "uart") && ((avr_uart_t *)io)->name == '0')
            S.uart = (avr_uart_t *)io;
    uint32_t flags = 0; /* no console echo, no sleeping on UCSR0A reads: pacing is ours */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    /* INT0/INT1 share D2/D3 with valve outputs 0 and 1; the firmware never enables them, but
     * simavr polls a low level on them every cycle unless told not to */
    avr_extint_set_strict_lvl_trig(avr, 0, 0);
    avr_extint_set_strict_lvl_trig(avr, 1, 0);
    avr_register_io_write(avr, R_UCSR0A, line_rate, NULL); /* after simavr's handlers: the last word */
    avr_register_io_write(avr, R_UCSR0B, line_rate, NULL);
    avr_register_io_write(avr, R_UBRR0L, line_rate, NULL);
    avr_register_io_write(avr, R_UCSR0C, ucsr0c_write, NULL);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), xoff_irq, NULL);
    adc_in = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, 0);
    avr_irq_register_notify(adc_in + ADC_IRQ_OUT_TRIGGER, adc_trigger, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), IOPORT_IRQ_PIN_ALL), pins_irq, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), IOPORT_IRQ_PIN_ALL), pins_irq, NULL);
    for (int i = TIMER_IRQ_OUT_PWM0; i <= TIMER_IRQ_OUT_PWM1; i++)
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_TIMER_GETIRQ('1'), i), pins_irq, NULL);
    avr_register_io(avr, &reset_probe);
    if (!S.uart || !uart_in || !adc_in) {
        fprintf(stderr, "fsboard-simavr: simavr's atmega328p lacks USART0 or the ADC\n");
        exit(3);
    }
}
