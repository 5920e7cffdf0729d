/* AVR board: ATmega328P at 16 MHz (Arduino Uno / Nano), built with avr-gcc and avr-libc.
 *
 *   sample timer   Timer2, CTC at 10 kHz (prescaler 8, OCR2A 199); every 10000/rate-th
 *                  interrupt starts the conversions of one sample (rate must divide 10000)
 *   analog inputs  ADC0-ADC7 (A0-A7), AVcc reference, ADC clock 125 kHz: 104 us per channel,
 *                  converted one after the other from the tick (interrupt-driven)
 *   valve outputs  output 0-5 = D2-D7 (PD2-PD7), 6 = D8 (PB0), 7 = D11 (PB3): logic level,
 *                  drive the solenoids through MOSFET modules (docs/drivers.md)
 *   analog outputs 0 = D9 (OC1A), 1 = D10 (OC1B): 12-bit PWM at 3.9 kHz (Timer1 mode 14);
 *                  filter and amplify to the regulator's command range
 *   serial         USART0 at FS_BAUD (default 500000, U2X: exact at 16 MHz), 8N1
 *   status LED     D13 (PB5): lit while the outputs are held safe by the heartbeat watchdog
 *   hang guard     the hardware watchdog (60 ms) resets a firmware that stops running its
 *                  main loop; every reset starts with all outputs low (power-on state)
 *   idle           the CPU sleeps (idle mode: timers, ADC and USART run on) whenever nothing
 *                  waits; every interrupt wakes it. Awake cycles are the CPU's work, which a
 *                  cycle count (boards/simavr) measures, and which a simulator need not spin
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <util/atomic.h>

#include "../../core/fs_core.h"

#ifndef FS_BAUD
#define FS_BAUD 500000UL
#endif
#define BASE_HZ 10000U
#define CONVERSION_US 104U
#define RX_RING 64
#define TX_RING 256

static struct fs_core core;
static volatile uint8_t rx[RX_RING], rx_head, rx_tail;
static volatile uint8_t tx[TX_RING], tx_head, tx_len;

/* sampling state, shared with the interrupts */
static volatile uint16_t divider = BASE_HZ / 1000, sub;
static volatile uint32_t tick_counter;
static volatile uint8_t channels[FS_MAX_CH], n_channels = 1;
static volatile uint8_t adc_busy, adc_index, adc_late, adc_drop;
static volatile uint32_t adc_tick;
static volatile uint16_t adc_counts[FS_MAX_CH];
static volatile uint8_t ready, ready_late, overrun;
static volatile uint32_t ready_tick;
static volatile uint16_t ready_counts[FS_MAX_CH];

/* MCUSR says why we reset; read it before anything else and clear it (avr-libc's advice
 * for a firmware that uses the watchdog: WDRF left set keeps the watchdog running) */
uint8_t mcusr_copy __attribute__((section(".noinit")));
void read_mcusr(void) __attribute__((naked, used, section(".init3")));
void read_mcusr(void) {
    mcusr_copy = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

static uint8_t reset_cause(void) {
    if (mcusr_copy & _BV(WDRF))
        return FS_RESET_WATCHDOG;
    if (mcusr_copy & _BV(BORF))
        return FS_RESET_BROWNOUT;
    if (mcusr_copy & _BV(EXTRF))
        return FS_RESET_EXTERNAL;
    return FS_RESET_POWER;
}

/* ---------------------------------------------------------------- interrupts */
ISR(USART_RX_vect) {
    uint8_t b = UDR0, next = (uint8_t)((rx_head + 1) % RX_RING);
    if (next != rx_tail) { /* full: the byte is lost; the frame's CRC fails, the host retries */
        rx[rx_head] = b;
        rx_head = next;
    }
}

ISR(USART_UDRE_vect) {
    if (tx_len) {
        UDR0 = tx[tx_head];
        tx_head = (uint8_t)(tx_head + 1); /* TX_RING is 256: the index wraps by itself */
        tx_len--;
    } else {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
    }
}

ISR(TIMER2_COMPA_vect) {
    uint8_t since = TCNT2; /* 0.5 us per count since the compare match */
    if (++sub < divider)
        return;
    if (adc_busy) {
        if (adc_drop) { /* a conversion from before START still runs: tick 0 waits for its end */
            sub = divider - 1;
            return;
        }
        sub = 0; /* the last sample's conversions still run: this tick has no sample */
        overrun = 1;
        tick_counter++;
        return;
    }
    sub = 0;
    adc_tick = tick_counter++;
    adc_late = since / 2;
    adc_index = 0;
    adc_busy = 1;
    ADMUX = (uint8_t)(_BV(REFS0) | channels[0]);
    ADCSRA |= _BV(ADSC);
}

ISR(ADC_vect) {
    if (adc_drop) { /* started before the timer restarted: its sample belongs to no session */
        adc_drop = 0;
        adc_busy = 0;
        return;
    }
    adc_counts[adc_index++] = ADC;
    if (adc_index < n_channels) {
        ADMUX = (uint8_t)(_BV(REFS0) | channels[adc_index]);
        ADCSRA |= _BV(ADSC);
        return;
    }
    if (ready)
        overrun = 1; /* the main loop did not take the last sample in time */
    for (uint8_t i = 0; i < n_channels; i++)
        ready_counts[i] = adc_counts[i];
    ready_tick = adc_tick;
    ready_late = adc_late;
    ready = 1;
    adc_busy = 0;
}

/* ---------------------------------------------------------------- board hooks */
void fs_board_outputs(uint8_t levels) {
    PORTD = (uint8_t)((PORTD & 0x03) | (uint8_t)(levels << 2));
    PORTB = (uint8_t)((PORTB & (uint8_t)~(_BV(PB0) | _BV(PB3))) | ((levels >> 6) & 1 ? _BV(PB0) : 0) |
                      ((levels >> 7) & 1 ? _BV(PB3) : 0));
}

void fs_board_aout(uint8_t channel, uint16_t value) {
    uint16_t duty = value >> 4; /* 16-bit command onto the 12-bit PWM */
    if (channel == 0)
        OCR1A = duty;
    else
        OCR1B = duty;
}

int fs_board_configure(uint16_t rate_hz, uint8_t mask) {
    uint8_t n = 0, list[FS_MAX_CH];
    for (uint8_t ch = 0; ch < FS_MAX_CH; ch++)
        if (mask & (1u << ch))
            list[n++] = ch;
    if (rate_hz == 0 || BASE_HZ % rate_hz || n == 0 ||
        (uint32_t)n * (CONVERSION_US + 4) >= 1000000UL / rate_hz)
        return -1;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        for (uint8_t i = 0; i < n; i++)
            channels[i] = list[i];
        n_channels = n;
        divider = BASE_HZ / rate_hz;
        sub = divider - 1; /* the next timer interrupt takes sample 0 */
        tick_counter = 0;
        ready = overrun = 0;
        adc_drop = adc_busy; /* else its sample, ticked by the old count, would come first */
        DIDR0 = (uint8_t)(mask & 0x3F); /* no digital input buffers on analog pins */
    }
    return 0;
}

/* Only the main loop queues, and the UDRE handler reads nothing past tx_head + tx_len: the
 * frame is copied behind the queue's end with interrupts on. Interrupts are off only to read
 * that end (head and length change together in the handler) and to publish the length. A
 * copy with them off (about 20 bytes, 12 us) delayed the timer's interrupt past the few us a
 * sample's stamp allows. */
int fs_board_send(const uint8_t *frame, uint8_t len) {
    uint8_t at, used;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        at = (uint8_t)(tx_head + tx_len);
        used = tx_len;
    }
    if ((uint16_t)(TX_RING - 1) - used < len) /* the queue only drains meanwhile: still true at the end */
        return 0;
    for (uint8_t i = 0; i < len; i++)
        tx[(uint8_t)(at + i)] = frame[i];
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        tx_len = (uint8_t)(tx_len + len);
        UCSR0B |= _BV(UDRIE0);
    }
    return 1;
}

void fs_board_vented(uint32_t tick, uint32_t last_hb_tick) {
    (void)tick;
    (void)last_hb_tick;
}

/* ---------------------------------------------------------------- set-up */
static void hardware_init(void) {
    PORTD &= 0x03; /* outputs low before they become outputs: the valves' power-on state */
    PORTB &= (uint8_t)~(_BV(PB0) | _BV(PB1) | _BV(PB2) | _BV(PB3) | _BV(PB5));
    DDRD |= 0xFC;
    DDRB |= _BV(PB0) | _BV(PB1) | _BV(PB2) | _BV(PB3) | _BV(PB5);

    UBRR0 = (uint16_t)(F_CPU / 8 / FS_BAUD - 1);
    UCSR0A = _BV(U2X0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);

    TCCR2A = _BV(WGM21);
    TCCR2B = _BV(CS21);
    OCR2A = (uint8_t)(F_CPU / 8 / BASE_HZ - 1);
    TIMSK2 = _BV(OCIE2A);

    ICR1 = 4095;
    OCR1A = OCR1B = 0;
    TCCR1A = _BV(COM1A1) | _BV(COM1B1) | _BV(WGM11);
    TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS10);

    ADCSRA = _BV(ADEN) | _BV(ADIE) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
}

int main(void) {
    static const struct fs_board_info base = {.name = "avr328p", .adc_bits = 10, .n_adc = 8, .n_outputs = 8,
                                              .n_aout = 2, .max_rate_hz = 2000};
    struct fs_board_info info = base;
    info.reset_cause = reset_cause();
    hardware_init();
    fs_core_init(&core, &info);
    wdt_enable(WDTO_60MS);
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    for (;;) {
        wdt_reset();
        while (rx_tail != rx_head) {
            uint8_t b = rx[rx_tail];
            rx_tail = (uint8_t)((rx_tail + 1) % RX_RING);
            fs_core_rx(&core, b);
        }
        if (ready) {
            uint16_t counts[FS_MAX_CH];
            uint32_t tick;
            uint8_t late, missed;
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
                for (uint8_t i = 0; i < n_channels; i++)
                    counts[i] = ready_counts[i];
                tick = ready_tick;
                late = ready_late;
                missed = overrun;
                ready = overrun = 0;
            }
            if (missed)
                fs_core_adc_overrun(&core);
            fs_core_tick(&core, tick, counts, late);
        }
        if (core.vented)
            PORTB |= _BV(PB5);
        else
            PORTB &= (uint8_t)~_BV(PB5);
        cli();
        if (rx_tail == rx_head && !ready) {
            sleep_enable();
            sei(); /* the instruction after SEI runs before any interrupt: no wake-up is lost */
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
